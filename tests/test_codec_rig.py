"""The codec's rig steps: an ancestor's translation folded into the mover, rest frames and the
canonical walking side stored with the codec (and the model), so that a new clip is encoded as
the training clips were and decoding returns to the original rig; variances carried to it."""

import io

import numpy as np
import pytest

from bayesmotion.codecs.pose import PoseCodec, fold_ancestor_translation
from bayesmotion.data import Motion, MotionDataset, Skeleton, Trial
from bayesmotion.data.mirror import mirror, mirror_plan
from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.emotion.infer import infer_emotion
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.model.data import fit_codecs
from bayesmotion.model.generate import generate
from bayesmotion.model.io import load
from bayesmotion.model.spec import HGPDM
from tests.test_mirror import ROOT6, ROT3, _half_turned_skeleton, _random_motion

WALKS = ("walk", "walk-back", "walk-left", "walk-right")


def _rooted_skeleton() -> Skeleton:
    """A static ``Root`` with six channels above the moving ``Hips`` (Bandai's layout)."""
    names = ("Root", "Hips", "Spine", "Arm_L", "Arm_R")
    parents = (-1, 0, 1, 2, 2)
    offsets = np.array([[0, 0, 0], [0, 90, 0], [0, 10, 0], [5, 0, 0], [-5, 0, 0.]])
    ends = {3: np.array([10.0, 0, 0]), 4: np.array([-10.0, 0, 0])}
    return Skeleton(names, parents, offsets, (ROOT6, ROOT6, ROT3, ROT3, ROT3), ends)


def _rooted_motion(sk, seed, root_walks: bool) -> Motion:
    rng = np.random.default_rng(seed)
    T = 25
    v = np.zeros((T, sk.n_channels))
    v[:, 6:9] = sk.offsets[1] + rng.normal(0, 0.5, (T, 3))
    v[:, 9:12] = rng.uniform(-10, 10, (T, 3))
    v[:, 12:] = rng.uniform(-40, 40, (T, 9))
    v[:, 4] = 30.0 if root_walks else 0.0  # a turned root (X rotation) must be allowed for
    walk = 4.0 * np.arange(T)
    v[:, 2 if root_walks else 8] += walk
    return Motion(sk, v, 30.0, f"clip{seed}")


def test_an_ancestors_translation_is_folded_into_the_mover():
    sk = _rooted_skeleton()
    clips = [_rooted_motion(sk, s, root_walks=(s == 2)) for s in range(3)]
    folded = fold_ancestor_translation(clips[2], mover=1)
    # the mover and everything below it stay where they were; the root rests at the origin
    np.testing.assert_allclose(folded.positions(True)[:, 1:], clips[2].positions(True)[:, 1:],
                               atol=1e-9 * sk.size())
    np.testing.assert_allclose(folded.positions()[:, 0], 0.0, atol=1e-12)
    assert not folded.values[:, :3].any()
    assert fold_ancestor_translation(clips[0], mover=1) is clips[0]  # nothing to fold
    codec = PoseCodec.fit(clips, root_mode="heading")
    assert codec.mover == 1 and codec.fold_root
    # the root's position channels are constant once folded, so they are no pose channels
    assert not any(n.startswith("Root:") and "position" in n for n in codec.channel_names)
    for m in clips:
        e = codec.encode(m)
        back = codec.decode(e.Y, e.anchor, fps=m.fps)
        np.testing.assert_allclose(back.positions()[:, 1:], m.positions()[:, 1:],
                                   atol=1e-8 * sk.size())


def _walks():
    sk = _half_turned_skeleton()
    left = [_random_motion(sk, T=20, seed=s, walk=(3.0, 0.5), sway=5.0) for s in (1, 2)]
    plan = mirror_plan(sk, left)
    right = [mirror(_random_motion(sk, T=20, seed=s, walk=(3.0, 0.5), sway=5.0), plan)
             for s in (3, 4)]
    ahead = [_random_motion(sk, T=20, seed=5, walk=(0.0, 3.0), sway=5.0)]
    return sk, left + right + ahead


