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
        del meta["spec"]["relative_to"]
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


# ------------------------------------------------ poses relative to a group (relative_to)
@pytest.fixture(scope="module")
def relative_model(tiny_data):
    """The tiny handshakes read relative to their repetition (three groups, each holding a
    happy and a sad trial)."""
    spec = bm.HGPDM(latent_dim=3, interaction_dim=3, pose_space="affective",
                    relative_to="repetition")
    return spec.fit(tiny_data, max_iter=60, progress=False)


def test_relative_to_is_checked():
    assert bm.HGPDM().relative_to is None
    with pytest.raises(BayesmotionError, match="use pose_space='affective'"):
        bm.HGPDM(relative_to="content")
    with pytest.raises(BayesmotionError, match="leave nothing to tell the emotions apart"):
        bm.HGPDM(pose_space="affective", relative_to="emotion")
    with pytest.raises(BayesmotionError, match="a label name such as 'content'"):
        bm.HGPDM(pose_space="affective", relative_to=3)
    spec = bm.HGPDM(pose_space="affective", relative_to="content",
                    interaction_factors=("emotion",), dynamics_factors=("emotion",))
    assert bm.HGPDM.from_dict(spec.to_dict()) == spec


def test_codec_subtracts_each_groups_training_mean(tiny_data):
    motions = [t.actors[0] for t in tiny_data]
    groups = [t.labels["repetition"] for t in tiny_data]
    plain = AffectiveCodec.fit(motions, root_mode="heading")
    codec = AffectiveCodec.fit(motions, root_mode="heading", relative_to="repetition",
                               groups=groups)
    assert codec.groups == ("0", "1", "2") and codec.offsets.shape == (3, 18)
    np.testing.assert_array_equal(codec.mean, plain.mean)
    np.testing.assert_array_equal(codec.scale, plain.scale)
    for g in codec.groups:  # each group's training frames are centred on zero
        Y = np.concatenate([codec.encode(m, group=g).Y
                            for m, h in zip(motions, groups, strict=True) if h == g])
        np.testing.assert_allclose(Y.mean(0), 0.0, atol=1e-9)
    m = motions[4]  # the numbers: standardised features minus the group's standardised mean
    F = affective_features(m)
    own = np.concatenate([affective_features(x) for x, h in zip(motions, groups, strict=True)
                          if h == "1"])
    np.testing.assert_allclose(codec.encode(m, group="1").Y,
                               (F - own.mean(0)) / plain.scale, rtol=1e-9, atol=1e-9)
    # a group the training motions lack: read relative to the mean of all training frames
    assert not codec.knows("9") and codec.knows("1") and plain.knows(None)
    np.testing.assert_array_equal(codec.encode(m, group="9").Y, plain.encode(m).Y)
    with pytest.raises(BayesmotionError, match="has no 'repetition' label"):
        codec.encode(m)
    with pytest.raises(BayesmotionError, match="have no 'repetition' label"):
        AffectiveCodec.fit(motions, root_mode="heading", relative_to="repetition",
                           groups=[*groups[:-1], None])


