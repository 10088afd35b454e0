"""Pose features relative to each clip's action (``HGPDM(pose_reference="content")``).

The codec is checked against hand-computed level means and within-level scales; the model
path (fit, infer, save, load) against the same numbers; every refusal names its cause.
"""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.codecs.affective import AffectiveCodec
from bayesmotion.emotion.clip import clip_poses
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.features.pose import affective_features

from .conftest import make_tiny_dataset
from .test_model import _rewrite, _with_meta

# two made-up actions, each holding both emotions of the tiny handshake set
CONTENTS = ("reach", "greet", "reach", "greet", "reach", "greet")


def with_contents(ds):
    trials = [bm.Trial(t.actors, {**t.labels, "content": c}, t.name)
              for t, c in zip(ds.trials, CONTENTS, strict=True)]
    return bm.MotionDataset(tuple(trials), ds.levels)


@pytest.fixture(scope="module")
def data():
    ds = with_contents(make_tiny_dataset())
    # each action holds both emotions (the fixture's order is not assumed)
    for c in set(CONTENTS):
        assert {t.labels["emotion"] for t in ds if t.labels["content"] == c} == {"happy", "sad"}
    return ds


@pytest.fixture(scope="module")
def model(data):
    spec = bm.HGPDM(latent_dim=3, interaction_dim=3, pose_space="affective",
                    pose_reference="content")
    return spec.fit(data, max_iter=30, progress=False)


def test_each_level_is_centred_on_its_own_mean_and_scaled_within(data):
    motions = [t.actors[0] for t in data]
    codec = AffectiveCodec.fit(motions, root_mode="heading", reference="content",
                               reference_labels=CONTENTS)
    assert codec.reference == "content" and codec.reference_levels == ("greet", "reach")
    raw = [affective_features(m) for m in motions]
    means = {c: np.concatenate([f for f, g in zip(raw, CONTENTS, strict=True) if g == c]).mean(0)
             for c in ("greet", "reach")}
    np.testing.assert_allclose(codec.reference_means, [means["greet"], means["reach"]],
                               rtol=1e-12, atol=1e-12)
    within = np.concatenate([f - means[g] for f, g in zip(raw, CONTENTS, strict=True)])
    np.testing.assert_allclose(codec.scale, within.std(0), rtol=1e-12)
    for m, f, g in zip(motions, raw, CONTENTS, strict=True):
        np.testing.assert_allclose(codec.encode(m, reference_level=g).Y,
                                   (f - means[g]) / codec.scale, rtol=1e-12, atol=1e-12)
    # the same clip against the other action's posture differs by the means' difference
    d = codec.encode(motions[0], reference_level="greet").Y - codec.encode(
        motions[0], reference_level="reach").Y
    np.testing.assert_allclose(d, np.broadcast_to((means["reach"] - means["greet"])
                                                  / codec.scale, d.shape), atol=1e-12)


def test_a_clip_needs_a_level_the_training_clips_had(data):
    motions = [t.actors[0] for t in data]
    codec = AffectiveCodec.fit(motions, root_mode="heading", reference="content",
                               reference_labels=CONTENTS)
    with pytest.raises(BayesmotionError, match="relative to each clip's 'content'"):
        codec.encode(motions[0])
    with pytest.raises(BayesmotionError, match="'wave' is not among the training clips' levels"):
        codec.encode(motions[0], reference_level="wave")
    with pytest.raises(BayesmotionError, match="every training clip needs a 'content' label"):
        AffectiveCodec.fit(motions, root_mode="heading", reference="content",
                           reference_labels=CONTENTS[:-1])


def test_the_option_is_checked():
    assert bm.HGPDM().pose_reference is None
    with pytest.raises(BayesmotionError, match="needs pose_space='affective'"):
        bm.HGPDM(pose_reference="content")
    with pytest.raises(BayesmotionError, match="a label name such as 'content'"):
        bm.HGPDM(pose_space="affective", pose_reference=3)
    with pytest.raises(BayesmotionError, match="every trial needs a 'content' label"):
        bm.HGPDM(latent_dim=3, interaction_dim=3, pose_space="affective",
                 pose_reference="content").fit(make_tiny_dataset(), max_iter=2, progress=False)


def test_the_model_reads_each_trial_against_its_action(model, data):
    for a, codec in enumerate(model.codecs):
        assert codec.reference == "content" and codec.reference_levels == ("greet", "reach")
        start = 0
        for t in data:
            Y = codec.encode(t.actors[a], reference_level=t.labels["content"]).Y
            np.testing.assert_array_equal(model.data.Y[a][start:start + t.n_frames], Y)
            start += t.n_frames
    trial = data.trials[4]
    level = trial.labels["content"]
    np.testing.assert_array_equal(clip_poses(model, trial)[0],
                                  clip_poses(model, trial.actors, reference=level)[0])
    with pytest.raises(BayesmotionError, match="relative to each clip's 'content'"):
        clip_poses(model, trial.actors)
    with pytest.raises(BayesmotionError, match="reference must be None or a level name"):
        bm.infer_emotion(model, trial, reference=1)


