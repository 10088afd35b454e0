"""Affective pose features and movement features against hand-computed values."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.features import (
    BANDAI_MAP,
    CMU_MAP,
    POSE_FEATURE_NAMES,
    SEMANTIC_JOINTS,
    JointMap,
    affective_features,
    body_frame_pose,
    clip_features,
    clip_features_from_positions,
    joint_map_for,
    movement_features,
    movement_features_from_positions,
    pose_features,
)

IDENTITY = JointMap(**{k: k for k in SEMANTIC_JOINTS})

# A stick figure facing +Z (left = +X), drawn so every feature has a closed form.
FIGURE = {
    "root": (0, 0, 0), "spine": (0, 1, 0), "neck": (0, 2, 0), "head": (0, 3, 0),
    "l_shoulder": (1, 2, 0), "r_shoulder": (-1, 2, 0),
    "l_elbow": (2, 2, 0), "r_elbow": (-2, 2, 0),
    "l_hand": (3, 2, 0), "r_hand": (-2, 3, 0),        # left arm straight, right forearm up
    "l_hip": (1, 0, 0), "r_hip": (-1, 0, 0),
    "l_knee": (1, -2, 0), "r_knee": (-1, -2, 0),
    "l_foot": (1, -4, 0), "r_foot": (-1, -2, 2),      # left leg straight, right shin forward
    "l_toe": (1, -4, 1), "r_toe": (-1, -4, 1),
}
NAMES = tuple(FIGURE)
POSE = np.array([FIGURE[k] for k in NAMES], dtype=float)

deg = lambda c: np.degrees(np.arccos(c))
EXPECTED = {
    "angle_spine_shoulders": 90.0,
    "angle_spine_hands": deg(-1 / np.sqrt(5)),      # (-2,2,0)·(3,1,0) = -4 over 2√2·√10
    "angle_l_elbow": 180.0,
    "angle_r_elbow": 90.0,
    "angle_neck_head_l_shoulder": 90.0,
    "angle_neck_head_r_shoulder": 90.0,
    "angle_root_head_l_knee": deg(-2 / np.sqrt(5)),  # (0,3,0)·(1,-2,0) = -6 over 3·√5
    "angle_root_head_r_knee": deg(-2 / np.sqrt(5)),
    "angle_root_feet": deg(8 / 9),                   # (1,-4,1)·(-1,-4,1) = 16 over 18
    "angle_l_knee": 180.0,
    "angle_r_knee": 90.0,
    "ratio_l_hand_neck_root": 3 / np.sqrt(13),
    "ratio_r_hand_neck_root": np.sqrt(5) / np.sqrt(13),
    "ratio_hands_torso": np.sqrt(26) / 2,
    "ratio_feet_torso": 1.0,
    "area_shoulders_spine_root": 0.5,                # base 2, heights 1 and 2
    "area_hands_spine_root": 4 / 6.5,                # shoelace: |-8|/2 over |-13|/2
    "area_hands_neck_feet_root": 1.5 / np.sqrt(17),  # |(0,2,8)|/2 = √17
}


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_names_and_expected_table_agree():
    assert len(POSE_FEATURE_NAMES) == 18 and set(EXPECTED) == set(POSE_FEATURE_NAMES)
    kinds = [n.split("_")[0] for n in POSE_FEATURE_NAMES]
    assert (kinds.count("angle"), kinds.count("ratio"), kinds.count("area")) == (11, 4, 3)


def test_pose_features_hand_computed():
    got = pose_features(POSE[None], NAMES, IDENTITY)[0]
    want = np.array([EXPECTED[n] for n in POSE_FEATURE_NAMES])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_pose_features_invariant_to_similarity_transforms():
    rng = np.random.default_rng(0)
    P = POSE[None] + 0.3 * rng.normal(size=(20, len(NAMES), 3))
    ref = pose_features(P, NAMES, IDENTITY)
    R = random_rotation(rng)
    moved = 7.3 * P @ R.T + np.array([4.0, -2.0, 11.0])
    np.testing.assert_allclose(pose_features(moved, NAMES, IDENTITY), ref, rtol=1e-9, atol=1e-9)


def test_pose_features_any_leading_shape_and_joint_order():
    perm = np.random.default_rng(1).permutation(len(NAMES))
    shuffled = pose_features(POSE[perm][None, None], [NAMES[i] for i in perm], IDENTITY)
    assert shuffled.shape == (1, 1, 18)
    np.testing.assert_allclose(shuffled[0, 0], pose_features(POSE, NAMES, IDENTITY), atol=1e-12)


def test_degenerate_ratio_is_nan_without_warning():
    P = POSE.copy()
    P[NAMES.index("l_hand")] = P[NAMES.index("root")]    # hand on the root: |l_hand root| = 0
    f = dict(zip(POSE_FEATURE_NAMES, pose_features(P, NAMES, IDENTITY), strict=True))
    assert np.isnan(f["ratio_l_hand_neck_root"]) and np.isfinite(f["angle_l_elbow"])


def test_joint_map_detection_and_errors():
    assert joint_map_for(tuple(CMU_MAP.__dict__.values())) is CMU_MAP
    assert joint_map_for(list(BANDAI_MAP.__dict__.values()) + ["joint_Root"]) is BANDAI_MAP
    with pytest.raises(bm.BayesmotionError, match=r"cmu: missing \[.*'Hips'.*bandai: missing"):
        joint_map_for(NAMES)
    with pytest.raises(bm.BayesmotionError, match="lacks the joints .*'head'"):
        pose_features(POSE[:3], NAMES[:3], IDENTITY)


def walker(T=400, fps=100.0, radius=5.0, speed=1.5):
    """The figure walking a circle of ``radius`` at ``speed``, facing along its path.

    Root (x, z) = (R cos φ - R, R sin φ): at φ = 0 it heads +Z, then bends towards -X, the
    figure's right, so the heading is θ = -φ (clockwise about +Y) and the body is turned by θ.
    """
    phi = speed * np.arange(T) / fps / radius
    root = radius * np.stack([np.cos(phi) - 1, np.zeros(T), np.sin(phi)], -1)
    body = np.einsum("tij,kj->tki", np.stack([rot_y(-p) for p in phi]), POSE)
    return root[:, None] + body


def test_movement_features_on_a_circle():
    fps, radius, speed, L = 100.0, 5.0, 4.0, 4.0   # L = 2 + 2; feet glide too fast for contact
    m = movement_features_from_positions(walker(400, fps, radius, speed), NAMES, fps, IDENTITY)
    inner = slice(60, -60)                                   # away from the smoothing edges
    np.testing.assert_allclose(m["speed"][1:-1], speed / L * np.sinc(speed / radius / fps / np.pi),
                               rtol=1e-9)                    # chord, not arc: R sin δ per frame
    np.testing.assert_allclose(m["root_height"], 0.0, atol=1e-12)
    np.testing.assert_allclose(m["turn_rate"][1:-1], -speed / radius, rtol=1e-9)
    # a 101-frame moving average of points on a circle lies on a circle of radius
    # R·mean(cos kδ), k = -50..50; central differences give the curvature of that circle exactly
    delta = speed / radius / fps
    shrunk = radius * np.mean(np.cos(delta * np.arange(-50, 51)))
    np.testing.assert_allclose(m["curvature"][inner], -L / shrunk, rtol=1e-6)
    np.testing.assert_allclose(m["speed_lowpass"][inner], m["speed"][inner], rtol=1e-9)
    assert not m["contacts"].any() and m["step_frequency"] == 0.0


def stepper(T=400, fps=100.0, period=1.0):
    """The figure marking time: each foot (ankle and toe) lifts 0.5 L for half a period."""
    s = np.sin(2 * np.pi * np.arange(T) / fps / period)
    P = np.repeat(POSE[None], T, axis=0)
    for side, h in (("l", np.maximum(s, 0)), ("r", np.maximum(-s, 0))):
        for j in (f"{side}_foot", f"{side}_toe"):
            P[:, NAMES.index(j), 1] += 0.5 * 4.0 * h
    return P


def test_contacts_phase_and_step_frequency():
    m = movement_features_from_positions(stepper(), NAMES, 100.0, IDENTITY)
    # left down (speed 0) on frames 51-99, 151-199, ...; right on 0-49, 101-149, ...:
    # footsteps at 51, 101, ..., 351, every half period -> 2 steps per second
    onsets = np.nonzero(m["contacts"][1:] & ~m["contacts"][:-1])
    np.testing.assert_array_equal(onsets[0] + 1, [51, 101, 151, 201, 251, 301, 351])
    np.testing.assert_array_equal(onsets[1], [0, 1, 0, 1, 0, 1, 0])
    assert m["step_frequency"] == pytest.approx(2.0, rel=1e-12)
    ph = m["phase"]
    assert np.isnan(ph[:51]).all() and np.isnan(ph[352:]).all()
    np.testing.assert_allclose(ph[[51, 76, 101, 126, 151]], [0, np.pi / 2, np.pi, 1.5 * np.pi, 0],
                               atol=1e-12)
    np.testing.assert_allclose(m["speed"], 0.0, atol=1e-12)


@pytest.fixture(scope="module")
def real(cmu_files, bandai_root):
    """Two real clips with their FK positions, computed once (FK compiles per clip shape)."""
    out = {}
    for path in (cmu_files[0], bandai_root / "data" / "dataset-1_walk-left_happy_001.bvh"):
        motion = bm.read_bvh(path)
        out[path.stem] = (motion, motion.positions())
    return out


def test_movement_features_invariant_on_real_walk(real):
    motion, P = real["dataset-1_walk-left_happy_001"]
    names, fps = motion.skeleton, motion.fps
    ref = movement_features_from_positions(P, names, fps)
    alpha = 0.7
    moved = 2.5 * P @ rot_y(alpha).T + np.array([300.0, 12.0, -40.0])
    got = movement_features_from_positions(moved, names, fps)
    for key, value in ref.items():
        shift = alpha if key == "heading" else 0.0     # heading turns with the world
        if value.dtype == bool:
            np.testing.assert_array_equal(got[key], value, err_msg=key)
        else:
            np.testing.assert_allclose(got[key], value + shift, rtol=1e-7, atol=1e-9,
                                       err_msg=key)
    np.testing.assert_allclose(clip_features_from_positions(moved, names, fps),
                               clip_features_from_positions(P, names, fps), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(body_frame_pose(moved, names), body_frame_pose(P, names),
                               atol=1e-9)


def test_real_walk_gait_is_plausible(real):
    motion, P = real["dataset-1_walk-left_happy_001"]
    m = movement_features_from_positions(P, motion.skeleton, motion.fps)
    assert 1.4 < m["step_frequency"] < 2.4                       # footsteps per second
    assert np.all((m["contacts"].mean(0) > 0.35) & (m["contacts"].mean(0) < 0.8))
    assert 0.8 < np.median(m["speed"]) < 2.5                     # leg lengths per second
    assert np.all(np.isfinite(m["curvature"]))


def test_real_pose_features_finite_and_in_range(real):
    for name, (motion, P) in real.items():
        F = pose_features(P, motion.skeleton)
        assert F.shape == (motion.n_frames, 18) and np.all(np.isfinite(F)), name
        angles = F[:, :11]
        assert np.all((angles > 0) & (angles <= 180)), name
        knees = F[:, [POSE_FEATURE_NAMES.index("angle_l_knee"),
                      POSE_FEATURE_NAMES.index("angle_r_knee")]]
        assert np.all(knees > 60), name                            # no knee folds past 120°
        assert np.all(F[:, 11:] > 0), name
        c = clip_features_from_positions(P, motion.skeleton, motion.fps)
        assert c.shape == (45,) and np.all(np.isfinite(c)), name


def test_motion_level_wrappers_match_positions_api():
    """affective_features / movement_features / clip_features(motion) run FK, then the same."""
    # a star skeleton: every joint hangs off the root at its FIGURE offset; the root translates
    sk = bm.Skeleton(NAMES, [-1] + [0] * (len(NAMES) - 1), POSE,
                     [("Xposition", "Yposition", "Zposition")] + [()] * (len(NAMES) - 1))
    values = walker(T=120)[:, 0]                     # root path on the circle
    motion = bm.Motion(sk, values, fps=100.0)
    Pm = motion.positions()
    np.testing.assert_allclose(Pm, POSE[None] + values[:, None], atol=1e-12)
    np.testing.assert_allclose(affective_features(motion, IDENTITY),
                               pose_features(Pm, NAMES, IDENTITY), atol=1e-12)
    np.testing.assert_allclose(clip_features(motion, IDENTITY),
                               clip_features_from_positions(Pm, NAMES, 100.0, IDENTITY))
    assert movement_features(motion, IDENTITY)["speed"].shape == (120,)
