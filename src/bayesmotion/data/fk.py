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

from bayesmotion.data.skeleton import Skeleton
from bayesmotion.shapes import padded_length


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


def _mm3(A: jax.Array, B: jax.Array) -> jax.Array:
    """A @ B for stacks of 3 x 3 matrices as elementwise multiply-adds, which XLA fuses with
    the gathers around them instead of calling a batched dot on 3 x 3 operands."""
    return jnp.sum(A[..., :, :, None] * B[..., None, :, :], axis=-2)


def _mv3(A: jax.Array, v: jax.Array) -> jax.Array:
    """A @ v for stacks of 3 x 3 matrices and 3-vectors, elementwise (see :func:`_mm3`)."""
    return jnp.sum(A * v[..., None, :], axis=-1)


@lru_cache(maxsize=64)
def _plan(layout: tuple):
    """Static (NumPy) schedule of a joint layout for FK vectorised over joints.

    groups: per Euler order string, (joints (n,), channel columns (n, len(order))).
    pos: (joint, axis, column) triples of the position channels.
    levels: joints grouped by depth, each with its parents; the world transforms are built one
    depth level at a time (about 10 batched steps for a 31-joint body instead of 31 unrolled
    joints, which keeps compilation short).
    """
    parents, rot_idx, orders, pos_idx, _ = layout
    J = len(parents)
    groups: dict[str, list] = {}
    for j in range(J):
        if orders[j]:
            groups.setdefault(orders[j], []).append(j)
    groups = {o: (np.array(js), np.array([rot_idx[j][:len(o)] for j in js]))
              for o, js in groups.items()}
    pos = np.array([(j, a, pos_idx[j][a]) for j in range(J) for a in range(3)
                    if pos_idx[j][a] >= 0], dtype=int).reshape(-1, 3)
    depth = np.zeros(J, int)
    for j in range(J):
        depth[j] = 0 if parents[j] < 0 else depth[parents[j]] + 1
    levels = [(np.flatnonzero(depth == d), np.array(parents)[depth == d])
              for d in range(depth.max() + 1)]
    return groups, pos, levels


def _local(values, offsets, layout):
    """Joint-major local transforms: rotations (J, T, 3, 3), the Euler partial products of
    every order group, translations (J, T, 3). values: (T, C). (Joint-major so that the
    per-level gathers move contiguous blocks.)"""
    groups, pos, _ = _plan(layout)
    T, J = values.shape[0], len(layout[0])
    vT = values.T  # (C, T)
    eye = jnp.eye(3, dtype=values.dtype)
    blocks, owners = [], []
    partial_products = {}
    for order, (js, cols) in groups.items():
        Rg = jnp.broadcast_to(eye, (js.size, T, 3, 3))
        parts = []
        for k, axis in enumerate(order):
            parts.append(Rg)
            Rg = _mm3(Rg, axis_rotation(axis, jnp.deg2rad(vT[cols[:, k]])))
        partial_products[order] = parts
        blocks.append(Rg)
        owners.append(js)
    fixed = np.setdiff1d(np.arange(J), np.concatenate(owners) if owners else [])
    if fixed.size:
        blocks.append(jnp.broadcast_to(eye, (fixed.size, T, 3, 3)))
        owners.append(fixed)
    # one concatenation and one gather into joint order (scattering group by group into a
    # (J, T, 3, 3) array copied the whole array per group)
    R = jnp.concatenate(blocks)[np.argsort(np.concatenate(owners))]
    t = jnp.broadcast_to(offsets.astype(values.dtype)[:, None, :], (J, T, 3))
    if pos.size:
        t = t.at[pos[:, 0], :, pos[:, 1]].set(vT[pos[:, 2]])
    return R, partial_products, t


def _world(R, t, layout):
    """Joint-major world rotations (J, T, 3, 3) and positions (J, T, 3), level by level.

    Each depth level is kept as its own array and gathers its parents from the level above;
    the levels are put into joint order once at the end. (Scattering every level into full
    (J, T, 3, 3) arrays copied them ~10 times: 18 MB each for 8,000 frames.)"""
    _, _, levels = _plan(layout)
    roots, _ = levels[0]
    Rw, pw = [R[roots]], [t[roots]]
    for (prev, _), (js, ps) in zip(levels[:-1], levels[1:], strict=True):
        where = np.searchsorted(prev, ps)  # each parent's row in the level above (sorted)
        Rp = Rw[-1][where]
        Rw.append(_mm3(Rp, R[js]))
        pw.append(pw[-1][where] + _mv3(Rp, t[js]))
    order = np.argsort(np.concatenate([js for js, _ in levels]))
    return jnp.concatenate(Rw)[order], jnp.concatenate(pw)[order]