@pytest.mark.slow
def test_relative_model_infers_round_trips_and_flags_an_unknown_group(relative_model, tiny_data,
                                                                       tmp_path):
    import warnings

    from bayesmotion.data.motion import Trial
    from bayesmotion.emotion.ood import OutOfDistributionWarning

    model = relative_model
    assert all(c.relative_to == "repetition" for c in model.codecs)
    for a, codec in enumerate(model.codecs):  # the training poses are centred per group
        for g in codec.groups:
            rows = np.concatenate([np.full(t.n_frames, t.labels["repetition"] == g)
                                   for t in tiny_data])
            np.testing.assert_allclose(model.data.Y[a][rows].mean(0), 0.0, atol=1e-9)
    trial = tiny_data.trials[4]
    kw = {"couple": "c1", "n_steps": 60, "seed": 1}
    ep = bm.infer_emotion(model, trial, **kw)
    assert not ep.out_of_distribution and "unknown_group" not in ep.info["ood"]
    # the same clip without labels, its group given as a style: the same answer
    bare = Trial(trial.actors, {}, trial.name)
    given = bm.infer_emotion(model, bare, styles={"repetition": "1"}, **kw)
    np.testing.assert_allclose(given.mean, ep.mean, rtol=1e-9)
    with pytest.raises(BayesmotionError, match="has no 'repetition' label"):
        bm.infer_emotion(model, bare, **kw)
    with pytest.raises(BayesmotionError, match=r"styles\['repetition'\] must be the clip's"):
        bm.infer_emotion(model, bare, styles={"repetition": [0.5, 0.5]}, **kw)
    # the online iterator reads the group the same way (one prefix: the whole clip)
    online = list(bm.infer_online(model, bare, start=trial.n_frames,
                                  styles={"repetition": "1"}, **kw))
    assert len(online) == 1
    np.testing.assert_allclose(online[0].mean, ep.mean, rtol=1e-9)
    # a group no training trial had: flagged, its probabilities the prior's
    foreign = Trial(trial.actors, {**trial.labels, "repetition": "7"}, trial.name)
    with pytest.warns(OutOfDistributionWarning, match="'7' is none of the training trials'"):
        far = bm.infer_emotion(model, foreign, **kw)
    assert far.out_of_distribution
    assert far.info["ood"]["unknown_group"] == {"label": "repetition", "group": "7",
                                                "training_groups": ["0", "1", "2"]}
    assert far.info["in_distribution_weight"] == 0.0
    np.testing.assert_allclose(far.probabilities, [0.5, 0.5])
    # saved and loaded: the same groups, offsets and poses
    path = tmp_path / "relative.npz"
    model.save(path)
    back = bm.load(path)
    assert back.spec.relative_to == "repetition"
    for a, b in zip(model.codecs, back.codecs, strict=True):
        assert b.groups == a.groups
        np.testing.assert_array_equal(b.offsets, a.offsets)
    np.testing.assert_array_equal(clip_poses(back, trial)[0], clip_poses(model, trial)[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = bm.infer_emotion(back, trial, **kw)
    np.testing.assert_allclose(again.mean, ep.mean, rtol=1e-9)


def test_relative_model_refuses_what_it_cannot_read(relative_model, tiny_data, tmp_path):
    from bayesmotion.emotion.batch import infer_many
    from bayesmotion.evaluation.evaluate import online_sharpening

    def spec(**kw):
        return bm.HGPDM(latent_dim=2, interaction_dim=2, pose_space="affective", **kw)

    with pytest.raises(BayesmotionError, match=r"no 'contnet' label; their labels are \["):
        spec(relative_to="contnet").fit(tiny_data, max_iter=2, progress=False)
    with pytest.raises(BayesmotionError, match="is also a style factor"):
        spec(relative_to="repetition", interaction_factors=("emotion", "repetition")).fit(
            tiny_data, max_iter=2, progress=False)
    with pytest.raises(BayesmotionError, match="online_sharpening sets them"):
        online_sharpening(relative_model, tiny_data.trials[:1], styles={"repetition": "1"})
    pytest.importorskip("dask.distributed")
    with pytest.raises(BayesmotionError, match="clip files carry no labels"):
        infer_many(relative_model, [str(tmp_path / "a.bvh")], None, progress=False)


def test_relative_model_files_with_bad_groups_are_refused(relative_model, tmp_path):
    good = tmp_path / "good.npz"
    relative_model.save(good)
    no_offsets = _rewrite(good, tmp_path / "a.npz",
                          lambda k, v: None if k == "codec0/group_offsets" else v)
    with pytest.raises(ModelFileError, match="holds no group offsets"):
        bm.load(no_offsets)
    short = _rewrite(good, tmp_path / "b.npz",
                     lambda k, v: v[:2] if k == "codec1/group_offsets" else v)
    with pytest.raises(ModelFileError, match=r"at most 1e6 in size, with shape \(3, 18\)"):
        bm.load(short)
    huge = _rewrite(good, tmp_path / "e.npz",
                    lambda k, v: v + 1e9 if k == "codec0/group_offsets" else v)
    with pytest.raises(ModelFileError, match="at most 1e6 in size"):
        bm.load(huge)

    def spec_plain(meta):
        meta["spec"]["relative_to"] = None

    def twice(meta):
        meta["codecs"][0]["groups"] = ["0", "0", "1"]

    with pytest.raises(ModelFileError, match="does not match the codecs'"):
        bm.load(_with_meta(good, tmp_path / "c.npz", spec_plain))
    with pytest.raises(ModelFileError, match="distinct group names"):
        bm.load(_with_meta(good, tmp_path / "d.npz", twice))


@pytest.mark.slow
def test_cli_infers_a_relative_model_with_its_group(capsys, relative_model, tiny_data, tmp_path):
    import json

    from bayesmotion import write_bvh
    from bayesmotion.app.cli import main

    from .test_cli import one_line_error

    model = tmp_path / "relative.npz"
    relative_model.save(model)
    trial = tiny_data.trials[4]
    clips = [str(tmp_path / f"a{a}.bvh") for a in range(2)]
    for m, path in zip(trial.actors, clips, strict=True):
        write_bvh(m, path)
    assert "give the clips' 'repetition' with --group" in one_line_error(
        capsys, ["infer", str(model), *clips])
    assert main(["infer", str(model), *clips, "--json", "--couple", "c1", "--group", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    want = bm.infer_emotion(relative_model, trial, couple="c1")
    assert out["label"] == want.label and not out["out_of_distribution"]
    np.testing.assert_allclose(out["probabilities"], want.probabilities, rtol=1e-6, atol=1e-9)
    plain = tmp_path / "plain.npz"
    bm.HGPDM(latent_dim=2, interaction_dim=2, pose_space="affective").fit(
        tiny_data, max_iter=2, progress=False).save(plain)
    assert "--group is for models fitted with --relative-to" in one_line_error(
        capsys, ["infer", str(plain), *clips, "--group", "1"])
