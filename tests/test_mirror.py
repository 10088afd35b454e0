"""Left-right mirroring: exact in world positions, on symmetric, half-turned and measured
(asymmetric) skeletons; the label-free canonical side on real walks; rest frames that move
joint angles away from gimbal lock without moving a joint."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import bayesmotion as bm
from bayesmotion.data import Motion, Skeleton
from bayesmotion.data.fk import euler_matrices
from bayesmotion.data.mirror import (
    _euler_tracks,
    canonical_side,
    lateral_ratio,
    mirror,
    mirror_pairs,
    mirror_plan,
    reframe,
    rest_frames,
    world_and_local,
)
from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.errors import BayesmotionError

ROOT6 = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
ROT3 = ("Zrotation", "Xrotation", "Yrotation")


def _half_turned_skeleton() -> Skeleton:
    """Hips, Spine and two arms; the right arm's frames are turned half a turn from the mirrored
    left ones (its bones point along +x locally, as the left's, although they hang the other
    way), as in Bandai's rig."""
    names = ("Hips", "Spine", "Arm_L", "Hand_L", "Arm_R", "Hand_R")
    parents = (-1, 0, 1, 2, 1, 4)
    offsets = np.array([[0, 0, 0], [0, 10, 0], [5, 0, 0], [10, 0, 0], [-5, 0, 0], [10, 0, 0.]])
    ends = {3: np.array([3.0, 1.0, 0.0]), 5: np.array([3.0, -1.0, 0.0])}
    return Skeleton(names, parents, offsets, (ROOT6,) + (ROT3,) * 5, ends)


def _random_motion(sk: Skeleton, T: int = 30, seed: int = 0, walk=(0.0, 0.0),
                   sway: float = 20.0) -> Motion:
    """Random joint angles; the hips sway by up to ``sway`` degrees and travel by ``walk``
    (x, z) per frame."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(-60, 60, size=(T, sk.n_channels))
    v[:, 3:6] = rng.uniform(-sway, sway, size=(T, 3))
    v[:, 0] = walk[0] * np.arange(T)
    v[:, 1] = 90.0
    v[:, 2] = walk[1] * np.arange(T)
    # the right arm hangs the other way: its rest is a half turn about the vertical
    v[:, sk.channel_offsets[4] + 2] += 180.0
    return Motion(sk, v, 30.0, "synthetic")


def _position_perm(sk: Skeleton, perm: np.ndarray) -> np.ndarray:
    """The partner permutation extended to ``positions(with_end_sites=True)``'s end sites."""
    ends = sorted(sk.end_sites)
    return np.concatenate([perm, [sk.n_joints + ends.index(perm[j]) for j in ends]])


def _check_exact(m: Motion, plan, axis: int = 0) -> Motion:
    """The mirror is the world reflection of the horizontal ``axis`` (Y stays up), joints
    swapped with their partners."""
    flip = np.ones(3)
    flip[axis] = -1.0
    np.testing.assert_array_equal(plan.reflection, np.diag(flip))
    mm = mirror(m, plan)
    assert mm.skeleton.same_layout(m.skeleton) and mm.values.shape == m.values.shape
    P, Q = m.positions(True), mm.positions(True)
    expected = P[:, _position_perm(m.skeleton, plan.perm)] * flip
    np.testing.assert_allclose(Q, expected, atol=1e-9 * m.skeleton.size())
    back = mirror(mm, plan)  # an involution in positions
    np.testing.assert_allclose(back.positions(True), P, atol=1e-9 * m.skeleton.size())
    return mm


