"""Pose codec: lossless encode/decode, continuity, dropped channels, normalisation."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.codecs.pose import PoseCodec


@pytest.fixture(scope="module")
def cmu():
    return bm.load_cmu_handshake().actors


@pytest.mark.parametrize("mode", ["heading", "velocity", "partner", "absolute"])
def test_decode_encode_reproduces_joint_positions(cmu, mode):
    a, b = cmu
    codec = PoseCodec.fit([a], [b] if mode == "partner" else None, root_mode=mode)
    enc = codec.encode(a, b if mode == "partner" else None)
    back = codec.decode(enc.Y, enc.anchor, skeleton=a.skeleton, fps=a.fps)
    err = np.abs(back.positions() - a.positions()).max() / a.skeleton.size()
    assert err < 1e-6


@pytest.mark.parametrize("mode", ["heading", "velocity"])
def test_real_bandai_round_trip_and_constant_channels(bandai_files, mode):
    m = bm.read_bvh(bandai_files[0])
    codec = PoseCodec.fit([m], root_mode=mode)
    assert m.skeleton.names[codec.mover] == "Hips"  # joint_Root is static in Bandai files
    enc = codec.encode(m)
    back = codec.decode(enc.Y, enc.anchor, skeleton=m.skeleton, fps=m.fps)
    assert np.abs(back.positions() - m.positions()).max() / m.skeleton.size() < 1e-6
    assert codec.dim < m.skeleton.n_channels  # the constant position channels were dropped


def test_unwrapping_removes_360_degree_jumps():
    sk = bm.Skeleton(["r"], [-1], np.zeros((1, 3)),
                     [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation",
                       "Xrotation")])
    t = np.linspace(0, 2, 50)
    z = (170 + 40 * t + 180) % 360 - 180  # crosses +-180 once
    vals = np.zeros((50, 6))
    vals[:, 3] = z
    vals[:, 0] = t
    m = bm.Motion(sk, vals, 25.0)
    codec = PoseCodec.fit([m], root_mode="absolute")
    Y = codec.encode(m).Y * codec.scale + codec.mean
    zcol = list(codec.keep).index(3)
    assert np.abs(np.diff(Y[:, zcol])).max() < 5
    back = codec.decode(codec.encode(m).Y, fps=25.0)
    np.testing.assert_allclose(np.asarray(back.positions()), np.asarray(m.positions()),
                               atol=1e-9)


def test_type_scaling_keeps_physical_weighting(cmu):
    a, _ = cmu
    codec = PoseCodec.fit([a], scaling="type")
    kinds = codec._kinds()[codec.keep]
    rot = kinds == 0
    assert np.unique(codec.scale[rot]).size == 1  # one pooled scale for all rotations
    Y = codec.encode(a).Y
    np.testing.assert_allclose(Y.mean(0), 0, atol=1e-10)
    per = PoseCodec.fit([a], scaling="channel").encode(a).Y
    np.testing.assert_allclose(per.std(0), 1, rtol=1e-10)


def test_layout_mismatch_names_joints(cmu):
    a, _ = cmu
    codec = PoseCodec.fit([a])
    sk = a.skeleton
    names = list(sk.names)
    names[3] = "Knee"
    other = bm.Motion(bm.Skeleton(names, sk.parents, sk.offsets, sk.channels), a.values, a.fps)
    with pytest.raises(bm.SkeletonMismatchError, match="LeftLeg"):
        codec.encode(other)


def _turned(motion, degrees, shift=(0.0, 0.0)):
    """The same motion rotated about the vertical axis through the origin and shifted."""
    from scipy.spatial.transform import Rotation

    sk = motion.skeleton
    v = motion.values.copy()
    j = 0
    idx, orders = sk.rotation_layout()
    pos = sk.position_layout()[j]
    turn = Rotation.from_euler("Y", degrees, degrees=True)
    R = turn * Rotation.from_euler(orders[j].upper(), v[:, idx[j]], degrees=True)
    v[:, idx[j]] = R.as_euler(orders[j].upper(), degrees=True)
    v[:, pos] = turn.apply(v[:, pos]) + np.array([shift[0], 0.0, shift[1]])
    return motion.replace(values=v)


def test_heading_mode_is_invariant_to_walking_direction(cmu):
    a, _ = cmu
    turned = _turned(a, 130.0, shift=(250.0, -40.0))
    # the same body motion, facing and travelling elsewhere: positions differ...
    assert np.abs(turned.positions() - a.positions()).max() > 100
    for mode, same in (("heading", True), ("velocity", False)):
        codec = PoseCodec.fit([a], root_mode=mode)
        d = np.abs(codec.encode(turned).Y - codec.encode(a).Y).max()
        assert (d < 1e-6) == same, (mode, d)
    codec = PoseCodec.fit([a], root_mode="heading")
    enc = codec.encode(turned)
    back = codec.decode(enc.Y, enc.anchor, skeleton=a.skeleton, fps=a.fps)
    np.testing.assert_allclose(back.positions(), turned.positions(), atol=1e-6 * a.skeleton.size())
    assert codec.channel_names[-1].endswith(":heading_rate")
    # the heading (anchor + integrated rate) of the turned clip is the original's + 130 deg
    heading = lambda e: e.anchor[2] + np.concatenate(
        [[0.0], np.cumsum(np.deg2rad(e.Y[1:, -1] * codec.scale[-1] + codec.mean[-1]) / a.fps)])
    turn = np.rad2deg(heading(codec.encode(turned)) - heading(codec.encode(a)))
    np.testing.assert_allclose((turn - 130.0 + 180.0) % 360.0 - 180.0, 0.0, atol=1e-6)


def test_heading_mode_needs_horizontal_translation():
    sk = bm.Skeleton(["r"], [-1], np.zeros((1, 3)),
                     [("Yposition", "Zrotation", "Xrotation", "Yrotation")])
    m = bm.Motion(sk, np.random.default_rng(0).normal(size=(20, 4)), 25.0)
    with pytest.raises(bm.BayesmotionError, match="horizontal position"):
        PoseCodec.fit([m], root_mode="heading")


def test_mover_is_the_joint_that_walks_in_most_clips(bandai_root):
    """Bandai's joint_Root sits at the origin in every walk-back clip but the short normal one,
    where it carries the translation; Hips carries the walk in the others."""
    walks = bm.load_bandai(bandai_root, content=["walk-back"], fps=7.5)
    motions = [t.actors[0] for t in walks]
    root = [np.ptp(m.values[:, :3], axis=0).max() for m in motions]
    assert max(root) > 50 and sorted(root)[-2] < 1e-9  # joint_Root moves in one clip only
    from bayesmotion.data.motion import find_mover

    assert motions[0].skeleton.names[find_mover(motions)] == "Hips"


@pytest.mark.parametrize("mode", ["heading", "velocity"])
def test_clips_a_whole_turn_apart_encode_alike(cmu, mode):
    """Unwrapping keeps one clip continuous; the codec's branch reference puts every clip of
    the same pose on the same 360-degree branch (training and new clips alike)."""
    a, _ = cmu
    rot = np.flatnonzero(a.rotation_mask())
    v = a.values.copy()
    v[:, rot[5]] += 360.0
    v[:, rot[9]] -= 720.0
    turned = a.replace(values=v)
    codec = PoseCodec.fit([a, turned], root_mode=mode)
    np.testing.assert_allclose(codec.encode(turned).Y, codec.encode(a).Y, atol=1e-9)
    enc = codec.encode(turned)
    back = codec.decode(enc.Y, enc.anchor, skeleton=a.skeleton, fps=a.fps)
    np.testing.assert_allclose(back.positions(), a.positions(), atol=1e-6 * a.skeleton.size())


def test_heading_has_no_gimbal_lock_on_any_single_bandai_walk(bandai_files):
    """The rotation left after removing the heading stays near the rest pose whichever local
    axis defines the heading (fitted on one clip the choice varies): no 180-degree jumps."""
    walks = [f for f in bandai_files if "_walk" in f.name]
    checked = 0
    for f in walks:
        m = bm.read_bvh(f)
        codec = PoseCodec.fit([m], root_mode="heading")
        Y = codec.encode(m).Y * codec.scale + codec.mean
        cols, _ = codec._mover_rotation(m.skeleton)
        mover = np.isin(codec.keep, cols)
        if not mover.any():  # walk-back normal alone: its static joint_Root carries the walk
            continue
        checked += 1
        # raw BVH steps of this joint are below 16 deg per frame at 30 fps; 180 in gimbal lock
        assert np.abs(np.diff(Y[:, mover], axis=0)).max() < 20, f.name
    assert checked >= len(walks) - 1


def test_one_actor_codec_fields_survive_save_and_load(bandai_root, tmp_path):
    """mover, heading axis and branch (with NaNs) are saved; a file without them (written
    before they existed) still loads, with no branch shift and the first joint as mover."""
    walks = bm.load_bandai(bandai_root, content=["walk"], fps=5.0)
    walks = bm.MotionDataset(tuple(t.select(slice(0, 12)) for t in walks), walks.levels)
    m = bm.HGPDM(latent_dim=2, interaction_dim=2).fit(walks, max_iter=2, progress=False)
    path = tmp_path / "walk.npz"
    m.save(path)
    back = bm.load(path)
    a, b = m.codecs[0], back.codecs[0]
    assert (b.root_mode, b.mover, b.heading_axis) == ("heading", a.mover, a.heading_axis)
    np.testing.assert_array_equal(b.branch, a.branch)
    clip = walks[0].actors[0]
    np.testing.assert_array_equal(b.encode(clip).Y, a.encode(clip).Y)
    # an older file: no branch entries
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if not k.endswith("branch")}
    assert len(arrays) < len(np.load(path).files)
    old = tmp_path / "old.npz"
    np.savez(old, **arrays)
    assert bm.load(old).codecs[0].branch is None


def test_decode_defaults_to_the_rate_the_codec_was_fitted_at(tmp_path):
    """decode uses the codec's rate, not 30 fps (a 15 fps walk must not come back with its
    root integrated at 1/30 s per frame, labelled 30 fps). The rate is also kept in model
    files."""
    import bayesmotion as bm

    trial = bm.load_handshakes(fps=5.0)[0]
    m = trial.actors[0]
    for mode in ("velocity", "heading"):
        codec = PoseCodec.fit([m], root_mode=mode)
        assert codec.fps == m.fps
        enc = codec.encode(m)
        back = codec.decode(enc.Y, enc.anchor, skeleton=m.skeleton)
        assert back.fps == m.fps
        np.testing.assert_allclose(back.positions(), m.positions(), atol=1e-9)
    model = bm.HGPDM(latent_dim=2, interaction_dim=2).fit(
        bm.load_handshakes(fps=5.0).take([0, 1]), max_iter=2, progress=False)
    model.save(tmp_path / "m.npz")
    assert bm.load(tmp_path / "m.npz").codecs[0].fps == model.fps == 5.0
    with pytest.raises(bm.BayesmotionError, match="fps must be positive"):
        codec.decode(enc.Y, enc.anchor, fps=0.0)
