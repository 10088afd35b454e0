"""Naturalness proxies against hand-made motions with closed-form answers."""

import numpy as np
import pytest

from bayesmotion.datasets import load_cmu_handshake
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.naturalness import (
    ANGLE_NAMES,
    NaturalnessReference,
    joint_angles,
    naturalness,
    naturalness_from_positions,
)
from bayesmotion.features import SEMANTIC_JOINTS, JointMap

IDENTITY = JointMap(**{k: k for k in SEMANTIC_JOINTS})
FPS = 30.0
# A figure facing +Z (left = +X), arms hanging straight, legs straight: L = 1 + 1 = 2.
STAND = {
    "root": (0, 2, 0), "spine": (0, 2.5, 0), "neck": (0, 3, 0), "head": (0, 3.4, 0),
    "l_shoulder": (0.4, 3, 0), "r_shoulder": (-0.4, 3, 0),
    "l_elbow": (0.4, 2.5, 0), "r_elbow": (-0.4, 2.5, 0),
    "l_hand": (0.4, 2.0, 0), "r_hand": (-0.4, 2.0, 0),
    "l_hip": (0.2, 2, 0), "r_hip": (-0.2, 2, 0),
    "l_knee": (0.2, 1, 0), "r_knee": (-0.2, 1, 0),
    "l_foot": (0.2, 0, 0), "r_foot": (-0.2, 0, 0),
    "l_toe": (0.2, 0, 0.2), "r_toe": (-0.2, 0, 0.2),
}
L = 2.0
IDX = {k: i for i, k in enumerate(SEMANTIC_JOINTS)}


def still(T: int) -> np.ndarray:
    """(T, 18, 3) the standing figure, unmoving."""
    P = np.array([STAND[k] for k in SEMANTIC_JOINTS], dtype=float)
    return np.repeat(P[None], T, axis=0)


def score(P, reference=None, **kw):
    return naturalness_from_positions(P, SEMANTIC_JOINTS, FPS, reference, IDENTITY, **kw)


def ref_of(*clips):
    return NaturalnessReference.from_positions(list(clips), SEMANTIC_JOINTS, FPS, IDENTITY)


