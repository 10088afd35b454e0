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
    contact_steps,
    pin_feet,
    pin_offset,
    plant_legs,
    root_translation_columns,
    sliding_contacts,
    step_weights,
)
from bayesmotion.features.joint_map import CMU_MAP
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
    legs = r.pin_feet(legs=True, speed_scale=2.0)
    for a in range(len(r.skeletons)):
        expected = pin_feet(r.to_motion()[a], legs=True, speed_scale=2.0)
        np.testing.assert_allclose(legs.to_motion()[a].values, expected.values, atol=1e-9)
        np.testing.assert_allclose(legs.positions[a], expected.positions(), atol=1e-6)
        np.testing.assert_allclose(legs.to_motion(1)[a].values,
                                   pin_feet(r.to_motion(1)[a], legs=True,
                                            speed_scale=2.0).values, atol=1e-9)


def _swung_left_leg(m: Motion) -> Motion:
    """``m`` with its left thigh swung +-3 degrees (period 2 s): the planted left foot glides
    relative to the body, which a root correction cannot remove."""
    v = np.array(m.values)
    col = m.skeleton.channel_offsets[m.skeleton.index("LeftUpLeg")]
    v[:, col] += 3.0 * np.sin(np.pi * np.arange(m.n_frames) / m.fps)
    return m.replace(values=v)


def test_plant_legs_holds_a_planted_foot_still_and_moves_only_the_legs(actor):
    swung = _swung_left_leg(actor)
    sk = swung.skeleton
    # speed_scale so large that every contact step is held in full
    out = swung.replace(values=plant_legs(swung.values, sk, swung.fps, speed_scale=1e9))
    p0 = semantic_positions(swung.positions(), sk)
    p1 = semantic_positions(out.positions(), sk)
    L = leg_length(p0)
    c = sliding_contacts(p0, swung.fps, L)
    held = np.minimum(c, np.concatenate([c[:1], c[:-1]]))[:, 0]  # left foot, both ends
    assert held.sum() > 30
    before = np.linalg.norm(contact_steps(p0)[held, 0], axis=-1)
    after = np.linalg.norm(contact_steps(p1)[held, 0], axis=-1)
    assert before.max() > 1e-3 * L
    np.testing.assert_allclose(after, 0.0, atol=1e-9 * L)
    # heights and the foot's own orientation are kept: its contacts do not change (the right
    # foot shuffles a step inside its contact at frames 69-75, out of its leg's reach)
    for j in ("l_foot", "l_toe"):
        np.testing.assert_allclose(p1[j][:, 1], p0[j][:, 1], atol=1e-9 * L)
    np.testing.assert_allclose(p1["l_toe"] - p1["l_foot"], p0["l_toe"] - p0["l_foot"],
                               atol=1e-9 * L)
    # only the hips', knees' and ankles' rotation channels change; the body above stays
    legs = [sk.index(n) for n in ("LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg",
                                  "RightLeg", "RightFoot")]
    allowed = {sk.channel_offsets[j] + k for j in legs for k in range(3)}
    changed = np.flatnonzero(np.any(np.abs(out.values - swung.values) > 1e-9, axis=0))
    assert set(changed) <= allowed and changed.size
    for j in ("root", "spine", "neck", "head", "l_hand", "r_hand", "l_hip", "r_hip"):
        np.testing.assert_allclose(p1[j], p0[j], atol=1e-9 * L)
    # bone lengths: FK of the new channels
    for s in "lr":
        for a, b in ((f"{s}_hip", f"{s}_knee"), (f"{s}_knee", f"{s}_foot")):
            np.testing.assert_allclose(np.linalg.norm(p1[a] - p1[b], axis=-1),
                                       np.linalg.norm(p0[a] - p0[b], axis=-1), rtol=1e-9)


def test_pin_feet_with_legs_removes_sliding_the_root_cannot(actor):
    ref = NaturalnessReference.from_motions([actor], actor.fps)
    swung = _swung_left_leg(actor)
    root_only = naturalness(pin_feet(swung), ref)
    both = naturalness(pin_feet(swung, legs=True), ref)
    assert both["foot_sliding_ratio"] < 0.8 * root_only["foot_sliding_ratio"]
    assert abs(both["jerk_ratio"] - root_only["jerk_ratio"]) < 0.05
    # no foot moved: a motion whose contacts do not glide is returned unchanged
    frozen = actor.replace(values=np.repeat(actor.values[:1], 20, axis=0))
    np.testing.assert_array_equal(pin_feet(frozen, legs=True).values, frozen.values)


def test_plant_legs_refuses_legs_that_are_not_chains(actor):
    from dataclasses import replace

    bad = replace(CMU_MAP, l_knee="LeftToeBase")
    with pytest.raises(BayesmotionError, match="not a chain of parents"):
        plant_legs(actor.values, actor.skeleton, actor.fps, bad)


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


def test_real_gestures_lose_most_sliding_with_the_legs_and_keep_their_jerk(bandai_root):
    """Real Bandai bows and byes stand on both feet: the legs' clean-up removes most of what
    glides (the root alone cannot: the feet do not glide together) and keeps the jerk."""
    from bayesmotion.datasets.bandai import load_bandai

    for t in load_bandai(bandai_root, content=["bow", "bye"], fps=10):
        m = t.actors[0]
        ref = NaturalnessReference.from_motions([m], m.fps)
        root = naturalness(pin_feet(m), ref)
        legs = naturalness(pin_feet(m, legs=True), ref)
        assert legs["foot_sliding_ratio"] < 0.5, t.name
        assert legs["foot_sliding_ratio"] < 0.6 * root["foot_sliding_ratio"], t.name
        assert abs(legs["jerk_ratio"] - 1.0) < 0.03, t.name