def test_half_turned_frames_are_found_and_positions_are_exact():
    sk = _half_turned_skeleton()
    m = _random_motion(sk)
    plan = mirror_plan(sk, [m])
    assert [sk.names[j] for j in plan.perm] == ["Hips", "Spine", "Arm_R", "Hand_R", "Arm_L",
                                               "Hand_L"]
    np.testing.assert_allclose(plan.frames[1], np.eye(3))  # the midline keeps its frame
    # the arms' frames are the half turn that takes +x (the bone) to -x
    for j in (2, 3, 4, 5):
        np.testing.assert_allclose(plan.frames[j] @ [1.0, 0, 0], [-1.0, 0, 0])
    for axis in (0, 2):
        _check_exact(m, mirror_plan(sk, [m], axis=axis), axis)
    # the half-turned rig is symmetric under this plan: the skeleton is kept
    assert mirror(m, plan).skeleton is sk


def test_lateral_ratio_reads_the_walking_side_and_mirroring_negates_it():
    sk = _half_turned_skeleton()
    # Arm_L sits at +x of the hips and the hips barely turn, so walking along +x is to the left
    left = _random_motion(sk, walk=(3.0, 0.5), seed=1, sway=5.0)
    assert lateral_ratio(left) > 0.8
    plan = mirror_plan(sk, [left])
    assert lateral_ratio(mirror(left, plan), plan) == pytest.approx(-lateral_ratio(left, plan))
    ahead = _random_motion(sk, walk=(0.0, 3.0), seed=2, sway=5.0)
    assert abs(lateral_ratio(ahead)) < 0.1
    out, flipped = canonical_side([left, mirror(left, plan), ahead], plan=plan)
    assert flipped.tolist() == [False, True, False]
    np.testing.assert_allclose(out[1].positions(), left.positions(), atol=1e-9 * sk.size())


def test_measured_cmu_skeleton_is_mirrored_with_the_motion():
    data = bm.load_handshakes(fps=10, n_repetitions=1)
    motions = [a for t in list(data)[:2] for a in t.actors]
    sk = motions[0].skeleton
    perm = mirror_pairs(sk)
    pairs = {(sk.names[i], sk.names[j]) for i, j in enumerate(perm) if i < j}
    assert ("LeftArm", "RightArm") in pairs and ("LHipJoint", "RHipJoint") in pairs
    assert len(pairs) == 12 and perm[sk.index("LowerBack")] == sk.index("LowerBack")
    plan = mirror_plan(sk, motions)
    for m in motions:  # two subjects: two skeletons of one layout
        mm = _check_exact(m, plan)
        # a measured person is not exactly symmetric: the offsets travel with the motion
        assert mm.skeleton is not m.skeleton
        j, s = sk.index("LeftUpLeg"), sk.index("RightUpLeg")
        np.testing.assert_allclose(mm.skeleton.offsets[j],
                                   plan.frames[sk.parents[j]].T @ plan.reflection
                                   @ m.skeleton.offsets[s])
        assert lateral_ratio(mm, plan) == pytest.approx(-lateral_ratio(m, plan))


def test_bad_pairs_are_named():
    sk = _half_turned_skeleton()
    with pytest.raises(BayesmotionError, match="'Elbow_L', not a joint"):
        mirror_pairs(sk, {"Elbow_L": "Arm_R"})
    with pytest.raises(BayesmotionError, match="break the joint tree"):
        mirror_pairs(sk, {"Spine": "Arm_L"})
    with pytest.raises(BayesmotionError, match="axis must be 0"):
        mirror_plan(sk, axis=1)
    m = _random_motion(sk)
    other = mirror_plan(_half_turned_skeleton(), [m])
    with pytest.raises(BayesmotionError, match="plan is for 6 joints"):
        mirror(bm.load_handshakes(fps=10, n_repetitions=1)[0].actors[0], other)


