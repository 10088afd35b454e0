"""The interactive viewer page and rollout files: what the page holds, that it works in a real
browser (headless Chromium: loads without console errors, plays, scrubs, turns, switches
clips), and that rollout files round-trip and refuse what they should."""

import io
import json
import re
import warnings
import zipfile

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.app.cli import main
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.inference.posterior import ChainTooShortWarning
from bayesmotion.viz.viewer import (
    ViewerClip,
    load_clips,
    motion_clip,
    rollout_clip,
    viewer_fragment,
    viewer_html,
    write_viewer,
)
from tests._browser import browser_check


@pytest.fixture(scope="module")
def rollouts(tiny_model):
    """A sampled rollout per emotion and a 50/50 mix (mean only)."""
    out = {e: tiny_model.generate(emotion=e, couple="c1", n_frames=24, n_samples=3, seed=1)
           for e in tiny_model.levels["emotion"]}
    out["mix"] = tiny_model.generate(emotion=[0.5, 0.5], couple="c1", n_frames=24)
    return out


def _data(page: str) -> list:
    m = re.search(r'<script type="application/json" class="bm-data">(.*?)</script>', page,
                  re.S)
    assert "<" not in m.group(1)  # nothing in the data can end the element or open a comment
    return json.loads(m.group(1))


# ----------------------------------------------------------------------------- rollout files
def test_rollout_file_round_trips_everything(rollouts, tmp_path):
    r = rollouts["happy"]
    back = bm.load_rollout(r.save(tmp_path / "r.npz"))
    for k in ("I", "I_var", "X", "X_var", "Y", "Y_var", "angles", "angles_var", "positions",
              "positions_var"):
        np.testing.assert_array_equal(getattr(back, k), getattr(r, k), err_msg=k)
    assert set(back.samples) == set(r.samples) and set(back.sample_var) == set(r.sample_var)
    for k in r.samples:
        np.testing.assert_array_equal(back.samples[k], r.samples[k], err_msg=k)
        np.testing.assert_array_equal(back.sample_var[k], r.sample_var[k], err_msg=k)
    for f in r.styles:
        np.testing.assert_array_equal(back.styles[f], r.styles[f])
    assert (back.fps, back.start, back.n_observed, back.extrapolated) == (
        r.fps, r.start, r.n_observed, r.extrapolated)
    assert [sk.names for sk in back.skeletons] == [sk.names for sk in r.skeletons]
    # the skeletons read back decode the saved angles to the saved positions
    np.testing.assert_allclose(np.stack([m.positions() for m in back.to_motion()]),
                               r.positions, atol=1e-6)
    mix = bm.load_rollout(rollouts["mix"].save(tmp_path / "mix.npz"))
    assert mix.samples is None and mix.sample_var is None


