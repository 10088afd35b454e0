"""The affective pose space: an H-GPDM whose bottom layer models the 18 pose features."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.codecs.affective import AffectiveCodec
from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.emotion.clip import clip_poses
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.features.pose import POSE_FEATURE_NAMES, affective_features

from .conftest import make_tiny_dataset
from .test_model import _rewrite, _with_meta


@pytest.fixture(scope="module")
def tiny_data():
    return make_tiny_dataset()


@pytest.fixture(scope="module")
def affective_model(tiny_data):
    spec = bm.HGPDM(latent_dim=3, interaction_dim=3, pose_space="affective")
    return spec.fit(tiny_data, max_iter=60, progress=False)


def test_pose_space_is_checked():
    assert bm.HGPDM().pose_space == "angles"
    with pytest.raises(BayesmotionError, match="pose_space must be one of angles/affective"):
        bm.HGPDM(pose_space="features")
    with pytest.raises(BayesmotionError, match="rest frames leave unchanged"):
        bm.HGPDM(pose_space="affective", rest_frames=True)
    with pytest.raises(BayesmotionError, match="standardises each feature"):
        bm.HGPDM(pose_space="affective", scaling="channel")


def test_codec_standardises_the_pose_features(tiny_data):
    motions = [t.actors[1] for t in tiny_data]
    codec = AffectiveCodec.fit(motions, root_mode="heading")
    assert codec.dim == 18 and codec.channel_names == POSE_FEATURE_NAMES
    Y = np.concatenate([codec.encode(m).Y for m in motions])
    np.testing.assert_allclose(Y.mean(0), 0.0, atol=1e-9)
    np.testing.assert_allclose(Y.std(0), 1.0, rtol=1e-9)
    m = motions[2]
    np.testing.assert_allclose(codec.encode(m).Y * codec.scale + codec.mean,
                               affective_features(m), rtol=1e-12, atol=1e-9)
    with pytest.raises(BayesmotionError, match="cannot generate motion"):
        codec.decode(codec.encode(m).Y)


@pytest.mark.slow
def test_model_fits_infers_and_round_trips(affective_model, tiny_data, tmp_path):
    model = affective_model
    assert all(isinstance(c, AffectiveCodec) for c in model.codecs)
    assert [Y.shape[1] for Y in model.data.Y] == [18, 18]
    # the fit moved: the objective fell from its PCA start
    assert model.diagnostics["objective"] < model.diagnostics["initial_objective"]
    trial = tiny_data.trials[4]
    ep = bm.infer_emotion(model, trial, couple="c1", n_steps=60, seed=1)
    assert ep.label == trial.labels["emotion"]
    path = tmp_path / "affective.npz"
    model.save(path)
    back = bm.load(path)
    assert back.spec.pose_space == "affective"
    for a, b in zip(model.codecs, back.codecs, strict=True):
        assert isinstance(b, AffectiveCodec)
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.scale, b.scale)
    np.testing.assert_array_equal(clip_poses(back, trial)[0], clip_poses(model, trial)[0])
    again = bm.infer_emotion(back, trial, couple="c1", n_steps=60, seed=1)
    np.testing.assert_allclose(again.mean, ep.mean, rtol=1e-9)
    with pytest.raises(BayesmotionError, match="cannot generate motion"):
        model.generate(emotion="happy", couple="c1", n_frames=10)


def test_bad_feature_scale_in_a_model_file_is_refused(affective_model, tmp_path):
    good = tmp_path / "good.npz"
    affective_model.save(good)
    bad = _rewrite(good, tmp_path / "bad.npz",
                   lambda k, v: -v if k == "codec0/feature_scale" else v)
    with pytest.raises(ModelFileError, match="scale positive"):
        bm.load(bad)


def test_walks_to_the_right_are_read_as_mirrored_walks(bandai_root):
    data = load_bandai(bandai_root, content=("walk-left", "walk-right"), fps=15.0)
    motions = [t.actors[0] for t in data]
    codec = AffectiveCodec.fit(motions, root_mode="heading", canonical_side=True)
    names = list(POSE_FEATURE_NAMES)
    left = [i for i, n in enumerate(names) if "_l_" in n or n.endswith("_l")]
    right = [names.index(names[i].replace("_l_", "_r_")) for i in left]
    assert left and len(left) == len(right)
    for t, m in zip(data, motions, strict=True):
        enc = codec.encode(m)
        assert enc.mirrored == (t.labels["content"] == "walk-right"), t.name
        F = enc.Y * codec.scale + codec.mean
        raw = affective_features(m)
        if enc.mirrored:  # the mirror image's left hand is the clip's right hand
            np.testing.assert_allclose(F[:, left], raw[:, right], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(F[:, right], raw[:, left], rtol=1e-9, atol=1e-9)
        else:
            np.testing.assert_allclose(F, raw, rtol=1e-9, atol=1e-9)


def test_cli_names_what_an_affective_model_cannot_do(capsys, affective_model, tmp_path):
    from .test_cli import one_line_error

    model = tmp_path / "a.npz"
    affective_model.save(model)
    assert "cannot generate motion" in one_line_error(
        capsys, ["generate", str(model), "--couple", "c1", "--out", str(tmp_path / "gen")])
    assert "drop rest_frames" in one_line_error(
        capsys, ["fit", "builtin:handshakes", "--out", str(tmp_path / "m.npz"),
                 "--pose-space", "affective", "--rest-frames"])
    assert not (tmp_path / "m.npz").exists()


def test_model_files_before_pose_spaces_load_as_joint_angle_models(tiny_model, tmp_path):
    from bayesmotion.codecs.pose import PoseCodec

    good = tmp_path / "angles.npz"
    tiny_model.save(good)

    def strip(meta):
        del meta["spec"]["pose_space"]
        for c in meta["codecs"]:
            del c["pose_space"]

    old = bm.load(_with_meta(good, tmp_path / "old.npz", strip))
    assert old.spec.pose_space == "angles"
    assert all(isinstance(c, PoseCodec) for c in old.codecs)
    np.testing.assert_array_equal(old.data.Y[0], tiny_model.data.Y[0])


def test_inconsistent_pose_space_metadata_is_refused(affective_model, tmp_path):
    good = tmp_path / "good.npz"
    affective_model.save(good)

    def angles_spec(meta):
        meta["spec"]["pose_space"] = "angles"

    def list_codec(meta):
        meta["codecs"][0] = ["not", "a", "mapping"]

    with pytest.raises(ModelFileError, match="does not match its codecs"):
        bm.load(_with_meta(good, tmp_path / "a.npz", angles_spec))
    with pytest.raises(ModelFileError, match="codec metadata must be a mapping"):
        bm.load(_with_meta(good, tmp_path / "b.npz", list_codec))


def test_posterior_of_an_affective_model_samples_and_refuses_generation(affective_model):
    import warnings

    with warnings.catch_warnings():  # 20 steps: a look, not a converged chain
        warnings.simplefilter("ignore")
        post = bm.sample_posterior(affective_model, n_steps=20, burn=5, thin=1, progress=False)
    assert post.idata.posterior.sizes["draw"] == 15
    assert np.all(np.isfinite(post.idata.sample_stats["lp"].values))
    with pytest.raises(BayesmotionError, match="cannot generate motion"):
        post.generate(emotion="happy", couple="c1", n_frames=10)