def test_real_walks_to_the_right_are_the_ones_mirrored(bandai_root):
    data = load_bandai(bandai_root, content=("walk", "walk-back", "walk-left", "walk-right"),
                       fps=15.0)
    motions = [t.actors[0] for t in data]
    out, flipped = canonical_side(motions)
    assert [t.name for t, f in zip(data, flipped, strict=True) if f] == [
        t.name for t in data if t.labels["content"] == "walk-right"]
    plan = mirror_plan(motions[0].skeleton, motions)
    ratios = {t.name: lateral_ratio(m, plan) for t, m in zip(data, motions, strict=True)}
    for t in data:
        r, content = ratios[t.name], t.labels["content"]
        if content == "walk-left":
            assert r > 0.15, t.name
        elif content == "walk-right":
            assert r < -0.15, t.name
        else:  # straight ahead or back
            assert abs(r) < 0.15, t.name
    for m, mm, f in zip(motions, out, flipped, strict=True):
        if f:
            np.testing.assert_allclose(mm.positions(True), mirror(m, plan).positions(True))
    _check_exact(motions[0], plan)


def _mean_local_rotations(motions) -> np.ndarray:
    L = np.concatenate([world_and_local(m.skeleton, m.values)[1] for m in motions])
    return L.mean(0)


def test_rest_frames_centre_every_joint_and_keep_the_positions():
    data = bm.load_handshakes(fps=10, n_repetitions=1)
    motions = [t.actors[0] for t in data]
    sk = motions[0].skeleton
    B = rest_frames(motions)
    np.testing.assert_allclose(B[0], np.eye(3))  # the root carries the heading: kept
    for b in B:
        np.testing.assert_allclose(b @ b.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(b) == pytest.approx(1.0)
    out = [reframe(m, B) for m in motions]
    for m, o in zip(motions, out, strict=True):
        np.testing.assert_allclose(o.positions(True), m.positions(True), atol=1e-9 * sk.size())
        cols = sk.rotation_layout()[0][0]
        np.testing.assert_allclose(o.values[:, cols], m.values[:, cols], atol=1e-9)
    # every other joint's mean local rotation is now the identity (its projected mean)
    before, after = _mean_local_rotations(motions), _mean_local_rotations(out)
    for j in range(1, sk.n_joints):
        U, _, Vt = np.linalg.svd(after[j])
        np.testing.assert_allclose(U @ Vt, np.eye(3), atol=1e-9)
    assert max(np.linalg.norm(before[j] - np.eye(3)) for j in range(1, sk.n_joints)) > 0.5
    with pytest.raises(BayesmotionError, match=r"frames must be \(31, 3, 3\)"):
        reframe(motions[0], B[:3])
    with pytest.raises(BayesmotionError, match="at least one motion"):
        rest_frames([])


def test_rest_frames_take_bandais_spine_out_of_gimbal_lock(bandai_root):
    data = load_bandai(bandai_root, content=("walk", "walk-left", "walk-right"), fps=15.0)
    motions = [t.actors[0] for t in data]
    sk = motions[0].skeleton
    cols = sk.rotation_layout()[0][sk.index("Spine")]
    # ZXY with the middle angle near 90 degrees: Z and Y swing together, by more than a half
    # turn within some clips, while the spine itself barely moves
    assert all(np.abs(m.values[:, cols[1]]).min() > 60 for m in motions)
    assert max(np.ptp(m.values[:, cols[0]]) for m in motions) > 180
    B = rest_frames(motions)
    out = [reframe(m, B) for m in motions]
    assert max(np.abs(o.values[:, cols]).max() for o in out) < 30
    for m, o in zip(motions, out, strict=True):
        np.testing.assert_allclose(o.positions(True), m.positions(True), atol=1e-9 * sk.size())


def test_euler_angles_follow_the_reference_branch_and_stay_continuous():
    rng = np.random.default_rng(3)
    T = 200
    # a smooth ZXY track whose middle angle passes 90 degrees (gimbal lock) and back
    first = np.column_stack([40 * np.sin(np.linspace(0, 3, T)), np.linspace(60, 120, T),
                             30 * np.cos(np.linspace(0, 2, T))]) + rng.normal(0, 0.1, (T, 3))
    R = euler_matrices("ZXY", first)
    second = first + [180.0, 0.0, 180.0]
    second[:, 1] = 180.0 - first[:, 1]
    np.testing.assert_allclose(euler_matrices("ZXY", second), R, atol=1e-12)  # same rotations
    for ref in (first, second + 360.0):
        out = _euler_tracks(R[:, None], ["ZXY"], ref[:, None])[:, 0]
        np.testing.assert_allclose(euler_matrices("ZXY", out), R, atol=1e-9)
        assert np.abs(np.diff(out, axis=0)).max() < 20  # no branch or turn jumps
        np.testing.assert_allclose(out[0], ref[0], atol=1e-6)  # on the reference's branch



def _euler_nearest_one_by_one(R, order, reference):
    """The per-frame, per-joint loop _euler_tracks replaced: its reference."""
    a = Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)
    b = a + [180.0, 0.0, 180.0]
    b[:, 1] = 180.0 - a[:, 1]
    out, prev = np.empty_like(a), reference[0]
    for k in range(len(a)):
        ca = prev + (a[k] - prev + 180.0) % 360.0 - 180.0
        cb = prev + (b[k] - prev + 180.0) % 360.0 - 180.0
        prev = out[k] = ca if np.sum((ca - prev) ** 2) <= np.sum((cb - prev) ** 2) else cb
    return out + 360.0 * np.round((reference.mean(0) - out.mean(0)) / 360.0)