def bend_knees(P: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """Flex both knees by theta (T,) radians: shank and foot turn rigidly about the knee's +X."""
    P = P.copy()
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    for side in "lr":
        knee = P[:, IDX[f"{side}_knee"]]
        for j in (f"{side}_foot", f"{side}_toe"):
            d = P[:, IDX[j]] - knee          # rotate about +X: y' = y c - z s, z' = y s + z c
            P[:, IDX[j]] = knee + np.concatenate(
                [d[:, :1], d[:, 1:2] * c - d[:, 2:] * s, d[:, 1:2] * s + d[:, 2:] * c], axis=1)
    return P


# --------------------------------------------------------------------------- foot sliding
def test_planted_feet_do_not_slide_while_the_body_moves():
    T = 40
    P = still(T)
    t = np.arange(T) / FPS
    upper = [IDX[k] for k in SEMANTIC_JOINTS if not k.endswith(("foot", "toe"))]
    P[:, upper, 2] += 1.0 * t[:, None]                   # the body leans along, feet stay
    n = score(P)
    assert n["foot_sliding"] == 0.0
    assert n["contact_fraction"] == 1.0


def test_sliding_feet_measure_their_speed_in_leg_lengths():
    T = 40
    P = still(T)
    P[..., 2] += 1.0 * (np.arange(T) / FPS)[:, None]    # everything glides at 1 unit/s
    n = score(P)
    assert n["contact_fraction"] == 1.0
    np.testing.assert_allclose(n["foot_sliding"], 1.0 / L, rtol=1e-12)
    # the ratio is to the reference clips' pooled sliding speed
    half = still(T)
    half[..., 2] += 0.5 * (np.arange(T) / FPS)[:, None]
    np.testing.assert_allclose(score(P, ref_of(half))["foot_sliding_ratio"], 2.0, rtol=1e-12)


def test_swinging_foot_is_not_in_contact_and_pivoting_toe_is_the_contact_point():
    T = 40
    t = np.arange(T) / FPS
    P = still(T)
    # right foot lifted 0.5 units (0.25 L) and swinging forward fast: no contact, no sliding
    for j in ("r_foot", "r_toe"):
        P[:, IDX[j], 1] += 0.5
        P[:, IDX[j], 2] += 6.0 * t
    P[20, [IDX["r_foot"], IDX["r_toe"]], 1] -= 0.5        # one frame (< 0.1 s) on the floor
    # left heel rises about the planted toe (10 -> 50 degrees): the ankle moves, the toe not
    phi = np.radians(np.linspace(10, 50, T))
    toe = P[:, IDX["l_toe"]]
    P[:, IDX["l_foot"]] = toe + 0.2 * np.stack([0 * phi, np.sin(phi), -np.cos(phi)], axis=1)
    n = score(P)
    assert n["foot_sliding"] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(n["contact_fraction"], 0.5)


# --------------------------------------------------------------------------- jerk
def test_constant_velocity_and_constant_acceleration_have_no_jerk():
    T = 30
    t = (np.arange(T) / FPS)[:, None]
    P = still(T)
    P[..., 0] += 0.7 * t
    P[..., 2] += 1.3 * t + 0.9 * t**2
    n = score(P)
    assert n["jerk"] < 1e-8 and n["jerk_local"] < 1e-8


def test_cubic_trajectory_has_its_analytic_jerk_and_ratio():
    T, c = 30, 0.4
    t = (np.arange(T) / FPS)[:, None]
    P, Q = still(T), still(T)
    P[..., 2] += c * t**3                               # d³z/dt³ = 6c for every joint
    Q[..., 2] += 2 * c * t**3
    np.testing.assert_allclose(score(P)["jerk"], 6 * c / L, rtol=1e-6)
    np.testing.assert_allclose(score(Q, ref_of(P))["jerk_ratio"], 2.0, rtol=1e-6)
    assert score(P)["jerk_local"] < 1e-8                # all of it is the global path's


def test_limb_jerk_shows_in_the_body_frame():
    T, c = 30, 0.4
    t = (np.arange(T) / FPS)[:, None]
    P = still(T)
    P[:, [IDX["l_hand"], IDX["r_hand"]], 2] += c * t**3   # 2 of 18 joints jerk at 6c
    n = score(P)
    np.testing.assert_allclose([n["jerk"], n["jerk_local"]], 6 * c / L * np.sqrt(2 / 18),
                               rtol=1e-6)


def test_jerk_needs_four_frames():
    with pytest.raises(BayesmotionError, match="4 frames"):
        score(still(3))


# --------------------------------------------------------------------------- joint limits
def test_knee_flexion_is_signed_about_the_body_left_axis():
    theta = np.radians(np.array([-15.0, 0.0, 30.0, 90.0]))
    P = bend_knees(still(4), theta)
    from bayesmotion.features.pose import semantic_positions

    A = joint_angles(semantic_positions(P, SEMANTIC_JOINTS, IDENTITY))
    for side in "lr":
        np.testing.assert_allclose(A[:, ANGLE_NAMES.index(f"{side}_knee_flexion")],
                                   np.degrees(theta), atol=1e-9)
    np.testing.assert_allclose(A[:, ANGLE_NAMES.index("l_elbow_flexion")], 0.0, atol=1e-9)
    np.testing.assert_allclose(A[:, ANGLE_NAMES.index("l_ankle")], 90.0, atol=1e-9)


def test_motion_beyond_the_reference_knee_range_is_flagged_frame_by_frame():
    T = 60
    u = np.linspace(0, 2 * np.pi, T)
    ref_flex, flex = 20 - 20 * np.cos(u), 30 - 30 * np.cos(u)        # up to 40 and 60 degrees
    ref = bend_knees(still(T), np.radians(ref_flex))
    P = bend_knees(still(T), np.radians(flex))
    n = score(P, ref_of(ref))
    expected = np.mean(flex > ref_flex.max() + 1e-9)
    assert 0 < expected < 1
    assert n["joint_limit_source"] == "reference"
    np.testing.assert_allclose(n["joint_limit_violations"], expected)
    np.testing.assert_allclose(n["joint_limit_exceedance"], flex.max() - ref_flex.max(),
                               atol=1e-9)
    for name, frac in n["violations_by_angle"].items():
        np.testing.assert_allclose(frac, expected if "knee" in name else 0.0)
    # a margin as wide as the exceedance absorbs it; the reference clip itself never violates
    wide = score(P, ref_of(ref), margin=n["joint_limit_exceedance"] + 1e-6)
    assert wide["joint_limit_violations"] == 0.0
    assert score(ref, ref_of(ref))["joint_limit_violations"] == 0.0


def test_anatomical_limits_without_reference():
    theta = np.radians(np.array([0.0, 45.0, 170.0, -20.0, 10.0]))
    n = score(bend_knees(still(5), theta))
    assert n["joint_limit_source"] == "anatomical"
    assert "jerk_ratio" not in n and "foot_sliding_ratio" not in n
    np.testing.assert_allclose(n["anatomical_violations"], 2 / 5)     # 170 and -20 degrees
    np.testing.assert_allclose(n["joint_limit_violations"], 2 / 5)
    np.testing.assert_allclose(n["joint_limit_exceedance"], 10.0, atol=1e-9)


# --------------------------------------------------------------------------- invariance, motions
def test_similarity_invariance():
    T = 50
    rng = np.random.default_rng(0)
    u = np.linspace(0, 4 * np.pi, T)
    P = bend_knees(still(T), np.radians(25 - 25 * np.cos(u)))
    P += 0.01 * rng.standard_normal(P.shape)
    P[..., 2] += np.linspace(0, 2, T)[:, None]
    a = np.radians(37.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    Q = 3.0 * P @ R.T + np.array([5.0, -1.0, 2.0])
    n, m = score(P, ref_of(P[::-1])), score(Q, ref_of(Q[::-1]))
    for k in ("foot_sliding", "contact_fraction", "jerk", "joint_limit_violations",
              "foot_sliding_ratio", "jerk_ratio", "anatomical_violations", "jerk_local",
              "jerk_local_ratio"):
        np.testing.assert_allclose(m[k], n[k], rtol=1e-9, atol=1e-12)


def test_real_clip_against_itself_and_frame_rate_guard():
    motion = load_cmu_handshake().actors[0]
    n = naturalness(motion, [motion])
    assert n["joint_limit_violations"] == 0.0
    np.testing.assert_allclose([n["foot_sliding_ratio"], n["jerk_ratio"], n["jerk_local_ratio"]],
                               1.0)
    assert all(np.isfinite(v) for v in n.values() if isinstance(v, float))
    # references at another rate are resampled to the motion's; a prebuilt one is checked
    half = motion.resample(motion.fps / 2)
    np.testing.assert_allclose(naturalness(half, [motion])["jerk_ratio"], 1.0)
    with pytest.raises(BayesmotionError, match="fps"):
        naturalness(half, NaturalnessReference.from_motions([motion]))
