"""Pose codec: lossless encode/decode, continuity, dropped channels, normalisation."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.data.representation import PoseCodec


@pytest.fixture(scope="module")
def cmu():
    return bm.load_cmu_handshake().actors


@pytest.mark.parametrize("mode", ["velocity", "partner", "absolute"])
def test_decode_encode_reproduces_joint_positions(cmu, mode):
    a, b = cmu
    codec = PoseCodec.fit([a], [b] if mode == "partner" else None, root_mode=mode)
    enc = codec.encode(a, b if mode == "partner" else None)
    back = codec.decode(enc.Y, enc.anchor, skeleton=a.skeleton, fps=a.fps)
    err = np.abs(back.positions() - a.positions()).max() / a.skeleton.size()
    assert err < 1e-6


def test_real_bandai_round_trip_and_constant_channels(bandai_files):
    m = bm.read_bvh(bandai_files[0])
    codec = PoseCodec.fit([m])
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
