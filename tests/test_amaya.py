"""The Amaya et al. (1996) baseline: fit a style on one pair, apply it to another motion."""

import numpy as np
import pytest

from bayesmotion import BayesmotionError, Motion, Skeleton, SkeletonMismatchError
from bayesmotion.baselines import apply_amaya, fit_amaya
from bayesmotion.data.emotion import (
    CMU_BODY_PARTS,
    EMOTION_PRESETS,
    EmotionStyle,
    apply_emotion,
    channel_categories,
    unwrapped,
)
from bayesmotion.datasets import load_cmu_handshake

STYLE = EmotionStyle(speed=1.3, amplitude={"torso": 0.8, "arms": 1.4, "legs": 1.1},
                     posture={"Neck": (8, 0, 0), "RightShoulder": (0, 0, 5)}, peak_shift=0.1)


@pytest.fixture(scope="module")
def actors():
    return load_cmu_handshake().actors


@pytest.mark.parametrize("speed_from", ["duration", "angular_speed"])
@pytest.mark.parametrize("style", [STYLE, EMOTION_PRESETS["sad"], EMOTION_PRESETS["angry"]])
def test_fit_recovers_a_known_style(actors, style, speed_from):
    neutral = actors[0]
    fitted = fit_amaya(neutral, apply_emotion(neutral, style), speed_from=speed_from)
    assert fitted.speed == pytest.approx(style.speed, rel=0.05)
    for c in ("torso", "arms", "legs"):
        assert fitted.amplitude[c] == pytest.approx(style.amplitude.get(c, 1.0), rel=0.10)
    for joint, offset in style.posture.items():
        np.testing.assert_allclose(fitted.posture[joint], offset, atol=0.5)
    assert set(fitted.posture) == set(CMU_BODY_PARTS)


def test_fit_of_identical_motions_is_neutral(actors):
    fitted = fit_amaya(actors[1], actors[1])
    assert fitted.speed == 1.0
    assert all(f == pytest.approx(1.0) for f in fitted.amplitude.values())
    assert all(np.allclose(v, 0) for v in fitted.posture.values())


def arm_stats(m):
    v = unwrapped(m)[:, channel_categories(m.skeleton) == "arms"]
    return m.duration, np.abs(np.diff(v, axis=0)).mean() * m.fps, v.std(axis=0).mean()


@pytest.mark.parametrize("emotion, sign", [("angry", 1), ("sad", -1)])
def test_apply_to_a_second_motion_changes_it_in_the_fitted_direction(actors, emotion, sign):
    """Fit on subject 18, apply to subject 19: measured duration, speed, amplitude move."""
    style = fit_amaya(actors[0], apply_emotion(actors[0], EMOTION_PRESETS[emotion]))
    before, after = arm_stats(actors[1]), arm_stats(apply_amaya(style, actors[1]))
    assert np.sign(before[0] - after[0]) == sign  # shorter when faster
    assert np.sign(after[1] - before[1]) == sign  # angular speed
    assert np.sign(after[2] - before[2]) == sign  # amplitude
    assert after[2] / before[2] == pytest.approx(EMOTION_PRESETS[emotion].amplitude["arms"],
                                                 rel=0.05)


def test_errors(actors):
    other = load_cmu_handshake().actors[0]
    sk = other.skeleton
    small = Skeleton(sk.names[:2], sk.parents[:2], sk.offsets[:2], sk.channels[:2])
    with pytest.raises(SkeletonMismatchError, match="skeleton layout"):
        fit_amaya(other, Motion(small, np.zeros((5, 9)), 120.0))
    with pytest.raises(BayesmotionError, match="speed_from"):
        fit_amaya(other, other, speed_from="tempo")
    with pytest.raises(BayesmotionError, match="cannot estimate a speed"):
        fit_amaya(other, other.select([0]))
