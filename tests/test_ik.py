"""Two-bone inverse kinematics and Euler channels from rotations (bayesmotion.data.ik)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from bayesmotion.data.fk import euler_matrices
from bayesmotion.data.ik import euler_channels, rotation_between, two_bone_ik
from bayesmotion.errors import BayesmotionError


def test_rotation_between_is_the_smallest_rotation_onto_the_direction():
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    R = rotation_between(u, v)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    uh = u / np.linalg.norm(u, axis=-1, keepdims=True)
    vh = v / np.linalg.norm(v, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.einsum("tij,tj->ti", R, uh), vh, atol=1e-12)
    # smallest: it turns about u x v and by the angle between u and v, nothing more
    axis = np.cross(u, v)
    np.testing.assert_allclose(np.einsum("tij,tj->ti", R, axis), axis, atol=1e-10)
    angle = Rotation.from_matrix(R).magnitude()
    np.testing.assert_allclose(angle, np.arccos(np.clip(np.sum(uh * vh, -1), -1, 1)),
                               atol=1e-7)
    with pytest.raises(BayesmotionError, match="180"):
        rotation_between(np.array([[1.0, 0, 0]]), np.array([[-1.0, 0, 0]]))


def _chain(rng, T):
    """A random bent chain a -> b -> c: world rotations of a and b, positions, bone offsets."""
    R_a = Rotation.random(T, random_state=1).as_matrix()
    R_b = R_a @ Rotation.from_rotvec(np.c_[rng.uniform(0.8, 1.5, T), np.zeros((T, 2))]
                                     ).as_matrix()
    t_b, t_c = np.array([0.0, -0.45, 0.0]), np.array([0.0, -0.40, 0.0])
    p_a = rng.normal(size=(T, 3))
    p_b = p_a + R_a @ t_b
    p_c = p_b + R_b @ t_c
    return p_a, p_b, p_c, R_a, R_b, t_b, t_c


def test_two_bone_ik_puts_the_end_on_a_target_in_reach_keeping_bones_and_bend_side():
    rng = np.random.default_rng(1)
    T = 40
    p_a, p_b, p_c, R_a, R_b, t_b, t_c = _chain(rng, T)
    target = p_c + rng.normal(scale=0.03, size=(T, 3))  # within reach
    Ra2, Rb2, reached = two_bone_ik(p_a, p_b, p_c, R_a, R_b, target)
    # forward kinematics of the new rotations: the end is on the target
    p_b2 = p_a + Ra2 @ t_b
    p_c2 = p_b2 + Rb2 @ t_c
    np.testing.assert_allclose(p_c2, target, atol=1e-10)
    np.testing.assert_allclose(reached, target, atol=1e-10)
    for R in (Ra2, Rb2):
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # the middle joint bends to the side it bent to before (same side of the line a-target)
    line = (target - p_a) / np.linalg.norm(target - p_a, axis=-1, keepdims=True)

    def side(pb):
        w = (pb - p_a) - np.sum((pb - p_a) * line, -1, keepdims=True) * line
        return w

    assert np.all(np.sum(side(p_b) * side(p_b2), -1) > 0)
    # no target change, no rotation change
    Ra3, Rb3, _ = two_bone_ik(p_a, p_b, p_c, R_a, R_b, p_c)
    np.testing.assert_allclose(Ra3, R_a, atol=1e-10)
    np.testing.assert_allclose(Rb3, R_b, atol=1e-10)


def test_two_bone_ik_straightens_towards_a_target_out_of_reach():
    rng = np.random.default_rng(2)
    p_a, p_b, p_c, R_a, R_b, t_b, t_c = _chain(rng, 10)
    far = p_a + 3.0 * (p_c - p_a)
    Ra2, Rb2, reached = two_bone_ik(p_a, p_b, p_c, R_a, R_b, far)
    p_c2 = p_a + Ra2 @ t_b + Rb2 @ t_c
    np.testing.assert_allclose(p_c2, reached, atol=1e-10)
    direction = (far - p_a) / np.linalg.norm(far - p_a, axis=-1, keepdims=True)
    np.testing.assert_allclose(reached, p_a + 0.85 * direction, atol=1e-9)


@pytest.mark.parametrize("order", ["ZXY", "ZYX", "XYZ", "YXZ", "XZY", "YZX", "ZXZ"])
def test_euler_channels_reproduce_the_rotation_on_the_branch_nearest_the_reference(order):
    rng = np.random.default_rng(3)
    T = 30
    angles = rng.uniform(-170, 170, size=(T, 3))
    angles[:, 1] = rng.uniform(10, 80, T) if order[0] == order[2] else rng.uniform(-80, 80, T)
    R = euler_matrices(order, angles)
    # the reference: the same rotations written with 360-degree shifts
    shifted = angles + 360.0 * rng.integers(-2, 3, size=(T, 3))
    out = euler_channels(order, R, shifted + rng.normal(scale=1.0, size=(T, 3)))
    np.testing.assert_allclose(out, shifted, atol=1e-8)
    # the reference on the other triple of the same rotations: that triple comes back
    other = angles + np.array([180.0, 0.0, 180.0])
    other[:, 1] = 180.0 - angles[:, 1] if len(set(order)) == 3 else -angles[:, 1]
    np.testing.assert_allclose(euler_matrices(order, other), R, atol=1e-12)
    np.testing.assert_allclose(euler_channels(order, R, other), other, atol=1e-8)
    np.testing.assert_allclose(euler_matrices(order, out), R, atol=1e-12)


def test_euler_channels_refuse_joints_without_three_rotation_channels():
    with pytest.raises(BayesmotionError, match="three Euler channels"):
        euler_channels("ZX", np.eye(3)[None], np.zeros((1, 2)))