def _fk(values, offsets, end_offsets, *, layout, with_end_sites: bool):
    lead = values.shape[:-1]
    v = values.reshape(-1, values.shape[-1])
    R, _, t = _local(v, offsets, layout)
    Rw, pw = _world(R, t, layout)
    if with_end_sites and len(layout[4]):
        ends = np.asarray(layout[4])
        tips = pw[ends] + _mv3(Rw[ends], end_offsets.astype(v.dtype)[:, None, :])
        pw = jnp.concatenate([pw, tips], axis=0)
    pw = jnp.swapaxes(pw, 0, 1)
    return pw.reshape(*lead, *pw.shape[-2:])


def layout_key(skeleton: Skeleton) -> tuple:
    """Hashable description of everything FK compiles against (not the bone offsets); kept on
    the (immutable) skeleton after the first call."""
    key = skeleton.__dict__.get("_fk_layout")
    if key is None:
        rot_idx, orders = skeleton.rotation_layout()
        key = (skeleton.parents, tuple(map(tuple, rot_idx.tolist())), orders,
               tuple(map(tuple, skeleton.position_layout().tolist())),
               tuple(sorted(skeleton.end_sites)))
        object.__setattr__(skeleton, "_fk_layout", key)
    return key


def _end_offsets(skeleton: Skeleton) -> np.ndarray:
    ends = sorted(skeleton.end_sites)
    return np.array([skeleton.end_sites[j] for j in ends]).reshape(len(ends), 3)


@lru_cache(maxsize=64)
def _jitted_fk(layout: tuple, with_end_sites: bool):
    return jax.jit(partial(_fk, layout=layout, with_end_sites=with_end_sites))


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
    # float64 whatever comes in: integer channels would truncate the bone offsets (cast to the
    # values' dtype inside), float32 would leak into the positions
    values = jnp.asarray(values, dtype=jnp.float64)
    lead = values.shape[:-1]
    flat = values.reshape(-1, values.shape[-1])
    n = flat.shape[0]
    flat = jnp.pad(flat, ((0, padded_length(n) - n), (0, 0)))
    out = f(flat, jnp.asarray(skeleton.offsets), jnp.asarray(_end_offsets(skeleton)))[:n]
    return out.reshape(*lead, *out.shape[-2:])


def fk_function(skeleton: Skeleton, with_end_sites: bool = False):
    """Traceable FK ``(values (..., C), offsets (J, 3)) -> (..., J, 3)`` for use inside jit."""
    layout = layout_key(skeleton)
    ends = jnp.asarray(_end_offsets(skeleton))
    return lambda v, offsets: _fk(v, offsets, ends, layout=layout,
                                  with_end_sites=with_end_sites)