def test_rest_frames_and_canonical_side_round_trip_to_the_original_rig():
    sk, clips = _walks()
    codec = PoseCodec.fit(clips, root_mode="heading", rest_frames=True, canonical_side=True)
    assert codec.frames is not None and codec.side is not None
    flags = [codec.encode(m).mirrored for m in clips]
    assert flags == [False, False, True, True, False]
    for m, flag in zip(clips, flags, strict=True):
        e = codec.encode(m)
        back = codec.decode(e.Y, e.anchor, m.skeleton, m.fps, mirrored=e.mirrored)
        assert back.skeleton.same_layout(sk)
        np.testing.assert_allclose(back.positions(True), m.positions(True),
                                   atol=1e-8 * sk.size())
        if flag:  # without mirrored=True the canonical (left-side) motion comes back
            side = codec.decode(e.Y, e.anchor, m.skeleton, m.fps)
            np.testing.assert_allclose(side.positions(), mirror(m, codec.side).positions(),
                                       atol=1e-8 * sk.size())
    # rest frames: every joint below the mover has mean rig angles near zero
    rig = np.concatenate([codec.prepare(m)[0].values for m in clips])
    assert np.abs(rig[:, 6:].mean(0)).max() < 20.0
    assert np.abs(np.concatenate([m.values for m in clips])[:, 6:].mean(0)).max() > 40.0


def test_canonical_side_and_frames_are_rejected_where_they_cannot_work(tmp_path):
    sk, clips = _walks()
    with pytest.raises(BayesmotionError, match="partner"):
        PoseCodec.fit(clips, clips, root_mode="partner", canonical_side=True)
    # two actors mirrored each alone would break their interaction, whatever the root mode
    pairs = MotionDataset(tuple(Trial((a, b), {"emotion": "neutral"}, f"p{i}")
                                for i, (a, b) in enumerate(zip(clips, clips[1:], strict=False))))
    spec = HGPDM(root_mode="heading", canonical_side=True).resolved(pairs)
    with pytest.raises(BayesmotionError, match="one-actor clips; this dataset has 2 actors"):
        fit_codecs(spec, pairs)
    codec = PoseCodec.fit(clips, root_mode="heading")
    e = codec.encode(clips[0])
    with pytest.raises(BayesmotionError, match="canonical side"):
        codec.decode(e.Y, e.anchor, mirrored=True)
    with pytest.raises(BayesmotionError, match="skeleton must be a Skeleton"):
        codec.decode(*e)  # Encoded has three fields: mirrored goes by name
    # a skeleton without left-right names cannot have a canonical side: say what to do
    plain = Skeleton(("a", "b", "c"), (-1, 0, 1), np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0.]]),
                     (ROOT6, ROT3, ROT3), {2: np.array([1.0, 0, 0])})
    m = Motion(plain, np.c_[np.arange(10.0), np.zeros((10, 11))], 30.0)
    with pytest.raises(BayesmotionError, match="canonical_side needs left-right joint pairs"):
        PoseCodec.fit([m], root_mode="heading", canonical_side=True)


@pytest.mark.slow
def test_corrupt_rig_arrays_in_a_model_file_are_refused(tmp_path):
    import zipfile

    _, clips = _walks()
    data = MotionDataset(tuple(Trial((m,), {"emotion": e}, f"t{i}") for i, (m, e) in
                               enumerate(zip(clips, ("neutral", "happy") * 2 + ("neutral",),
                                             strict=True))))
    model = HGPDM(latent_dim=2, interaction_dim=2, rest_frames=True,
                  canonical_side=True).fit(data, max_iter=1, progress=False)
    good = tmp_path / "good.npz"
    model.save(good)
    F = model.codecs[0].frames
    for entry, value, match in (("codec0/frames", F[:3], "rest frames must be finite"),
                                ("codec0/frames", 2.0 * F, "not rotations"),
                                ("codec0/side_perm", np.zeros(F.shape[0], int), "pairing")):
        bad = tmp_path / "bad.npz"
        buf = io.BytesIO()
        np.save(buf, value)
        with zipfile.ZipFile(good) as zin, zipfile.ZipFile(bad, "w") as zout:
            for item in zin.infolist():
                if item.filename != entry + ".npy":
                    zout.writestr(item, zin.read(item.filename))
            zout.writestr(entry + ".npy", buf.getvalue())
        with pytest.raises(ModelFileError, match=match):
            load(bad)