def test_euler_tracks_of_many_joints_equal_each_joints_own_track():
    rng = np.random.default_rng(4)
    T, orders = 150, ["ZXY", "XYZ", "YZX", "ZXY"]
    t = np.linspace(0, 1, T)[:, None]
    # smooth tracks, one through gimbal lock, references on both branches and other turns
    angles = rng.uniform(-150, 150, (len(orders), 1, 3)) + 80 * np.sin(5 * t + rng.uniform(
        0, 6, (len(orders), 1, 3)))
    angles[0, :, 1] = np.linspace(60, 120, T)
    R = np.stack([euler_matrices(o, a) for o, a in zip(orders, angles, strict=True)], 1)
    ref = rng.uniform(-400, 400, (T, len(orders), 3))
    got = _euler_tracks(R, orders, ref)
    for i, o in enumerate(orders):
        np.testing.assert_array_equal(got[:, i], _euler_nearest_one_by_one(R[:, i], o,
                                                                           ref[:, i]))
        np.testing.assert_allclose(euler_matrices(o, got[:, i]), R[:, i], atol=1e-9)

def test_names_of_other_exporters_pair_and_unmarked_names_are_refused():
    def chain(names):
        n = len(names)
        return Skeleton(tuple(names), (-1,) + (0,) * (n - 1), np.ones((n, 3)), ((ROT3),) * n)

    for hips, left, right in (("mixamorig:Hips", "mixamorig:LeftArm", "mixamorig:RightArm"),
                              ("pelvis", "upperarm_l", "upperarm_r"),
                              ("Hips", "Character1_LeftUpLeg", "Character1_RightUpLeg")):
        sk = chain([hips, left, right])
        assert mirror_pairs(sk).tolist() == [0, 2, 1]
        assert mirror_plan(sk).left.tolist() == [False, True, False]
    with pytest.raises(BayesmotionError, match="no left-right joint pairs found"):
        mirror_pairs(chain(["root", "armA", "armB"]))
    # explicit pairs decide the sides too (lateral_ratio reads them from the plan)
    sk = chain(["root", "armA", "armB"])
    plan = mirror_plan(sk, pairs={"armB": "armA"})
    assert plan.left.tolist() == [False, False, True]


def test_a_sideways_walk_mirrored_alone_keeps_its_static_root(bandai_root):
    data = load_bandai(bandai_root, content=("walk-left", "walk-right"), fps=15.0)
    for t in data:
        m = t.actors[0]
        mm = mirror(m)  # the default plan, from this clip alone
        cols = m.skeleton.rotation_layout()[0][0]  # joint_Root never rotates in real clips
        np.testing.assert_allclose(mm.values[:, cols], m.values[:, cols], atol=1e-9)
        _check_exact(m, mirror_plan(m.skeleton, [m]))
