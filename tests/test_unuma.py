"""Unuma Fourier model: round trips, planted periods, blending and emotion transfer."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.baselines.unuma import (
    blend,
    detect_period,
    emotion_component,
    fourier_eval,
    fourier_fit,
    motion_period,
    shift,
    superpose,
)

SKELETON = bm.Skeleton(
    ["root", "knee"], [-1, 0], [[0, 0, 0], [0, -1, 0]],
    [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"),
     ("Zrotation", "Yrotation", "Xrotation")])


def periodic_motion(period=1.1, fps=120.0, T=500, phase=0.0, amp=1.0, speed=80.0, seed=0):
    """Every channel a 5-harmonic series in t/period; the root also walks forward at `speed`."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / fps
    h = np.arange(1, 6)[:, None]
    a, b = rng.normal(size=(5, 9)) * 10 / h, rng.normal(size=(5, 9)) * 10 / h
    w = 2 * np.pi * np.outer(t + phase, h[:, 0]) / period
    V = rng.normal(size=9) * 5 + amp * (np.cos(w) @ a + np.sin(w) @ b)
    V[:, 2] += speed * t                                         # Z progression
    return bm.Motion(SKELETON, V, fps)


def test_round_trip_of_a_finite_fourier_series():
    m = periodic_motion()
    model = fourier_fit(m, n_harmonics=7, period=1.1)
    np.testing.assert_allclose(fourier_eval(model, m.n_frames).values, m.values, atol=1e-8)
    assert model.drift[2] == pytest.approx(80.0, rel=1e-10)
    np.testing.assert_allclose(np.delete(model.drift, 2), 0.0, atol=1e-10)
    np.testing.assert_allclose(model.a[5:], 0.0, atol=1e-10)   # harmonics 6, 7 are not there


def test_rotation_channels_are_unwrapped_before_fitting():
    t = np.arange(300) / 60.0
    V = np.zeros((300, 9))
    V[:, 6] = 170.0 + 30 * np.sin(2 * np.pi * t / 0.9)         # crosses 180 ...
    wrapped = V.copy()
    wrapped[:, 6] = (V[:, 6] + 180.0) % 360.0 - 180.0          # ... stored as -180..180
    model = fourier_fit(bm.Motion(SKELETON, wrapped, 60.0), 3, period=0.9)
    np.testing.assert_allclose(fourier_eval(model, 300).values[:, 6], V[:, 6], atol=1e-8)


@pytest.mark.parametrize("period", [0.83, 1.1, 1.37])
def test_planted_period_is_detected(period):
    m = periodic_motion(period=period, fps=120.0, T=600)
    assert motion_period(m) == pytest.approx(period, rel=0.01)
    noisy = m.values[:, 6:] + np.random.default_rng(1).normal(size=(600, 3))
    assert detect_period(noisy, 120.0) == pytest.approx(period, rel=0.01)


def test_detected_period_gives_a_close_fit():
    m = periodic_motion(period=1.1, T=600)
    model = fourier_fit(m, n_harmonics=6)
    err = np.abs(fourier_eval(model, m.n_frames).values - m.values).max()
    assert abs(model.period - 1.1) < 0.01 and err < 0.05 * np.ptp(m.values[:, 6:])


def test_period_detection_errors():
    with pytest.raises(bm.BayesmotionError, match="need two cycles"):
        detect_period(np.sin(np.arange(20.0))[:, None], 30.0)
    with pytest.raises(bm.BayesmotionError, match="need two cycles and a varying signal"):
        detect_period(np.ones((300, 2)), 30.0)