def np_axis_rotation(axis: str, rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(rad), np.sin(rad)
    o, z = np.ones_like(rad), np.zeros_like(rad)
    rows = {"X": ((o, z, z), (z, c, -s), (z, s, c)), "Y": ((c, z, s), (z, o, z), (-s, z, c)),
            "Z": ((c, -s, z), (s, c, z), (z, z, o))}[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def euler_matrices(order: str, degrees: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations of BVH Euler angles (T, len(order)) applied in channel ``order``
    (R = R_order[0] R_order[1] ...), NumPy float64."""
    degrees = np.asarray(degrees, dtype=np.float64)
    R = np.broadcast_to(np.eye(3), (degrees.shape[0], 3, 3))
    for k, axis in enumerate(order):
        R = R @ np_axis_rotation(axis, np.deg2rad(degrees[:, k]))
    return R


def numpy_transforms(skeleton: Skeleton, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (T, J, 3, 3) and positions (T, J, 3) of (T, C) channel values, NumPy
    float64 (the equations of the module docstring; no end sites)."""
    v = np.asarray(values, dtype=np.float64)
    parents, rot_idx, orders, pos_idx, _ = layout_key(skeleton)
    Rw, pw = [], []
    for j, parent in enumerate(parents):
        R = euler_matrices(orders[j], v[:, list(rot_idx[j][:len(orders[j])])])
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
    return np.stack(Rw, axis=1), np.stack(pw, axis=1)


def numpy_positions(skeleton: Skeleton, values: np.ndarray, with_end_sites=False) -> np.ndarray:
    """FK in NumPy (float64, vectorised over frames): no compilation, for data handling.

    The same equations as the JAX version (tests check they agree); use the JAX one inside
    jitted or differentiated code.
    """
    values = np.asarray(values, dtype=np.float64)
    lead = values.shape[:-1]
    v = values.reshape(-1, values.shape[-1])
    Rw, pw = numpy_transforms(skeleton, v)
    ends = layout_key(skeleton)[4]
    if with_end_sites and len(ends):
        tips = [pw[:, j] + Rw[:, j] @ skeleton.end_sites[j] for j in ends]
        pw = np.concatenate([pw, np.stack(tips, axis=1).reshape(v.shape[0], -1, 3)], axis=1)
    return pw.reshape(*lead, -1, 3)


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


def _moving_channels(layout: tuple) -> np.ndarray:
    """(J, C) 0/1: channel c moves joint j. Those are the rotations of j's strict ancestors and
    the position channels of j and its ancestors (a joint's own rotation turns its children,
    not itself)."""
    parents, *_ = layout
    owner, is_rot = _channel_tables(layout)
    _, pos, _ = _plan(layout)
    J, C = len(parents), len(owner)
    out = np.zeros((J, C))
    for j in range(J):
        a, strict = j, False
        while a >= 0:
            if strict:
                out[j, np.flatnonzero(is_rot & (owner == a))] = 1.0
            if pos.size:
                out[j, pos[pos[:, 0] == a, 2]] = 1.0
            a, strict = parents[a], True
    return out


def _fk_with_variance(values, var, offsets, *, layout):
    """Positions (T, J, 3) and their first-order variance from independent channel variances.

    d p_d / d theta_c = (pi/180) w_c x (p_d - p_j) for a rotation channel of joint j, where
    w_c is that Euler rotation's axis in world coordinates; d p_d / d t_c = R_world[parent(j)]
    e_axis for a position channel. var(p_d)[k] = sum_c (d p_d[k] / d v_c)^2 var_c. Equal to
    ``jacfwd`` of the FK (a test checks this) at a fraction of its cost.
    """
    parents, rot_idx, orders, pos_idx, _ = layout
    owner, is_rot = _channel_tables(layout)
    groups, pos, _ = _plan(layout)
    T, C, J = values.shape[0], len(owner), len(parents)
    R, parts, t = _local(values, offsets, layout)
    Rw, Pj = _world(R, t, layout)
    P = jnp.swapaxes(Pj, 0, 1)  # (T, J, 3)
    # the parent's world rotation of every joint (identity at roots), joint-major
    par = np.asarray(parents)
    Rp = jnp.where(jnp.asarray(par >= 0)[:, None, None, None], Rw[np.maximum(par, 0)],
                   jnp.eye(3, dtype=values.dtype))
    Wc = jnp.zeros((C, T, 3), values.dtype)
    for order, (js, cols) in groups.items():  # world axis of each Euler rotation
        for k, axis in enumerate(order):  # the parent's rotation times the partial product's
            col = parts[order][k][..., :, "XYZ".index(axis)]  # column: one matrix-vector
            Wc = Wc.at[cols[:, k]].set(_mv3(Rp[js], col))
    if pos.size:
        Wc = Wc.at[pos[:, 2]].set(Rp[pos[:, 0], :, :, pos[:, 1]])
    # For a rotation channel, (w x (p - q))_k = (w x p)_k - s_k with s = w x q (q its pivot).
    # Squared and summed over channels with weights u_c = rad^2 var_c, that is a quadratic in
    # p whose coefficients are sums over channels of w w^T (6 numbers), s w^T (9) and s^2 (3):
    # 18 per-channel features, accumulated down the tree (a position channel adds u_c W^2 / rad^2
    # to the constant), then expanded per joint. Points are taken relative to the root to keep
    # the terms small. Everything is channel- or joint-major (leading axis), frames second.
    P0 = Pj - Pj[:1]  # (J, T, 3)
    sv = jnp.cross(Wc, P0[owner])  # (C, T, 3)
    rad2 = (np.pi / 180.0) ** 2
    rot = jnp.asarray(is_rot)[:, None, None]
    w0, w1, w2 = Wc[..., 0], Wc[..., 1], Wc[..., 2]
    ww = jnp.stack([w0 * w0, w1 * w1, w2 * w2, w1 * w2, w0 * w2, w0 * w1], axis=-1)  # (C, T, 6)
    sw = (sv[..., :, None] * Wc[..., None, :]).reshape(C, T, 9)  # s_k w_i at 3k + i
    feats = jnp.concatenate([jnp.where(rot, ww, 0.0), jnp.where(rot, sw, 0.0),
                             jnp.where(rot, sv * sv, Wc * Wc / rad2)], axis=-1)
    featsw = feats * (rad2 * var[:, :C].T[..., None])  # (C, T, 18)
    # the channels that move joint j, summed: one product with a static 0/1 (J, C) matrix
    agg = jnp.einsum("jc,ctf->jtf", jnp.asarray(_moving_channels(layout), values.dtype), featsw)
    O = agg[..., :6]  # sums of w w^T: xx, yy, zz, yz, xz, xy
    H = agg[..., 6:15].reshape(J, T, 3, 3)  # H[k, i] = sum of s_k w_i
    x, y, z = P0[..., 0], P0[..., 1], P0[..., 2]
    # |(w x p)_k|^2 summed: x: (w_y p_z - w_z p_y)^2, y: (w_z p_x - w_x p_z)^2,
    # z: (w_x p_y - w_y p_x)^2
    quad = jnp.stack([O[..., 1] * z * z - 2 * O[..., 3] * y * z + O[..., 2] * y * y,
                      O[..., 2] * x * x - 2 * O[..., 4] * x * z + O[..., 0] * z * z,
                      O[..., 0] * y * y - 2 * O[..., 5] * x * y + O[..., 1] * x * x], axis=-1)
    # (w x p)_k s_k summed: x: H_xy p_z - H_xz p_y, y: H_yz p_x - H_yx p_z, z: H_zx p_y - H_zy p_x
    lin = jnp.stack([H[..., 0, 1] * z - H[..., 0, 2] * y,
                     H[..., 1, 2] * x - H[..., 1, 0] * z,
                     H[..., 2, 0] * y - H[..., 2, 1] * x], axis=-1)
    var_p = jnp.maximum(quad - 2 * lin + agg[..., 15:], 0.0)
    return P, jnp.swapaxes(var_p, 0, 1)


def fk_variance_function(skeleton: Skeleton):
    """Traceable ``(values (T, C), var (T, C), offsets) -> positions, variance (T, J, 3)``."""
    return partial(_fk_with_variance, layout=layout_key(skeleton))


@lru_cache(maxsize=64)
def _jitted_fk_variance(layout: tuple):
    return jax.jit(partial(_fk_with_variance, layout=layout))


def forward_kinematics_with_variance(skeleton: Skeleton, values, var):
    """World joint positions (T, J, 3) and their first-order variance (T, J, 3), NumPy, from
    channel values (T, C) with independent variances (T, C); compiled per joint layout and
    padded frame bucket, like :func:`forward_kinematics`."""
    f = _jitted_fk_variance(layout_key(skeleton))
    values, var = np.asarray(values, np.float64), np.asarray(var, np.float64)
    n = values.shape[0]
    pad = ((0, padded_length(n) - n), (0, 0))
    p, v = f(np.pad(values, pad), np.pad(var, pad), skeleton.offsets)
    return np.asarray(p)[:n], np.asarray(v)[:n]


def other_euler_solution(angles: np.ndarray, order: str) -> np.ndarray:
    """(..., 3) Euler angles (degrees) of the same rotations on the other branch: for
    Tait-Bryan orders (three different axes) ``(a + 180, 180 - b, c + 180)``; proper Euler orders
    (a repeated axis) are returned as they are."""
    angles = np.asarray(angles, dtype=np.float64)
    if len(set(order)) != 3:
        return angles
    out = angles + np.array([180.0, 0.0, 180.0])
    out[..., 1] = 180.0 - angles[..., 1]
    return out


def circular_mean_deg(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Circular mean of angles in degrees along ``axis``, in (-180, 180]."""
    rad = np.deg2rad(values)
    return np.rad2deg(np.arctan2(np.sin(rad).mean(axis), np.cos(rad).mean(axis)))
