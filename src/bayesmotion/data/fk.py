"""Forward kinematics in JAX, batched over frames.

``R_world[j] = R_world[parent] @ R_local[j]`` and
``p_world[j] = p_world[parent] + R_world[parent] @ t_local[j]``, where ``R_local`` is the product
of the joint's rotation channels in listed order and ``t_local`` is the joint's position channels
if it has them, else its OFFSET (see :mod:`bayesmotion.data.skeleton`).
"""

from __future__ import annotations

from functools import lru_cache, partial

import jax
import jax.numpy as jnp
import numpy as np

from .skeleton import Skeleton


def axis_rotation(axis: str, angle: jax.Array) -> jax.Array:
    """Rotation matrices about a coordinate axis. angle: (...,) radians -> (..., 3, 3)."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    o, z = jnp.ones_like(angle), jnp.zeros_like(angle)
    rows = {
        "X": ((o, z, z), (z, c, -s), (z, s, c)),
        "Y": ((c, z, s), (z, o, z), (-s, z, c)),
        "Z": ((c, -s, z), (s, c, z), (z, z, o)),
    }[axis]
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def euler_to_matrix(angles_deg: jax.Array, order: str) -> jax.Array:
    """Intrinsic Euler angles to matrices, ``R = R_order[0] @ R_order[1] @ ...``.

    Args:
        angles_deg: (..., len(order)) angles in degrees, in the listed order.
        order: axes such as ``"ZYX"``.
    Returns:
        (..., 3, 3) rotation matrices.
    """
    rad = jnp.deg2rad(angles_deg)
    R = jnp.broadcast_to(jnp.eye(3, dtype=rad.dtype), rad.shape[:-1] + (3, 3))
    for k, axis in enumerate(order):
        R = R @ axis_rotation(axis, rad[..., k])
    return R


def _fk(values, offsets, end_offsets, *, layout, with_end_sites: bool):
    parents, rot_idx, orders, pos_idx, end_joints = layout
    lead = values.shape[:-1]
    Rw, pw = [], []
    for j, parent in enumerate(parents):
        n_rot = len(orders[j])
        if n_rot:
            R = euler_to_matrix(values[..., list(rot_idx[j][:n_rot])], orders[j])
        else:
            R = jnp.broadcast_to(jnp.eye(3, dtype=values.dtype), lead + (3, 3))
        t = jnp.broadcast_to(offsets[j].astype(values.dtype), lead + (3,))
        for a in range(3):
            if pos_idx[j][a] >= 0:
                t = t.at[..., a].set(values[..., pos_idx[j][a]])
        if parent < 0:
            Rw.append(R)
            pw.append(t)
        else:
            Rw.append(Rw[parent] @ R)
            pw.append(pw[parent] + jnp.einsum("...ij,...j->...i", Rw[parent], t))
    if with_end_sites:
        for k, j in enumerate(end_joints):
            off = end_offsets[k].astype(values.dtype)
            pw.append(pw[j] + jnp.einsum("...ij,j->...i", Rw[j], off))
    return jnp.stack(pw, axis=-2)


def layout_key(skeleton: Skeleton) -> tuple:
    """Hashable description of everything FK compiles against (not the bone offsets)."""
    rot_idx, orders = skeleton.rotation_layout()
    return (skeleton.parents, tuple(map(tuple, rot_idx.tolist())), orders,
            tuple(map(tuple, skeleton.position_layout().tolist())),
            tuple(sorted(skeleton.end_sites)))


def _end_offsets(skeleton: Skeleton) -> np.ndarray:
    ends = sorted(skeleton.end_sites)
    return np.array([skeleton.end_sites[j] for j in ends]).reshape(len(ends), 3)


@lru_cache(maxsize=64)
def _jitted_fk(layout: tuple, with_end_sites: bool):
    return jax.jit(partial(_fk, layout=layout, with_end_sites=with_end_sites))


def _bucket(n: int) -> int:
    """Frame counts are padded up to 8 * 2^k so clips of many lengths share a few compilations."""
    b = 8
    while b < n:
        b *= 2
    return b


def forward_kinematics(skeleton: Skeleton, values, with_end_sites: bool = False) -> jax.Array:
    """World joint positions (JAX).

    Args:
        skeleton: the joint tree. One function is compiled per joint layout and padded frame
            bucket; bone offsets are an argument, so skeletons differing only in offsets share it.
        values: (..., C) channel values in BVH order (degrees, file length units).
        with_end_sites: append the End Site positions after the joints.
    Returns:
        (..., J, 3) world positions (``J + n_end_sites`` rows with end sites).
    """
    f = _jitted_fk(layout_key(skeleton), bool(with_end_sites))
    values = jnp.asarray(values)
    lead = values.shape[:-1]
    flat = values.reshape(-1, values.shape[-1])
    n = flat.shape[0]
    flat = jnp.pad(flat, ((0, _bucket(n) - n), (0, 0)))
    out = f(flat, jnp.asarray(skeleton.offsets), jnp.asarray(_end_offsets(skeleton)))[:n]
    return out.reshape(*lead, *out.shape[-2:])


def fk_function(skeleton: Skeleton, with_end_sites: bool = False):
    """Traceable FK ``(values (..., C), offsets (J, 3)) -> (..., J, 3)`` for use inside jit."""
    layout = layout_key(skeleton)
    ends = jnp.asarray(_end_offsets(skeleton))
    return lambda v, offsets: _fk(v, offsets, ends, layout=layout,
                                  with_end_sites=with_end_sites)


def _np_axis_rotation(axis: str, rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(rad), np.sin(rad)
    o, z = np.ones_like(rad), np.zeros_like(rad)
    rows = {"X": ((o, z, z), (z, c, -s), (z, s, c)), "Y": ((c, z, s), (z, o, z), (-s, z, c)),
            "Z": ((c, -s, z), (s, c, z), (z, z, o))}[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def numpy_positions(skeleton: Skeleton, values: np.ndarray, with_end_sites=False) -> np.ndarray:
    """FK in NumPy (float64, vectorised over frames): no compilation, for data handling.

    The same equations as the JAX version (tests check they agree); use the JAX one inside
    jitted or differentiated code.
    """
    values = np.asarray(values, dtype=np.float64)
    lead = values.shape[:-1]
    v = values.reshape(-1, values.shape[-1])
    parents, rot_idx, orders, pos_idx, end_joints = layout_key(skeleton)
    Rw, pw = [], []
    for j, parent in enumerate(parents):
        R = np.broadcast_to(np.eye(3), (v.shape[0], 3, 3))
        for k, axis in enumerate(orders[j]):
            R = R @ _np_axis_rotation(axis, np.deg2rad(v[:, rot_idx[j][k]]))
        t = np.tile(skeleton.offsets[j], (v.shape[0], 1))
        for a in range(3):
            if pos_idx[j][a] >= 0:
                t[:, a] = v[:, pos_idx[j][a]]
        if parent < 0:
            Rw.append(R)
            pw.append(t)
        else:
            Rw.append(Rw[parent] @ R)
            pw.append(pw[parent] + np.einsum("nij,nj->ni", Rw[parent], t))
    if with_end_sites:
        for j in end_joints:
            pw.append(pw[j] + Rw[j] @ skeleton.end_sites[j])
    return np.stack(pw, axis=-2).reshape(*lead, -1, 3)


def _channel_tables(layout: tuple):
    """Static per-channel tables: owner (C,) joint of each channel, is_rot (C,) bool."""
    parents, rot_idx, orders, pos_idx, _ = layout
    J = len(parents)
    cols = [c for j in range(J) for c in (*rot_idx[j][:len(orders[j])], *pos_idx[j]) if c >= 0]
    C = max(cols) + 1 if cols else 0
    owner, is_rot = np.zeros(C, int), np.zeros(C, bool)
    for j in range(J):
        for k in range(len(orders[j])):
            owner[rot_idx[j][k]], is_rot[rot_idx[j][k]] = j, True
        for c in pos_idx[j]:
            if c >= 0:
                owner[c] = j
    return owner, is_rot


def _fk_with_variance(values, var, offsets, *, layout):
    """Positions (T, J, 3) and their first-order variance from independent channel variances.

    d p_d / d theta_c = (pi/180) w_c x (p_d - p_j) for a rotation channel of joint j, where
    w_c is that Euler rotation's axis in world coordinates; d p_d / d t_c = R_world[parent(j)]
    e_axis for a position channel. var(p_d)[k] = sum_c (d p_d[k] / d v_c)^2 var_c. Equal to
    ``jacfwd`` of the FK (a test checks this) at a fraction of its cost.
    """
    parents, rot_idx, orders, pos_idx, _ = layout
    owner, is_rot = _channel_tables(layout)
    T, C, J = values.shape[0], len(owner), len(parents)
    eye = jnp.eye(3, dtype=values.dtype)
    Rw, pw = [], []
    dirs = [None] * C
    for j, parent in enumerate(parents):
        Rp = Rw[parent] if parent >= 0 else jnp.broadcast_to(eye, (T, 3, 3))
        R = Rp
        for k, ax in enumerate(orders[j]):
            c = rot_idx[j][k]
            dirs[c] = R[..., :, "XYZ".index(ax)]  # world axis of this rotation
            R = R @ axis_rotation(ax, jnp.deg2rad(values[:, c]))
        t = jnp.broadcast_to(offsets[j].astype(values.dtype), (T, 3))
        for a in range(3):
            c = pos_idx[j][a]
            if c >= 0:
                t = t.at[:, a].set(values[:, c])
                dirs[c] = Rp[..., :, a]
        Rw.append(R)
        pw.append(t if parent < 0 else pw[parent] + jnp.einsum("tij,tj->ti", Rp, t))
    P = jnp.stack(pw, axis=1)  # (T, J, 3)
    zero = jnp.zeros((T, 3), values.dtype)
    W = jnp.stack([d if d is not None else zero for d in dirs], axis=1)  # (T, C, 3)
    # Expand |w x (p - q)|_k^2 = (M_k . p - s_k)^2 with M = [w]_x, s = w x q, so that the sum
    # over channels is a sum of per-channel features G_kab = M_ka M_kb, h_kb = s_k M_kb,
    # e_k = s_k^2 (position channels: G = h = 0, e = W^2), accumulated down the tree, instead of
    # a (T, C, J, 3) Jacobian. Points are taken relative to the root to keep the terms small.
    P0 = P - P[:, :1]
    q = P0[:, owner]  # (T, C, 3) pivots
    M = jnp.cross(W[:, :, None, :], jnp.eye(3, dtype=values.dtype)[None, None])  # M[.., b, :]
    M = jnp.swapaxes(M, -1, -2)  # M[t, c, k, b] = (w x e_b)_k
    sv = jnp.cross(W, q)
    rad2 = (np.pi / 180.0) ** 2
    rot = jnp.asarray(is_rot)[None, :, None]
    G = jnp.where(rot[..., None, None], M[..., :, :, None] * M[..., :, None, :], 0.0)
    h = jnp.where(rot[..., None], sv[..., :, None] * M, 0.0)
    e = jnp.where(rot, sv * sv, W * W / rad2)
    feats = jnp.concatenate([G.reshape(T, C, 27), h.reshape(T, C, 9), e], axis=-1) * rad2
    featsw = feats * var[:, :C, None]
    # channels that move joint j: its parent's reach, the parent's rotations, j's positions
    reach = []
    for j, parent in enumerate(parents):
        acc = sum((featsw[:, c] for c in pos_idx[j] if c >= 0), jnp.zeros_like(featsw[:, 0]))
        if parent >= 0:
            acc = acc + reach[parent] + sum(featsw[:, rot_idx[parent][k]]
                                            for k in range(len(orders[parent])))
        reach.append(acc)
    agg = jnp.stack(reach, axis=1)  # (T, J, F)
    Gd, hd, ed = agg[..., :27].reshape(T, J, 3, 3, 3), agg[..., 27:36].reshape(T, J, 3, 3), \
        agg[..., 36:]
    quad = jnp.einsum("tjkab,tja,tjb->tjk", Gd, P0, P0)
    return P, jnp.maximum(quad - 2 * jnp.einsum("tjkb,tjb->tjk", hd, P0) + ed, 0.0)


def fk_variance_function(skeleton: Skeleton):
    """Traceable ``(values (T, C), var (T, C), offsets) -> positions, variance (T, J, 3)``."""
    return partial(_fk_with_variance, layout=layout_key(skeleton))