def test_blend_end_points_and_midpoint():
    fa = fourier_fit(periodic_motion(period=1.0, seed=1), 5, period=1.0)
    fb = fourier_fit(periodic_motion(period=1.4, seed=2, speed=120.0), 5, period=1.4)
    t = np.linspace(0, 3, 50)
    np.testing.assert_allclose(blend(fa, fb, 0.0).values(t), fa.values(t), atol=1e-12)
    np.testing.assert_allclose(blend(fa, fb, 1.0).values(t), fb.values(t), atol=1e-9)
    half = blend(fa, fb, 0.5)
    assert half.period == pytest.approx(1.2)
    # in normalised time u = t / P the blend is the average of the two cycles
    u = np.linspace(0, 1, 20)
    cyc = lambda f: f.values(u * f.period) - np.outer(u * f.period, f.drift)
    np.testing.assert_allclose(cyc(half), 0.5 * (cyc(fa) + cyc(fb)), atol=1e-9)
    # drift per cycle (stride length) is averaged: (80·1.0 + 120·1.4) / 2 over 1.2 s
    assert half.drift[2] == pytest.approx((80.0 + 168.0) / 2 / 1.2, rel=1e-9)
    far = blend(fa, fb, 1.5)                                     # extrapolation is allowed
    assert far.period == pytest.approx(1.6)


def test_shift_is_a_time_shift():
    f = fourier_fit(periodic_motion(), 5, period=1.1)
    t = np.linspace(0, 2, 40)
    np.testing.assert_allclose(shift(f, 0.37).values(t), f.values(t + 0.37), atol=1e-9)


def test_emotion_transfer_recovers_the_emotion_and_handles_phase():
    neutral = fourier_fit(periodic_motion(period=1.1, seed=3), 5, period=1.1)
    happy = fourier_fit(periodic_motion(period=0.9, seed=4, speed=120.0), 5, period=0.9)
    comp = emotion_component(happy, neutral, align=False)
    back = superpose(neutral, comp, 1.0)
    t = np.linspace(0, 2, 40)
    assert back.period == pytest.approx(0.9)
    np.testing.assert_allclose(back.values(t), happy.values(t), atol=1e-8)
    np.testing.assert_allclose(superpose(neutral, comp, 0.0).values(t), neutral.values(t),
                               atol=1e-12)
    # the same emotional motion recorded a third of a cycle later yields the same component
    late = shift(happy, 0.3)
    aligned = emotion_component(late, neutral)
    np.testing.assert_allclose(superpose(neutral, aligned).values(t),
                               superpose(neutral, emotion_component(happy, neutral)).values(t),
                               atol=1e-6)


def test_different_skeletons_are_refused():
    other = bm.Skeleton(["root"], [-1], [[0, 0, 0]], [("Xposition", "Yposition", "Zposition")])
    fo = fourier_fit(bm.Motion(other, np.random.default_rng(0).normal(size=(60, 3)), 30.0), 2,
                     period=1.0)
    f = fourier_fit(periodic_motion(), 2, period=1.1)
    with pytest.raises(bm.SkeletonMismatchError):
        blend(f, fo, 0.5)


def test_bandai_walk_period_is_a_plausible_stride(bandai_root):
    # Measured: normal 1.08 s, happy 1.02, sad 1.65, angry 0.78; each within 1 % of two
    # footstep intervals from foot contacts (features.movement_features: 1.84, 1.96, 1.21 and
    # 2.54 steps/s). Sad walks are slow and angry ones brisk, so only normal and happy are held
    # to the usual 0.8-1.4 s stride.
    period = {}
    for style in ("normal", "happy", "sad", "angry"):
        m = bm.read_bvh(bandai_root / "data" / f"dataset-1_walk_{style}_001.bvh")
        period[style] = motion_period(m)
    assert 0.8 < period["normal"] < 1.4 and 0.8 < period["happy"] < 1.4
    assert period["angry"] < period["normal"] < period["sad"] < 2.0
    assert period["angry"] > 0.6
    model = fourier_fit(m, 8)                                    # the angry walk
    err = fourier_eval(model, m.n_frames).values - m.values
    assert np.median(np.abs(err[:, m.rotation_mask()])) < 5.0   # degrees
