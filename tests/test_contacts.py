"""Foot contacts and the foot-skate clean-up (bayesmotion.features.contacts)."""

import numpy as np
import pytest

import bayesmotion  # noqa: F401  (float64)
from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.datasets import load_cmu_handshake
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.naturalness import NaturalnessReference, naturalness
from bayesmotion.features.contacts import (
    SPEED_SCALE,
    binomial_smooth,
    pin_feet,
    pin_offset,
    root_translation_columns,
    step_weights,
)
from bayesmotion.features.movement import leg_length
from bayesmotion.features.pose import semantic_positions


@pytest.fixture(scope="module")
def actor() -> Motion:
    """The shipped CMU handshake's first actor at 30 fps: standing, feet mostly planted."""
    return load_cmu_handshake().actors[0].resample(30.0)


def _leg(m: Motion) -> float:
    return leg_length(semantic_positions(m.positions(), m.skeleton))


def _glide(m: Motion, speed: float) -> Motion:
    """``m`` with its root moved along X at ``speed`` leg lengths per second."""
    v = np.array(m.values)
    v[:, root_translation_columns(m.skeleton)[0]] += (np.arange(m.n_frames) * speed
                                                      * _leg(m) / m.fps)
    return m.replace(values=v)


def test_step_weights_and_smoothing_by_hand():
    c = np.array([[0, 1], [1, 1], [1, 0], [1, 0]], dtype=bool)
    v = np.array([[0.0, 0.0], [1.0, 2.0], [0.0, 3.0], [0.5, 0.0]])
    w = step_weights(c, v, speed_scale=1.0)
    # a step counts when the foot is in contact at both of its ends; speed v weighs 1/(1+v^2)
    expected = np.array([[0.0, 1.0], [0.0, 1 / 5], [1.0, 0.0], [1 / 1.25, 0.0]])
    np.testing.assert_allclose(w, expected)
    x = np.array([[0.0], [4.0], [0.0], [0.0]])
    np.testing.assert_allclose(binomial_smooth(x, 1)[:, 0], [1.0, 2.0, 1.0, 0.0])
    np.testing.assert_allclose(binomial_smooth(x, 0), x)


def test_a_standing_pose_carried_along_is_held_exactly_or_by_the_stated_share(actor):
    """Every frame the same pose (both feet planted), the whole body translated by a known
    drift: with sum of weights >= 1 the offset undoes the drift exactly; a drift so fast that
    the two weights sum to 0.2 is undone by that share."""
    P0 = actor.positions()[:1]
    L = _leg(actor)
    T, fps = 40, actor.fps
    ground = np.sqrt(1.0 + 0.5**2)  # the drift's ground speed per unit of ``speed``
    for speed, share in ((0.5, 1.0), (3.0 * SPEED_SCALE, 2 / (1 + (3.0 * ground) ** 2))):
        drift = np.zeros((T, 1, 3))
        drift[:, 0, 0] = np.arange(T) * speed * L / fps
        drift[:, 0, 2] = -0.5 * np.arange(T) * speed * L / fps
        off = pin_offset(P0 + drift, actor.skeleton, fps, smooth=0)
        np.testing.assert_allclose(off, -share * (drift[:, 0] - drift[0, 0]), atol=1e-9)
        # smoothing leaves a constant step's displacement alone past the first frames
        smoothed = pin_offset(P0 + drift, actor.skeleton, fps, smooth=2)
        np.testing.assert_allclose(np.diff(smoothed, axis=0)[4:], np.diff(off, axis=0)[4:],
                                   atol=1e-9)


def test_pin_feet_removes_an_added_glide_and_changes_only_the_root_path(actor):
    ref = NaturalnessReference.from_motions([actor], actor.fps)
    glide = _glide(actor, 0.5)
    before = naturalness(glide, ref)
    fixed = pin_feet(glide)
    after = naturalness(fixed, ref)
    own = naturalness(pin_feet(actor), ref)
    # the capture's own contact-point speed is 0.35 L/s at 30 fps; the glide doubles it
    assert before["foot_sliding_ratio"] > 1.9
    assert own["foot_sliding_ratio"] < 1.0
    assert after["foot_sliding_ratio"] < own["foot_sliding_ratio"] + 0.1
    assert abs(after["jerk_ratio"] - 1.0) < 0.02
    # only the root's X and Z position channels moved
    changed = np.flatnonzero(np.any(np.abs(fixed.values - glide.values) > 1e-9, axis=0))
    assert set(changed) <= set(root_translation_columns(actor.skeleton))
    # so every frame's pose relative to the root is the original one
    P, Q = glide.positions(), fixed.positions()
    np.testing.assert_allclose(Q - Q[:, :1], P - P[:, :1], atol=1e-9)


def test_rollout_pin_feet_equals_the_motion_clean_up(tiny_model):
    r = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2)
    fixed = r.pin_feet()
    for a in range(len(r.skeletons)):
        expected = pin_feet(r.to_motion()[a])
        np.testing.assert_allclose(fixed.to_motion()[a].values, expected.values, atol=1e-9)
        np.testing.assert_allclose(fixed.positions[a], expected.positions(), atol=1e-6)
        for s in range(r.samples["angles"].shape[0]):
            np.testing.assert_allclose(fixed.to_motion(s)[a].values,
                                       pin_feet(r.to_motion(s)[a]).values, atol=1e-9)
    np.testing.assert_allclose(fixed.sample_var["positions"], fixed.samples["positions"].var(0))
    np.testing.assert_array_equal(fixed.positions_var, r.positions_var)
    np.testing.assert_array_equal(fixed.Y, r.Y)


def test_bad_arguments_are_refused(actor):
    with pytest.raises(BayesmotionError, match="speed_scale"):
        pin_feet(actor, speed_scale=0.0)
    with pytest.raises(BayesmotionError, match="smooth"):
        pin_feet(actor, smooth=-1)
    sk = actor.skeleton
    no_path = Skeleton(sk.names, sk.parents, sk.offsets,
                       (("Zrotation", "Yrotation", "Xrotation"),) + tuple(sk.channels[1:]),
                       sk.end_sites)
    m = Motion(no_path, np.delete(actor.values, [0, 1, 2], axis=1), actor.fps)
    with pytest.raises(BayesmotionError, match="no Xposition"):
        pin_feet(m)


def test_real_walks_keep_their_jerk_and_lose_no_contact_motion(bandai_root):
    """Real Bandai walks and runs glide little: the clean-up leaves their jerk within 3 % and
    does not raise their measured sliding."""
    from bayesmotion.datasets.bandai import load_bandai

    for t in load_bandai(bandai_root, content=["walk", "run"], fps=10):
        m = t.actors[0]
        ref = NaturalnessReference.from_motions([m], m.fps)
        n = naturalness(pin_feet(m), ref)
        assert n["foot_sliding_ratio"] <= 1.0 + 1e-9, t.name
        assert abs(n["jerk_ratio"] - 1.0) < 0.03, t.name
        glide = naturalness(pin_feet(_glide(m, 0.3)), ref)
        assert glide["foot_sliding_ratio"] < 1.0, t.name
