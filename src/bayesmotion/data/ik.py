"""Inverse kinematics in NumPy: two-bone limbs and rotations back to BVH Euler channels.

``two_bone_ik`` places the end of a chain ``a -> b -> c`` (hip, knee, ankle) at a target by
turning the two upper joints only: the middle joint stays in the plane the chain already bends
in (the plane of ``a``, ``b`` and the target, oriented by the old ``b``), each joint turns by
the smallest rotation that takes its bone to the new direction, and the bone lengths are kept
exactly. A target out of reach is met as nearly as the straight limb allows. The rotations
follow :mod:`bayesmotion.data.fk`: ``R_world[j] = R_world[parent] @ R_local[j]``.

``euler_channels`` turns rotation matrices back into a joint's Euler channels (degrees, the
channel order of the BVH file). Of the two angle triples of each matrix and their 360-degree
shifts it returns the one nearest a reference (the joint's channels before the change), so a
small change of rotation is a small change of the channels.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from bayesmotion.errors import BayesmotionError


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def rotation_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(T, 3, 3) smallest rotations taking the directions of ``u`` (T, 3) to those of ``v``.

    Rodrigues' formula ``I + [w]x + [w]x^2 / (1 + cos)`` with ``w = u x v`` for unit vectors;
    opposite directions (no unique smallest rotation) are refused.
    """
    u, v = _unit(np.asarray(u, np.float64)), _unit(np.asarray(v, np.float64))
    w = np.cross(u, v)
    c = np.einsum("ti,ti->t", u, v)
    if np.any(c <= -1.0 + 1e-12):
        raise BayesmotionError("rotation_between: a bone would have to turn by 180 degrees")
    K = np.zeros(u.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return np.eye(3) + K + K @ K / (1.0 + c)[..., None, None]


def two_bone_ik(p_a: np.ndarray, p_b: np.ndarray, p_c: np.ndarray, R_a: np.ndarray,
                R_b: np.ndarray, target: np.ndarray, bend: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New world rotations of a chain's two upper joints that put its end at ``target``.

    Args:
        p_a: (T, 3) world position of the upper joint (the hip), which does not move.
        p_b: (T, 3) world position of the middle joint (the knee).
        p_c: (T, 3) world position of the end joint (the ankle).
        R_a: (T, 3, 3) world rotation of the upper joint (it places ``b``).
        R_b: (T, 3, 3) world rotation of the middle joint (it places ``c``).
        target: (T, 3) where the end joint should be.
        bend: (T, 3) direction the middle joint bends towards where the limb is straight, so
            that its old position gives no bending plane (default: none; a straight limb then
            bends towards an arbitrary perpendicular).

    Returns:
        ``(R_a', R_b', reached)``: the new world rotations and the (T, 3) position the end
        joint takes (``target`` where it is within reach).
    """
    ab, bc = p_b - p_a, p_c - p_b
    la, lb = np.linalg.norm(ab, axis=-1), np.linalg.norm(bc, axis=-1)
    to = target - p_a
    dist = np.linalg.norm(to, axis=-1)
    lo, hi = np.abs(la - lb), la + lb
    d = np.clip(dist, lo + 1e-9 * hi, hi * (1.0 - 1e-12))
    u = np.where(dist[:, None] > 1e-12 * hi[:, None], to, ab + bc)
    u = _unit(u)
    w = ab - np.einsum("ti,ti->t", ab, u)[:, None] * u
    if bend is not None:
        wb = bend - np.einsum("ti,ti->t", bend, u)[:, None] * u
        straight = np.linalg.norm(w, axis=-1) < 1e-6 * la
        w = np.where(straight[:, None], wb, w)
    none = np.linalg.norm(w, axis=-1) < 1e-12 * la
    if np.any(none):  # straight and no usable hint: any perpendicular
        w = np.where(none[:, None], np.cross(u, np.eye(3)[np.argmin(np.abs(u), -1)]), w)
    w = _unit(w)
    cos_a = np.clip((la**2 + d**2 - lb**2) / (2.0 * la * d), -1.0, 1.0)
    p_b2 = p_a + la[:, None] * (cos_a[:, None] * u + np.sqrt(1.0 - cos_a**2)[:, None] * w)
    reached = p_a + d[:, None] * u
    S1 = rotation_between(ab, p_b2 - p_a)
    S2 = rotation_between(np.einsum("tij,tj->ti", S1, bc), reached - p_b2)
    return S1 @ R_a, S2 @ S1 @ R_b, reached


def _alternative(order: str, angles: np.ndarray) -> np.ndarray:
    """The other Euler triple of the same rotations: (a + 180, 180 - b, c + 180) for three
    distinct axes, (a + 180, -b, c + 180) for a repeated first and last axis."""
    alt = angles + np.array([180.0, 0.0, 180.0])
    alt[:, 1] = (180.0 - angles[:, 1]) if len(set(order)) == 3 else -angles[:, 1]
    return alt


def euler_channels(order: str, R: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(T, 3) Euler channels, degrees, of (T, 3, 3) rotations for a joint whose rotation
    channels are ``order`` (e.g. ``"ZXY"``: ``R = Rz Rx Ry``), nearest ``near`` (T, 3).

    Raises:
        BayesmotionError: a joint with fewer than three rotation channels, which cannot
            hold an arbitrary rotation.
    """
    if len(order) != 3:
        raise BayesmotionError(f"a joint with rotation channels {order!r} cannot take an "
                               "arbitrary rotation (three Euler channels needed)")
    with warnings.catch_warnings():
        # at gimbal lock scipy sets the third angle to 0: still an exact decomposition
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        first = Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)
    best, best_cost = None, None
    for cand in (first, _alternative(order, first)):
        cand = cand + 360.0 * np.round((near - cand) / 360.0)
        cost = np.abs(cand - near).sum(-1)
        if best is None:
            best, best_cost = cand, cost
        else:
            better = cost < best_cost
            best = np.where(better[:, None], cand, best)
            best_cost = np.minimum(cost, best_cost)
    return best