def test_channel_variance_matches_monte_carlo_through_the_frames():
    """Rig angles with isotropic variance, carried to the original rig: the first-order
    variances match the spread of sampled rig poses turned back (within sampling error)."""
    sk, clips = _walks()
    codec = PoseCodec.fit(clips, root_mode="heading", rest_frames=True)
    rig = codec.prepare(clips[0])[0]
    base = rig.values[:3]
    rot = np.flatnonzero(rig.rotation_mask())
    var = np.zeros_like(base)
    var[:, rot] = 4.0  # (2 degrees)^2
    S = 3000
    rng = np.random.default_rng(0)
    samples = np.repeat(base, S, axis=0)  # each frame's S samples in one block
    samples[:, rot] += rng.normal(0.0, 2.0, (samples.shape[0], rot.size))
    back = codec.from_rig(rig.replace(values=samples), sk).values.reshape(3, S, -1)
    centre = codec.from_rig(rig.replace(values=base), sk).values
    dev = (back - centre[:, None] + 180.0) % 360.0 - 180.0
    empirical = np.mean(dev ** 2, axis=1)
    predicted = codec.channel_variance(rig.replace(values=base), var)
    moved = [j for j in range(sk.n_joints) if sk.parents[j] >= 0]
    cols = np.concatenate([sk.rotation_layout()[0][j] for j in moved])
    np.testing.assert_allclose(empirical[:, cols], predicted[:, cols], rtol=0.12)
    # a joint whose frame turned mixes its angles: some variances differ from the rig's 4
    assert np.abs(predicted[:, cols] - 4.0).max() > 0.5


@pytest.mark.slow
def test_model_stores_the_rig_steps_and_new_clips_go_through_them(tmp_path):
    _, clips = _walks()
    data = MotionDataset(tuple(Trial((m,), {"emotion": e}, f"t{i}") for i, (m, e) in
                               enumerate(zip(clips, ("neutral", "happy", "neutral", "happy",
                                                     "neutral"), strict=True))))
    spec = HGPDM(latent_dim=2, interaction_dim=2, rest_frames=True, canonical_side=True)
    model = spec.fit(data, max_iter=2, progress=False)
    path = tmp_path / "rig.npz"
    model.save(path)
    back = load(path)
    assert back.spec.rest_frames and back.spec.canonical_side
    c0, c1 = model.codecs[0], back.codecs[0]
    np.testing.assert_array_equal(c1.frames, c0.frames)
    for a, b in zip(c0.side, c1.side, strict=True):
        np.testing.assert_array_equal(a, b)
    assert c1.fold_root and c1.side_threshold == c0.side_threshold
    # a clip walking to the right is mirrored at inference as in training
    e0, e1 = c0.encode(clips[2]), c1.encode(clips[2])
    assert e1.mirrored
    np.testing.assert_array_equal(e1.Y, e0.Y)
    for clip, flag in ((clips[2], True), (clips[0], False)):
        ep = infer_emotion(back, clip, n_steps=20, max_iter=5, emotion_starts="nearest",
                           latent_uncertainty=False)
        assert ep.info["mirrored"] == [flag]
    # generation decodes to the original rig: its angles on the original skeleton give the
    # positions (computed with their variance in the rest frames); variances are finite
    r = generate(back, "happy", n_frames=8, n_samples=2, seed=0)
    sk = r.skeletons[0]
    np.testing.assert_allclose(Motion(sk, r.angles[0], r.fps).positions(), r.positions[0],
                               atol=1e-8 * sk.size())
    o = r.n_observed
    assert np.all(np.isfinite(r.angles_var)) and np.all(r.angles_var >= 0)
    assert np.all(r.positions_var[0, o:, 1:] > 0)  # the hips' height is constant here
    np.testing.assert_allclose(Motion(sk, r.samples["angles"][1, 0], r.fps).positions(),
                               r.samples["positions"][1, 0], atol=1e-8 * sk.size())