def test_rollout_file_refuses_other_files(rollouts, tiny_model, tmp_path):
    tiny_model.save(tmp_path / "model.npz")
    with pytest.raises(ModelFileError, match="not a bayesmotion rollout file"):
        bm.load_rollout(tmp_path / "model.npz")
    with pytest.raises(ModelFileError, match="not a bayesmotion model file"):
        bm.load(rollouts["happy"].save(tmp_path / "r.npz"))
    # a member the metadata does not name
    path = rollouts["mix"].save(tmp_path / "extra.npz")
    with zipfile.ZipFile(path, "a") as z:
        with z.open("extra.npy", "w") as f:
            np.save(f, np.zeros(3))
    with pytest.raises(ModelFileError, match="does not name"):
        bm.load_rollout(path)
    # a member of the wrong shape (positions of another length)
    src = rollouts["mix"].save(tmp_path / "src.npz")
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(bad, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "positions_var.npy":
                buf = io.BytesIO()
                np.save(buf, np.zeros((2, 5, 3, 3)))
                data = buf.getvalue()
            zout.writestr(item, data)
    with pytest.raises(ModelFileError, match="positions_var"):
        bm.load_rollout(bad)


def _rewritten(src, dst, member, value):
    """A copy of the archive ``src`` with ``member`` (a .npy name) holding ``value``."""
    import io

    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == member:
                buf = io.BytesIO()
                np.save(buf, value)
                data = buf.getvalue()
            zout.writestr(item, data)
    return dst


def test_every_malformed_member_is_refused_with_a_model_file_error(rollouts, tmp_path):
    """Each member replaced by an array of the wrong shape, and each variance made negative:
    the loader refuses all with ModelFileError (never a raw NumPy error, nor a rollout that
    fails later)."""
    src = rollouts["happy"].save(tmp_path / "src.npz")
    with zipfile.ZipFile(src) as z:
        members = [n for n in z.namelist() if n != "__meta__.npy"]
        shapes = {n: np.load(io.BytesIO(z.read(n))).shape for n in members}
    assert {"samples/positions/0.npy", "sample_var/angles.npy", "styles/emotion.npy"} <= set(
        members)
    for k, name in enumerate(members):
        wrong = np.zeros(tuple(d + 1 for d in shapes[name]) or (2,))
        with pytest.raises(ModelFileError):
            bm.load_rollout(_rewritten(src, tmp_path / f"w{k}.npz", name, wrong))
        if "var" in name:
            with pytest.raises(ModelFileError, match="negative"):
                bm.load_rollout(_rewritten(src, tmp_path / f"n{k}.npz", name,
                                           -np.ones(shapes[name])))


def test_a_rollout_that_cannot_be_read_back_is_not_written(rollouts, tmp_path):
    import dataclasses

    r = rollouts["mix"]
    bad = dataclasses.replace(r, positions_var=np.full_like(r.positions_var, np.inf))
    with pytest.raises(BayesmotionError, match="cannot be saved"):
        bad.save(tmp_path / "inf.npz")
    assert not (tmp_path / "inf.npz").exists()


@pytest.mark.slow
def test_posterior_predictive_rollouts_round_trip(tiny_model, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = bm.sample_posterior(tiny_model, n_steps=12, progress=False)
    r = post.generate(emotion="sad", couple="c1", n_frames=12, n_samples=2, n_draws=2)
    back = bm.load_rollout(r.save(tmp_path / "pp.npz"))
    np.testing.assert_array_equal(back.draws, r.draws)
    for k, parts in r.variance_parts.items():
        for n, v in parts.items():
            np.testing.assert_array_equal(back.variance_parts[k][n], v, err_msg=f"{k}/{n}")
    assert rollout_clip(back, "pp").to_json()["actors"][0]["samples"] is not None


# ------------------------------------------------------------------------------- the page
def test_page_holds_the_clips_and_nothing_external(rollouts):
    r = rollouts["happy"]
    clips = [rollout_clip(r, "happy", "emotion"),
             rollout_clip(rollouts["mix"], "</script><!-- <b>mix</b>", "interpolation")]
    page = viewer_html(clips, title="t <1>")
    assert "t &lt;1&gt;" in page
    # self-contained: no address to fetch anything from, no external script or stylesheet
    assert not re.search(r"https?://|src\s*=|<link", page)
    data = _data(page)
    assert [c["name"] for c in data] == ["happy", "</script><!-- <b>mix</b>"]
    a0 = data[0]["actors"][0]
    assert data[0]["n_frames"] == r.n_frames and data[0]["fps"] == r.fps
    np.testing.assert_allclose(a0["mean"], r.positions[0], atol=0.006)
    sd = np.sqrt(np.mean(r.positions_var[0] + r.sample_var["positions"][0], axis=-1))
    np.testing.assert_allclose(a0["sd"], sd, atol=0.006)
    np.testing.assert_allclose(a0["samples"], r.samples["positions"][:, 0], atol=0.006)
    assert data[1]["actors"][0]["samples"] is None
    # bones: every joint with a parent, none touching a hidden joint
    parents = r.skeletons[0].parents
    assert sorted(map(tuple, a0["bones"])) == sorted((j, p) for j, p in enumerate(parents)
                                                     if p >= 0)


def test_clip_checks_its_arrays(rollouts):
    c = rollout_clip(rollouts["happy"], "happy")
    with pytest.raises(BayesmotionError, match="joints but"):
        ViewerClip("x", 10.0, (c.parents[0][:-1],), (frozenset(),), (c.mean[0],))
    with pytest.raises(BayesmotionError, match="not all finite"):
        ViewerClip("x", 10.0, c.parents[:1], (frozenset(),), (c.mean[0] * np.nan,))
    with pytest.raises(BayesmotionError, match="fps"):
        ViewerClip("x", 0.0, c.parents[:1], (frozenset(),), (c.mean[0],))
    with pytest.raises(BayesmotionError, match="at least one clip"):
        viewer_html([])
    with pytest.raises(BayesmotionError, match="rollout files"):
        load_clips(["a.txt"])


def test_bvh_clips_hide_bandai_world_root(tmp_path):
    """A Bandai-style skeleton's fixed joint_Root is not drawn (nor its bone to the hips)."""
    text = ("HIERARCHY\nROOT joint_Root\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition "
            "Zposition\n JOINT Hips\n {\n  OFFSET 0 90 0\n  CHANNELS 3 Zrotation Xrotation "
            "Yrotation\n  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\nMOTION\nFrames: 2\n"
            "Frame Time: 0.1\n0 0 0 0 0 0\n1 0 0 0 0 0\n")
    (tmp_path / "w.bvh").write_text(text)
    [clip] = load_clips([tmp_path / "w.bvh"])
    assert clip.hidden == (frozenset({0}),) and clip.fps == pytest.approx(10.0)
    assert clip.to_json()["actors"][0]["bones"] == []
    assert motion_clip(bm.read_bvh(tmp_path / "w.bvh"), "w").n_frames == 2


def test_cli_generate_writes_a_rollout_and_a_viewer(tiny_model, tmp_path, capsys):
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    out = tmp_path / "gen"
    assert main(["generate", str(model), "--emotion", "sad", "--frames", "20", "--samples", "2",
                 "--out", str(out)]) == 0
    r = bm.load_rollout(out / "sad_rollout.npz")
    assert r.samples["positions"].shape[0] == 2 and r.n_frames == 20
    assert _data((out / "sad.html").read_text())[0]["n_frames"] == 20
    assert main(["view", str(out / "sad_rollout.npz"), "--out", str(tmp_path / "v.html")]) == 0
    assert main(["view", str(out / "sad_mean_actor0.bvh"), str(out / "sad_mean_actor1.bvh"),
                 "--out", str(tmp_path / "b.html")]) == 0
    data = _data((tmp_path / "b.html").read_text())
    assert len(data) == 1 and len(data[0]["actors"]) == 2
    # the BVH clip's positions are the rollout's, read back through the files
    np.testing.assert_allclose(data[0]["actors"][1]["mean"], r.positions[1], atol=0.02)
    capsys.readouterr()
    assert main(["view", str(out / "sad_mean_actor0.bvh"), str(out / "sad_rollout.npz"),
                 "--out", str(tmp_path / "x.html")]) == 2
    assert "not both" in capsys.readouterr().err
    assert not (tmp_path / "x.html").exists()


# ---------------------------------------------------------------- in a real browser
def test_viewer_plays_in_chromium(rollouts, tmp_path):
    clips = [rollout_clip(rollouts[e], e, "emotion") for e in ("happy", "sad")]
    clips.append(rollout_clip(rollouts["mix"], "happy 0.5 / sad 0.5", "interpolation"))
    page = write_viewer(tmp_path / "v.html", clips)
    seen = browser_check(page, tmp_path)
    assert seen["errors"] == []
    assert seen["label_before"].startswith("frame 1 / 24")
    assert not seen["label_after"].startswith("frame 1 /")  # time moved on
    assert seen["played"] and seen["turned"] and seen["switched"] and seen["paused_still"]
    assert seen["options"] == 3
    assert seen["label_scrubbed"].startswith("frame 11 / 24")


def test_two_viewers_on_one_page_each_keep_their_clips(rollouts, tmp_path):
    first = viewer_fragment([rollout_clip(rollouts[e], e) for e in ("happy", "sad")])
    second = viewer_fragment([rollout_clip(rollouts["mix"], "mix <!-- x")])
    page = tmp_path / "two.html"
    page.write_text(f"<!doctype html><html><body>{first}{second}</body></html>")
    seen = browser_check(page, tmp_path)
    assert seen["errors"] == [] and seen["options"] == 2 and seen["played"]