@pytest.mark.slow
def test_inference_and_files_keep_the_reference(model, data, tmp_path):
    trial = data.trials[4]
    ep = bm.infer_emotion(model, trial, couple="c1", n_steps=40, seed=1)
    bare = bm.infer_emotion(model, trial.actors, reference=trial.labels["content"],
                            couple="c1", n_steps=40, seed=1)
    np.testing.assert_allclose(bare.mean, ep.mean, rtol=1e-12)
    path = tmp_path / "ref.npz"
    model.save(path)
    back = bm.load(path)
    assert back.spec.pose_reference == "content"
    for a, b in zip(model.codecs, back.codecs, strict=True):
        assert b.reference_levels == a.reference_levels
        np.testing.assert_array_equal(b.reference_means, a.reference_means)
    np.testing.assert_allclose(bm.infer_emotion(back, trial, couple="c1", n_steps=40,
                                                seed=1).mean, ep.mean, rtol=1e-9)


def test_files_whose_reference_does_not_add_up_are_refused(model, tmp_path):
    good = tmp_path / "good.npz"
    model.save(good)

    def spec_without(meta):
        meta["spec"]["pose_reference"] = None

    def short_levels(meta):
        meta["codecs"][0]["reference_levels"] = ["greet"]

    with pytest.raises(ModelFileError, match="pose_reference=None does not match"):
        bm.load(_with_meta(good, tmp_path / "a.npz", spec_without))
    with pytest.raises(ModelFileError, match="of shape \\(1, 18\\)"):
        bm.load(_with_meta(good, tmp_path / "b.npz", short_levels))
    with pytest.raises(ModelFileError, match="means are missing"):
        bm.load(_rewrite(good, tmp_path / "c.npz",
                         lambda k, v: None if k == "codec1/reference_means" else v))
    with pytest.raises(ModelFileError, match="holds NaN"):
        bm.load(_rewrite(good, tmp_path / "d.npz",
                         lambda k, v: v * np.nan if k == "codec0/reference_means" else v))


def test_leave_one_out_baselines_include_the_content_relative_classifier(data):
    from bayesmotion.baselines.classifier import GroupCentred, trial_features
    from bayesmotion.evaluation.evaluate import BY_CONTENT, _baselines, _content_groups

    out, probs = _baselines(data, "emotion")
    X = trial_features(data)
    y = np.array(data.labels("emotion"))
    g = np.array(CONTENTS)
    manual = [GroupCentred().fit(np.delete(X, i, 0), np.delete(y, i), np.delete(g, i))
              .predict(X[i:i + 1], g[i:i + 1])[0] for i in range(len(y))]
    assert out[BY_CONTENT] == manual
    np.testing.assert_allclose(probs[BY_CONTENT].sum(1), 1.0)
    assert [("happy", "sad")[k] for k in np.argmax(probs[BY_CONTENT], 1)] == manual
    # a content seen in one emotion only would leave its held-out clip without a reference
    one_sided = bm.MotionDataset(tuple(
        bm.Trial(t.actors, {**t.labels, "content": t.labels["emotion"]}, t.name)
        for t in data.trials), {f: v for f, v in data.levels.items() if f != "content"})
    assert _content_groups(one_sided, "emotion") is None
    assert BY_CONTENT not in _baselines(one_sided, "emotion")[0]
    assert _content_groups(make_tiny_dataset(), "emotion") is None  # no content labels


@pytest.mark.slow
def test_cli_infer_takes_the_clips_action(model, data, tmp_path, capsys):
    import json

    from bayesmotion.app.cli import main

    from .test_cli import one_line_error

    path = tmp_path / "ref.npz"
    model.save(path)
    trial = data.trials[4]
    clips = []
    for a, m in enumerate(trial.actors):
        clips.append(str(tmp_path / f"actor{a}.bvh"))
        bm.write_bvh(m, clips[-1])
    assert "relative to each clip's 'content'" in one_line_error(
        capsys, ["infer", str(path), *clips, "--couple", "c1"])
    assert "'wave' is not among" in one_line_error(
        capsys, ["infer", str(path), *clips, "--couple", "c1", "--reference", "wave"])
    assert main(["infer", str(path), *clips, "--couple", "c1", "--json",
                 "--reference", trial.labels["content"]]) == 0
    assert json.loads(capsys.readouterr().out)["label"] in ("happy", "sad")
    assert "needs pose_space='affective'" in one_line_error(
        capsys, ["fit", "builtin:handshakes", "--out", str(tmp_path / "m.npz"),
                 "--pose-reference", "content"])
