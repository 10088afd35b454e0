"""Emotion transforms (Amaya-style) against hand-made references."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bayesmotion import BayesmotionError, Motion, Skeleton
from bayesmotion.data.emotion import (
    CMU_BODY_PARTS,
    EMOTION_PRESETS,
    EmotionStyle,
    add_bounce,
    add_posture,
    apply_emotion,
    body_parts,
    channel_categories,
    compose_styles,
    mean_posture,
    resample_at,
    scale_amplitude,
    time_warp,
    unwrapped,
    warp_times,
)
from bayesmotion.datasets import load_cmu_handshake

ZYX = ("Zrotation", "Yrotation", "Xrotation")
ROOT = ("Xposition", "Yposition", "Zposition") + ZYX


def tiny_skeleton():
    """Hips (root, 6 channels) -> Spine (torso) -> RightArm (arms) -> RightHand (arms)."""
    return Skeleton(["Hips", "Spine", "RightArm", "RightHand"], [-1, 0, 1, 2],
                    [[0, 0, 0], [0, 1, 0], [-1, 0, 0], [-1, 0, 0]], [ROOT, ZYX, ZYX, ZYX])


def tiny_motion(T=121, fps=120.0, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(T)[:, None] / fps
    v = 20 * np.sin(2 * np.pi * rng.uniform(0.5, 2, 15) * t + rng.uniform(0, 6, 15))
    v[:, :3] = rng.normal(size=3) + t * [1.0, 0.0, 2.0]
    return Motion(tiny_skeleton(), v, fps, "tiny")


@pytest.fixture(scope="module")
def cmu_actor():
    return load_cmu_handshake().actors[0]


# --------------------------------------------------------------------------- categories
def test_cmu_body_parts_cover_every_non_root_joint(cmu_actor):
    assert body_parts(cmu_actor.skeleton) == dict(CMU_BODY_PARTS)
    assert set(CMU_BODY_PARTS) == set(cmu_actor.skeleton.names[1:])


def test_body_parts_guesses_bandai_names():
    names = ["joint_Root", "Hips", "Spine", "Chest", "Neck", "Head", "Shoulder_L", "UpperArm_L",
             "LowerArm_L", "Hand_L", "UpperLeg_L", "LowerLeg_L", "Foot_L", "Toes_L"]
    sk = Skeleton(names, [-1] + list(range(len(names) - 1)), np.zeros((len(names), 3)),
                  [ROOT] + [ZYX] * (len(names) - 1))
    got = body_parts(sk)
    assert [got[n] for n in names[1:]] == ["torso"] * 5 + ["arms"] * 4 + ["legs"] * 4


def test_channel_categories_leave_the_root_alone():
    cats = channel_categories(tiny_skeleton())
    assert list(cats) == [""] * 6 + ["torso"] * 3 + ["arms"] * 6


# --------------------------------------------------------------------------- time warp
def test_time_warp_speed_one_is_identity():
    m = tiny_motion()
    out = time_warp(m, 1.0)
    assert out.n_frames == m.n_frames and out.fps == m.fps
    np.testing.assert_array_equal(out.values, m.values)


def test_time_warp_speed_two_halves_the_duration():
    m = tiny_motion(T=121)
    out = time_warp(m, 2.0)
    assert out.n_frames == 61
    assert out.duration == pytest.approx(m.duration / 2)
    np.testing.assert_array_equal(out.values, m.values[::2])


def test_time_warp_half_speed_interpolates_linearly():
    m = tiny_motion(T=11)
    out = time_warp(m, 0.5)
    assert out.n_frames == 21
    np.testing.assert_allclose(out.values[1::2], 0.5 * (m.values[:-1] + m.values[1:]),
                               atol=1e-12)


def test_peak_shift_keeps_the_ends_and_moves_the_middle_earlier():
    tau = warp_times(121, 120.0, 1.0, peak_shift=0.3)
    t = np.arange(121) / 120.0
    assert tau[0] == 0 and tau[-1] == pytest.approx(1.0)
    assert np.all(np.diff(tau) > 0)
    assert np.all(tau[1:-1] > t[1:-1])  # the source content arrives earlier
    np.testing.assert_allclose(tau, t * (1 + 0.3 * (1 - t)), atol=1e-15)


def test_timing_lag_delays_one_category():
    m = tiny_motion()
    out = time_warp(m, 1.0, timing={"arms": 10 / 120})
    arms = channel_categories(m.skeleton) == "arms"
    np.testing.assert_allclose(out.values[10:, arms], m.values[:-10, arms], atol=1e-9)
    np.testing.assert_array_equal(out.values[:, ~arms], m.values[:, ~arms])


def test_resample_at_changes_the_frame_rate():
    m = tiny_motion()
    out = resample_at(m, np.arange(0, 1.0 + 1e-9, 0.05), fps=20.0)
    assert out.fps == 20.0 and out.n_frames == 21
    np.testing.assert_allclose(out.values, m.values[::6], atol=1e-9)


def wrapping_motion():
    """A RightArm Z angle running 170 -> 190 deg, stored wrapped to (-180, 180]."""
    m = tiny_motion(T=41)
    v = m.values.copy()
    col = 6 + 3  # RightArm Zrotation
    v[:, col] = (np.linspace(170, 190, 41) + 180) % 360 - 180
    return m.replace(values=v), col


def test_transforms_do_not_jump_across_180():
    m, col = wrapping_motion()
    assert np.abs(np.diff(m.values[:, col])).max() > 300  # the input does wrap
    for out in (time_warp(m, 0.7, peak_shift=0.2), scale_amplitude(m, 1.5),
                scale_amplitude(m, 0.5, reference=np.full(15, -175.0)),
                apply_emotion(m, EmotionStyle(speed=1.3, amplitude={"arms": 1.2}))):
        assert np.abs(np.diff(out.values[:, col])).max() < 5


# --------------------------------------------------------------------------- amplitude
def test_scale_amplitude_one_is_identity_and_zero_gives_reference():
    m = tiny_motion()
    np.testing.assert_allclose(scale_amplitude(m, 1.0).values, m.values, atol=1e-12)
    ref = np.random.default_rng(1).uniform(-40, 40, 15)
    out = scale_amplitude(m, 0.0, reference=ref).values
    np.testing.assert_array_equal(out[:, 6:], np.broadcast_to(ref[6:], out[:, 6:].shape))
    np.testing.assert_array_equal(out[:, :6], m.values[:, :6])  # root untouched


def test_scale_amplitude_scales_deviation_per_category():
    m = tiny_motion()
    out = scale_amplitude(m, {"arms": 2.0, "torso": 0.5})
    mean = m.values.mean(axis=0)
    cats = channel_categories(m.skeleton)
    f = np.where(cats == "arms", 2.0, np.where(cats == "torso", 0.5, 1.0))
    expect = np.where(cats != "", mean + f * (m.values - mean), m.values)
    np.testing.assert_allclose(out.values, expect, atol=1e-12)
    np.testing.assert_allclose(mean_posture(out)[cats != ""], mean[cats != ""], atol=1e-12)


def test_scale_amplitude_reference_on_another_branch():
    """A reference 360 deg away is the same posture: deviations stay small."""
    m, col = wrapping_motion()
    ref = mean_posture(m)
    ref_shifted = ref.copy()
    ref_shifted[col] -= 360
    a = scale_amplitude(m, 0.5, reference=ref).values[:, col]
    b = scale_amplitude(m, 0.5, reference=ref_shifted).values[:, col]
    np.testing.assert_allclose((a - b) % 360, 0, atol=1e-9)


def test_scale_amplitude_bad_reference_shape():
    with pytest.raises(BayesmotionError, match=r"reference must be \(15,\)"):
        scale_amplitude(tiny_motion(), 2.0, reference=np.zeros(3))


# --------------------------------------------------------------------------- posture
def test_add_posture_adds_exactly_the_offsets():
    m = tiny_motion()
    out = add_posture(m, {"Spine": (1.0, 2.0, 3.0), "RightHand": (0.0, 0.0, -4.5)})
    diff = np.zeros(15)
    diff[6:9] = [3.0, 2.0, 1.0]  # Spine channels are Z, Y, X
    diff[12] = -4.5  # RightHand Zrotation
    np.testing.assert_array_equal(out.values, m.values + diff)


def test_add_posture_names_unknown_joints():
    with pytest.raises(BayesmotionError, match="Neck1"):
        add_posture(tiny_motion(), {"Neck1": (5, 0, 0)})


def test_add_bounce_is_a_sine_on_root_height():
    m = tiny_motion()
    out = add_bounce(m, 0.3, 2.0, phase=0.5)
    t = np.arange(m.n_frames) / m.fps
    d = out.values - m.values
    np.testing.assert_allclose(d[:, 1], 0.3 * np.sin(4 * np.pi * t + 0.5), atol=1e-15)
    assert not d[:, [0, *range(2, 15)]].any()


# --------------------------------------------------------------------------- styles
def test_neutral_preset_is_identity(cmu_actor):
    out = apply_emotion(cmu_actor, EMOTION_PRESETS["neutral"])
    np.testing.assert_allclose(out.values, unwrapped(cmu_actor), atol=1e-9)


def test_presets_apply_to_the_cmu_skeleton(cmu_actor):
    for name, style in EMOTION_PRESETS.items():
        out = apply_emotion(cmu_actor, style)
        assert out.n_frames == int(np.floor((cmu_actor.n_frames - 1) / style.speed + 1e-9)) + 1
        assert np.isfinite(out.values).all(), name


def test_style_is_frozen_and_validated():
    s = EmotionStyle(speed=2, amplitude={"arms": 1.5}, posture={"Neck": 3})
    assert s.posture["Neck"] == (3.0, 3.0, 3.0)
    with pytest.raises(TypeError):
        s.amplitude["arms"] = 2.0
    for bad in ({"speed": 0}, {"peak_shift": 1.0}, {"amplitude": {"tail": 1.0}},
                {"amplitude": {"arms": -1.0}}, {"timing": {"wings": 0.1}}, {"bounce": -1}):
        with pytest.raises(BayesmotionError):
            EmotionStyle(**bad)


def test_compose_styles():
    a = EmotionStyle(speed=1.2, amplitude={"arms": 1.5}, posture={"Neck": (1, 0, 0)},
                     timing={"torso": 0.1})
    b = EmotionStyle(speed=0.5, amplitude={"arms": 2.0, "legs": 0.5}, posture={"Neck": (2, 1, 0)},
                     bounce=0.01, bounce_hz=3.0, peak_shift=0.2)
    c = compose_styles(a, b)
    assert c.speed == pytest.approx(0.6)
    assert dict(c.amplitude) == {"arms": 3.0, "legs": 0.5}
    assert c.posture["Neck"] == (3.0, 1.0, 0.0)
    assert (c.bounce, c.bounce_hz, c.peak_shift, dict(c.timing)) == (0.01, 3.0, 0.2, {"torso": 0.1})


@settings(max_examples=40, deadline=None)
@given(T=st.integers(1, 60), speed=st.floats(0.1, 10), shift=st.floats(-0.95, 0.95),
       amp=st.floats(0, 3))
def test_any_style_gives_a_valid_motion(T, speed, shift, amp):
    m = tiny_motion(T=T, fps=30.0)
    out = apply_emotion(m, EmotionStyle(speed=speed, peak_shift=shift, amplitude={"arms": amp},
                                        bounce=0.01))
    assert out.n_frames == int(np.floor((T - 1) / speed + 1e-9)) + 1
    assert np.isfinite(out.values).all()


def test_the_joint_carrying_the_heading_is_never_scaled_or_lagged():
    """Bandai translates and turns Hips below a static joint_Root; were Hips in the torso
    category, scaling the torso would turn the walker's facing (by up to 11 degrees on a real
    walk) while its path stayed the same."""
    from bayesmotion.data.emotion import channel_categories, motion_mover, scale_amplitude

    names = ["joint_Root", "Hips", "Spine", "Head", "UpperLeg_L"]
    sk = Skeleton(names, [-1, 0, 1, 2, 1], np.ones((5, 3)), [ROOT] * 2 + [ZYX] * 3)
    T = 40
    rng = np.random.default_rng(0)
    v = 10 * np.sin(np.linspace(0, 6, T)[:, None] + rng.uniform(0, 6, sk.n_channels))
    v[:, :6] = 0.0  # joint_Root static
    v[:, 6] = np.linspace(0, 300, T)  # Hips walks along X
    m = Motion(sk, v, 30.0, "walk")
    assert motion_mover(m) == 1
    cats = channel_categories(sk, mover=1)
    assert list(cats[:12]) == [""] * 12 and list(cats[12:15]) == ["torso"] * 3
    out = scale_amplitude(m, {"torso": 1.3, "legs": 0.7})
    np.testing.assert_allclose(out.values[:, :12], m.values[:, :12], atol=1e-12)
    assert not np.allclose(out.values[:, 12:15], m.values[:, 12:15])  # the spine does scale