def test_bandai_walks_encode_without_outlier_channels(bandai_root):
    """Bandai's rig: joint_Root carries the walk-back normal clip's translation, the bone
    offsets are position channels, the spine sits near gimbal lock. With the codec's steps no
    channel of any walk leaves 15 standard units (before: 125, the root's depth), the hips'
    height has about unit spread, exactly the walks to the right are mirrored, and every clip
    decodes back to its own joint positions (the static joint_Root to the origin)."""
    data = load_bandai(bandai_root, content=WALKS, fps=15.0)
    clips = [t.actors[0] for t in data]
    codec = PoseCodec.fit(clips, root_mode="heading", rest_frames=True, canonical_side=True)
    hips_y = codec.channel_names.index("Hips:Yposition")
    Y = []
    for m in clips:
        e = codec.encode(m)
        assert e.mirrored == ("walk-right" in m.name), m.name
        back = codec.decode(e.Y, e.anchor, m.skeleton, m.fps, mirrored=e.mirrored)
        # joint_Root rests at the origin; Hips (the mover) and everything below are exact
        np.testing.assert_allclose(back.positions()[:, 1:], m.positions()[:, 1:],
                                   atol=1e-8 * m.skeleton.size())
        Y.append(e.Y)
        if not e.mirrored:  # angles come back on the data's own branch (up to whole turns)
            rot = m.rotation_mask()
            turned = (back.values[:, rot] - m.values[:, rot] + 180.0) % 360.0 - 180.0
            np.testing.assert_allclose(turned, 0.0, atol=1e-6)
    # noise on Y spreads the decoded angles as channel_variance predicts: no branch flips
    # between draws (before the decoder took the training clips' branch, the spine's angles
    # jumped between its two Euler solutions: 74-77 deg of spread against 5.7 predicted)
    m, e = clips[0], codec.encode(clips[0])
    rng = np.random.default_rng(0)
    draws = np.stack([codec.decode(e.Y + rng.normal(0.0, 0.05, e.Y.shape), e.anchor,
                                   m.skeleton, m.fps).values for _ in range(100)])
    rig = codec.decode_rig(e.Y, e.anchor, m.skeleton, m.fps)
    var = np.zeros_like(rig.values)
    kept = codec.keep < var.shape[1]
    var[:, codec.keep[kept]] = (0.05 * codec.scale[kept]) ** 2
    predicted = np.sqrt(codec.channel_variance(rig, var))[:, m.rotation_mask()]
    spread = draws.std(0)[:, m.rotation_mask()]
    assert spread.max() < 1.5 * predicted.max()
    sel = predicted > 0.5
    np.testing.assert_allclose(spread[sel], predicted[sel], rtol=0.35)
    Y = np.concatenate(Y)
    assert np.abs(Y).max() < 15.0
    assert 0.5 < Y[:, hips_y].std() < 2.0
    assert not any(n.startswith("joint_Root:") for n in codec.channel_names)


@pytest.mark.slow
def test_cli_fit_stores_the_rig_steps(tmp_path):
    from bayesmotion.app.cli import main
    from bayesmotion.data import write_bvh

    _, clips = _walks()
    rows = ["file,emotion"]
    for i, (m, e) in enumerate(zip(clips, ("neutral", "happy", "neutral", "happy", "neutral"),
                                   strict=True)):
        write_bvh(m, tmp_path / f"c{i}.bvh", precision=9)
        rows.append(f"c{i}.bvh,{e}")
    (tmp_path / "labels.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "m.npz"
    assert main(["fit", str(tmp_path), "--out", str(out), "--max-iter", "2", "--latent-dim",
                 "2", "--interaction-dim", "2", "--rest-frames", "--canonical-side"]) == 0
    model = load(out)
    assert model.spec.rest_frames and model.spec.canonical_side
    assert model.codecs[0].frames is not None and model.codecs[0].side is not None
    assert [model.codecs[0].encode(m).mirrored for m in clips] == [False, False, True, True,
                                                                   False]
