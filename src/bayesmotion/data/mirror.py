"""Left-right mirroring of motions, and a label-free canonical walking side.

Mirroring reflects the whole motion through a vertical plane and swaps every left joint with its
right partner. In world coordinates it is exact: the mirrored motion's joint ``j`` sits at
``M p[sigma(j)]`` in every frame, with ``M`` the reflection and ``sigma`` the left-right
pairing (tested to float precision). The channels are rewritten so that the result is an
ordinary motion of the same skeleton:

* the mirrored world rotation of joint ``j`` is ``G'_j = M G_sigma(j) M A_j``, where ``A_j`` is a
  fixed axis-aligned rotation per joint, chosen so that the skeleton's offsets fit
  (``A_j t_c = M t_sigma(c)`` for each child ``c``: rigs such as Bandai's give the right arm a
  frame turned half a turn from the mirrored left one) and, where the offsets leave a choice,
  so that the mirrored rotations lie closest to the motion's own (:func:`mirror_plan`);
* the local rotations ``A_p^T M L_sigma(j) M A_j`` are written back as Euler angles in each
  joint's channel order, continuous in time, on the branch and turn nearest to the joint's own
  angles at the first frame (near gimbal lock that can still differ from how real clips of the
  joint are written: :func:`reframe` with :func:`rest_frames` removes the problem); position
  channels become ``A_p^T M t_sigma(j)``;
* a skeleton that is not exactly symmetric (CMU's, measured on a person) is mirrored with the
  motion: joint ``j``'s offset becomes ``A_p^T M`` times its partner's (end sites alike), so the
  result may carry a skeleton with other offsets and the same joints and channels.

A person's left-right asymmetry is small next to what a walking direction changes, so a mirrored
walk to the right is a walk to the left. :func:`canonical_side` uses that: it mirrors every clip
that moves sideways to the actor's right (:func:`lateral_ratio`, from positions only, no labels),
so walks to either side share one representation. Emotion inference on the Bandai walks uses it
(``benchmarks/bandai_inference.py``).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Iterable, Sequence
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from bayesmotion.data.fk import euler_matrices, other_euler_solution
from bayesmotion.data.motion import Motion, find_mover
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError

# (left, right) spellings, tried as prefix, as (longer than one letter) suffix and after a
# namespace separator ("mixamorig:LeftArm", "Character1_LeftUpLeg"); a name pairs only with a
# name that exists ("LowerBack" has no "RowerBack")
_SIDE_TOKENS = (("_L", "_R"), (".L", ".R"), ("_l", "_r"), ("Left", "Right"), ("left", "right"),
                ("L_", "R_"), ("L", "R"), ("l", "r"))
_SEPARATORS = ":_.|"


def _axis_rotations() -> np.ndarray:
    """The 24 proper rotations that map coordinate axes to coordinate axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            A = np.zeros((3, 3))
            A[np.arange(3), perm] = signs
            if np.linalg.det(A) > 0:
                out.append(A)
    return np.array(out)


_AXIS_ROTATIONS = _axis_rotations()


def mirror_pairs(skeleton: Skeleton, pairs: dict[str, str] | None = None) -> np.ndarray:
    """(J,) index of each joint's left-right partner (itself for joints on the midline).

    Partners are found from the names (``Hand_L``/``Hand_R``, ``LeftArm``/``RightArm``,
    ``lhumerus``/``rhumerus``, ...) unless ``pairs`` maps left names to right names. The pairing
    must respect the tree (the partner of a joint's parent is its partner's parent).
    """
    names = list(skeleton.names)
    index = {n: i for i, n in enumerate(names)}
    perm = np.arange(len(names))
    if pairs is not None:
        if not pairs:
            raise BayesmotionError("pairs is empty; give {left name: right name, ...}")
        for a, b in pairs.items():
            for n in (a, b):
                if n not in index:
                    raise BayesmotionError(f"mirror pairs name {n!r}, not a joint of this "
                                           f"skeleton ({', '.join(names)})")
            perm[index[a]], perm[index[b]] = index[b], index[a]
    else:
        for i, n in enumerate(names):
            for left, right in _SIDE_TOKENS:
                candidates = _swapped(n, left, right) + _swapped(n, right, left)
                hit = [c for c in candidates if c in index and c != n]
                if hit:
                    perm[i] = index[hit[0]]
                    break
        if np.all(perm == np.arange(len(names))):
            raise BayesmotionError(
                "no left-right joint pairs found in the joint names (looked for _L/_R, .L/.R, "
                "_l/_r, Left/Right, L_/R_ and l/r, r/l prefixes); pass pairs={left: right, ...}")
    if not np.array_equal(perm[perm], np.arange(len(names))):
        raise BayesmotionError("mirror pairs are not symmetric (a joint's partner has another "
                               "partner); pass pairs={left: right, ...}")
    parents = np.array(skeleton.parents)
    for j, p in enumerate(parents):
        q = parents[perm[j]]
        if (p < 0) != (q < 0) or (p >= 0 and perm[p] != q):
            raise BayesmotionError(
                f"mirror pairs break the joint tree: {names[j]!r} has parent "
                f"{names[p] if p >= 0 else None!r}, its partner {names[perm[j]]!r} has "
                f"{names[q] if q >= 0 else None!r}")
    return perm


class MirrorPlan(NamedTuple):
    """What :func:`mirror` needs for one skeleton.

    Attributes:
        perm: (J,) left-right partner of each joint.
        reflection: (3, 3) the world reflection ``M`` (a vertical plane).
        frames: (J, 3, 3) the per-joint axis-aligned rotations ``A_j``.
        left: (J,) True for the joints on the actor's left (the keys of explicit ``pairs``,
            else read from the names).
    """

    perm: np.ndarray
    reflection: np.ndarray
    frames: np.ndarray
    left: np.ndarray


def world_and_local(skeleton: Skeleton, values: np.ndarray):
    """World rotations (T, J, 3, 3), local rotations (T, J, 3, 3) and local translations
    (T, J, 3) of a (T, C) channel array."""
    rot_idx, orders = skeleton.rotation_layout()
    pos_idx = skeleton.position_layout()
    T, J = values.shape[0], skeleton.n_joints
    L = np.empty((T, J, 3, 3))
    G = np.empty((T, J, 3, 3))
    t = np.empty((T, J, 3))
    for j, p in enumerate(skeleton.parents):
        n = len(orders[j])
        L[:, j] = euler_matrices(orders[j], values[:, rot_idx[j, :n]]) if n else np.eye(3)
        t[:, j] = skeleton.offsets[j]
        for a in range(3):
            if pos_idx[j, a] >= 0:
                t[:, j, a] = values[:, pos_idx[j, a]]
        G[:, j] = L[:, j] if p < 0 else G[:, p] @ L[:, j]
    return G, L, t


def mirror_plan(skeleton: Skeleton, motions: Iterable[Motion] = (), *, axis: int = 0,
                pairs: dict[str, str] | None = None) -> MirrorPlan:
    """The partners, reflection and per-joint frames that mirror motions of ``skeleton``.

    Args:
        skeleton: the joint tree.
        motions: reference motions of this skeleton; where the offsets allow several frames
            ``A_j``, the one whose mirrored world rotations lie closest to the motions' own is
            taken. Pass the clips to be mirrored (or a few of them) so every clip is mirrored
            with the same plan.
        axis: the world axis the reflection negates (0: X, 2: Z; Y is up). Either gives the
            same motion up to a half turn about the vertical.
        pairs: explicit ``{left name: right name}`` partners (default: from the names).
    """
    if axis not in (0, 2):
        raise BayesmotionError(f"axis must be 0 (X) or 2 (Z), the horizontal axes; got {axis}")
    perm = mirror_pairs(skeleton, pairs)
    M = np.eye(3)
    M[axis, axis] = -1.0
    motions = list(motions)
    for m in motions:
        if not m.skeleton.same_layout(skeleton):
            raise BayesmotionError(f"motion {m.name!r} has another skeleton than the plan's")
    size = skeleton.size()
    rigid = np.ones(skeleton.n_joints, dtype=bool)
    if motions:
        refs = [world_and_local(skeleton, m.values) for m in motions]
        G = np.concatenate([r[0] for r in refs])
        t_all = np.concatenate([r[2] for r in refs])
        t_mean = t_all.mean(0)
        # a translation that moves (the walking hips) is no bone: it sets no frame
        rigid = np.max(np.ptp(t_all, axis=0), axis=-1) <= 1e-6 * size
    else:
        G = None
        t_mean = np.asarray(skeleton.offsets, dtype=np.float64)
    frames = np.empty((skeleton.n_joints, 3, 3))
    for j in range(skeleton.n_joints):
        kids = skeleton.children(j)
        targets = [(t_mean[c], M @ t_mean[perm[c]]) for c in kids if rigid[c] and rigid[perm[c]]]
        if j in skeleton.end_sites:
            targets.append((skeleton.end_sites[j], M @ skeleton.end_sites[perm[j]]))
        off = np.array([sum(np.linalg.norm(A @ a - b) for a, b in targets)
                        for A in _AXIS_ROTATIONS])
        ok = off <= off.min() + 0.02 * size
        if G is not None:
            fit = np.array([np.mean(np.sum((M @ G[:, perm[j]] @ M @ A - G[:, j]) ** 2,
                                           axis=(-2, -1))) for A in _AXIS_ROTATIONS])
            fit[~ok] = np.inf
            frames[j] = _AXIS_ROTATIONS[int(np.argmin(fit))]
        else:
            frames[j] = _AXIS_ROTATIONS[int(np.argmin(np.where(ok, np.arange(len(ok)), 99)))]
    if pairs is not None:
        left = np.isin(np.arange(skeleton.n_joints), [skeleton.index(a) for a in pairs])
    else:
        left = _left_mask(skeleton, perm)
    return MirrorPlan(perm, M, frames, left)


def _euler_tracks(R: np.ndarray, orders: Sequence[str], reference: np.ndarray) -> np.ndarray:
    """(T, n, 3) Euler angles (degrees) of ``n`` joints' rotations R (T, n, 3, 3), one Euler
    order per joint, each joint's track continuous in time and on the branch and turn nearest to
    its ``reference`` (T, n, 3) at the first frame. The branch choice runs once per frame over
    every joint (one Python step per frame, not per frame and joint); joints never interact."""
    T, n = R.shape[:2]
    a = np.empty((T, n, 3))
    with warnings.catch_warnings():  # at gimbal lock scipy warns; the rotation is still exact
        warnings.filterwarnings("ignore", "Gimbal lock", UserWarning)
        for i, order in enumerate(orders):
            a[:, i] = Rotation.from_matrix(R[:, i]).as_euler(order.upper(), degrees=True)
    # Tait-Bryan: the second solution of the same rotation
    b = np.stack([other_euler_solution(a[:, i], o) for i, o in enumerate(orders)], axis=1)
    out = np.empty_like(a)
    prev = reference[0]
    for k in range(T):
        ca = prev + (a[k] - prev + 180.0) % 360.0 - 180.0  # each solution on the turn nearest
        cb = prev + (b[k] - prev + 180.0) % 360.0 - 180.0  # the previous frame's angles
        nearer_a = np.sum((ca - prev) ** 2, -1) <= np.sum((cb - prev) ** 2, -1)
        prev = out[k] = np.where(nearer_a[:, None], ca, cb)
    # each whole track by the turn that brings its mean nearest the reference's
    shift = 360.0 * np.round((reference.mean(0) - out.mean(0)) / 360.0)
    return out + shift


def mirror(motion: Motion, plan: MirrorPlan | None = None) -> Motion:
    """The left-right mirror image of ``motion`` (see the module docstring).

    ``plan`` defaults to :func:`mirror_plan` of the motion's skeleton with the motion itself as
    the reference; pass one plan to mirror several clips alike.
    """
    plan = mirror_plan(motion.skeleton, (motion,)) if plan is None else plan
    out = _reframe(motion, plan.perm, plan.reflection, plan.frames, near_original=True)
    return out.replace(name=f"{motion.name} (mirrored)".strip())


def rest_frames(motions: Sequence[Motion], fixed: Iterable[int] | None = None) -> np.ndarray:
    """(J, 3, 3) per-joint frames ``B_j`` that make each joint's mean local rotation the
    identity (see :func:`reframe`).

    ``B_j = mean(L_j)^T B_parent``, with ``mean(L_j)`` the rotation nearest the average of the
    joint's local rotation matrices over every frame of ``motions``. Joints in ``fixed`` keep
    their frame (``B = I``); by default the joint that carries the translation and its
    ancestors, whose heading the pose representation takes out itself.
    """
    motions = list(motions)
    if not motions:
        raise BayesmotionError("rest_frames needs at least one motion")
    sk = motions[0].skeleton
    for m in motions:
        if not m.skeleton.same_layout(sk):
            raise BayesmotionError(f"motion {m.name!r} has another skeleton than the first")
    if fixed is None:
        j, fixed = find_mover(motions), set()
        while j >= 0:
            fixed.add(j)
            j = sk.parents[j]
    fixed = set(fixed)
    L = np.concatenate([world_and_local(sk, m.values)[1] for m in motions])
    B = np.empty((sk.n_joints, 3, 3))
    for j, p in enumerate(sk.parents):
        if j in fixed:
            B[j] = np.eye(3)
            continue
        U, _, Vt = np.linalg.svd(L[:, j].mean(0))
        mean = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        B[j] = mean.T @ (np.eye(3) if p < 0 else B[p])
    return B


def reframe(motion: Motion, frames: np.ndarray, reference: np.ndarray | None = None) -> Motion:
    """``motion`` on the same joints with each joint's frame turned by ``frames`` (J, 3, 3).

    World positions are unchanged (to float precision); local rotations become
    ``B_p^T L_j B_j`` and offsets ``B_p^T t_j``, written as Euler angles in each joint's channel
    order on the branch nearest zero. With :func:`rest_frames` the angles stay near zero, away
    from gimbal lock: Bandai's spine sits at 85 degrees in its middle Euler angle, where its
    first and third angles trade off freely from clip to clip (they range over 25-141 degrees
    with their sum near zero).

    ``reference`` (C,) channel values: take each joint's angles on the branch and turn nearest
    these instead of zero (e.g. the circular mean of clips on the target frames, when turning
    frames back)."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.shape != (motion.skeleton.n_joints, 3, 3):
        raise BayesmotionError(f"frames must be ({motion.skeleton.n_joints}, 3, 3) for this "
                               f"skeleton, got {frames.shape}")
    eye = np.broadcast_to(np.eye(3), frames.shape)
    if not (np.allclose(frames @ np.swapaxes(frames, -1, -2), eye, atol=1e-9)
            and np.allclose(np.linalg.det(frames), 1.0, atol=1e-9)):
        raise BayesmotionError("frames must be rotations (orthonormal, determinant +1)")
    if reference is not None:
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (motion.skeleton.n_channels,):
            raise BayesmotionError(f"reference must have one value per channel "
                                   f"({motion.skeleton.n_channels},), got {reference.shape}")
    return _reframe(motion, np.arange(motion.skeleton.n_joints), np.eye(3), frames,
                    near_original=False, reference=reference)


def _reframe(motion: Motion, perm: np.ndarray, M: np.ndarray, A: np.ndarray,
             near_original: bool, reference: np.ndarray | None = None) -> Motion:
    """Joint ``j`` takes partner ``perm[j]``'s motion reflected by ``M``, in frame ``A[j]``:
    local rotations ``A_p^T M L_perm(j) M A_j``, translations ``A_p^T M t_perm(j)``."""
    sk = motion.skeleton
    if len(perm) != sk.n_joints:
        raise BayesmotionError(f"mirror plan is for {len(perm)} joints, the motion has "
                               f"{sk.n_joints}")
    _, L, t = world_and_local(sk, motion.values)
    rot_idx, orders = sk.rotation_layout()
    pos_idx = sk.position_layout()
    out = motion.values.copy()
    tracks = []  # (rotations, order, reference, columns) of the joints whose angles change
    for j, p in enumerate(sk.parents):
        Ap = np.eye(3) if p < 0 else A[p]
        s = perm[j]
        if s == j and not (np.any(M != np.eye(3)) or np.any(A[j] != np.eye(3))
                           or np.any(Ap != np.eye(3))):
            continue  # nothing changes: keep the channels as they are, bit for bit
        n = len(orders[j])
        if n:
            if n != 3:
                raise BayesmotionError(f"joint {sk.names[j]!r} has {n} rotation channels; "
                                       "mirroring and reframing need all three")
            Lm = Ap.T @ M @ L[:, s] @ M @ A[j]
            cols = rot_idx[j, :n]
            if near_original:
                ref = motion.values[:, cols]
            elif reference is not None:
                ref = np.broadcast_to(reference[cols], (len(Lm), 3))
            else:
                ref = np.zeros((len(Lm), 3))
            tracks.append((Lm, orders[j], ref, cols))
        tm = t[:, s] @ (Ap.T @ M).T
        for a in range(3):
            if pos_idx[j, a] >= 0:
                out[:, pos_idx[j, a]] = tm[:, a]
    if tracks:
        Ls, ords, refs, cols = zip(*tracks, strict=True)
        angles = _euler_tracks(np.stack(Ls, 1), ords, np.stack(refs, 1))
        for i, c in enumerate(cols):
            out[:, c] = angles[:, i]
    return motion.replace(skeleton=_moved_skeleton(sk, perm, M, A), values=out)


def _moved_skeleton(sk: Skeleton, perm: np.ndarray, M: np.ndarray, A: np.ndarray) -> Skeleton:
    """The skeleton :func:`_reframe` gives its result: offsets ``A_p^T M t_perm(j)``, end sites
    ``A_j^T M e_perm(j)``; ``sk`` itself when nothing moves (to 1e-9 of its size)."""
    offsets = np.array([(np.eye(3) if p < 0 else A[p]).T @ M @ sk.offsets[perm[j]]
                        for j, p in enumerate(sk.parents)])
    ends = {j: A[j].T @ M @ sk.end_sites[perm[j]] for j in sk.end_sites}
    if (np.allclose(offsets, sk.offsets, rtol=0, atol=1e-9 * sk.size())
            and all(np.allclose(e, sk.end_sites[j], rtol=0, atol=1e-9 * sk.size())
                    for j, e in ends.items())):
        return sk
    return Skeleton(sk.names, sk.parents, offsets, sk.channels, ends)


def reframed_skeleton(skeleton: Skeleton, frames: np.ndarray) -> Skeleton:
    """The skeleton that :func:`reframe` with ``frames`` gives a motion of ``skeleton``."""
    n = skeleton.n_joints
    return _moved_skeleton(skeleton, np.arange(n), np.eye(3), np.asarray(frames, float))


def mirrored_skeleton(skeleton: Skeleton, plan: MirrorPlan) -> Skeleton:
    """The skeleton that :func:`mirror` with ``plan`` gives a motion of ``skeleton``."""
    return _moved_skeleton(skeleton, plan.perm, plan.reflection, plan.frames)


def _swapped(name: str, a: str, b: str) -> list[str]:
    """``name`` with token ``a`` replaced by ``b`` at its start, at its end or after a
    namespace separator (the last two for tokens longer than one letter)."""
    out = []
    if len(a) > 1 and name.endswith(a):
        out.append(name[: -len(a)] + b)
    if name.startswith(a):
        out.append(b + name[len(a):])
    if len(a) > 1:
        for sep in _SEPARATORS:
            k = name.find(sep + a)
            if k >= 0:
                out.append(name[: k + 1] + b + name[k + 1 + len(a):])
    return out


def _is_left(name: str, partner: str) -> bool:
    """Whether ``name`` is the left one of the pair (``name``, ``partner``)."""
    for left, right in _SIDE_TOKENS:
        if partner in _swapped(name, left, right):
            return True
        if partner in _swapped(name, right, left):
            return False
    return False


def _left_mask(skeleton: Skeleton, perm: np.ndarray) -> np.ndarray:
    names = skeleton.names
    return np.array([perm[j] != j and _is_left(n, names[perm[j]]) for j, n in enumerate(names)])


def _left_right(skeleton: Skeleton, perm: np.ndarray,
                left_mask: np.ndarray) -> tuple[list[int], list[int]]:
    """The paired joints attached to the midline (hip joints, shoulders: their left-right line
    is the torso's) on the actor's left, and their right partners."""
    parents = skeleton.parents
    left = [j for j in range(skeleton.n_joints) if left_mask[j] and parents[j] >= 0
            and perm[parents[j]] == parents[j]]
    return left, [int(perm[j]) for j in left]


def lateral_ratio(motion: Motion, plan: MirrorPlan | None = None) -> float:
    """Mean sideways speed towards the actor's left, as a fraction of the mean horizontal speed
    (about +0.5 for a diagonal walk to the left, -0.5 to the right, near 0 straight ahead or
    back; mirroring negates it). The mover is the joint that carries the translation
    (:func:`~bayesmotion.data.motion.find_mover`); the actor's left is the direction
    from the right joints to their left partners, summed over the pairs that hang from the
    midline (hip joints, shoulders)."""
    sk = motion.skeleton
    if plan is None:
        perm = mirror_pairs(sk)
        left, right = _left_right(sk, perm, _left_mask(sk, perm))
    else:
        left, right = _left_right(sk, plan.perm, plan.left)
    if not left:
        raise BayesmotionError("lateral_ratio needs left-right joint pairs; none were found "
                               f"in {', '.join(sk.names)}")
    if motion.n_frames < 2:
        raise BayesmotionError("lateral_ratio needs at least two frames")
    p = motion.positions()[..., [0, 2]]
    v = np.diff(p, axis=0) * motion.fps
    v = v[:, find_mover([motion])]
    u = np.sum(p[:, left] - p[:, right], axis=1)
    u = 0.5 * (u[1:] + u[:-1])
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    speed = np.mean(np.linalg.norm(v, axis=-1))
    return float(np.mean(np.sum(v * u, axis=-1)) / max(speed, 1e-12))


def canonical_side(motions: Sequence[Motion], threshold: float = 0.15,
                   plan: MirrorPlan | None = None) -> tuple[list[Motion], np.ndarray]:
    """Mirror every motion that moves to the actor's right (``lateral_ratio < -threshold``).

    Returns the motions (mirrored or not) and a boolean array saying which were mirrored. One
    plan (default: :func:`mirror_plan` with all the motions as reference) mirrors them all.
    """
    motions = list(motions)
    if not motions:
        return [], np.zeros(0, dtype=bool)
    if plan is None:
        plan = mirror_plan(motions[0].skeleton, motions)
    flip = np.array([lateral_ratio(m, plan) < -threshold for m in motions])
    return [mirror(m, plan) if f else m for m, f in zip(motions, flip, strict=True)], flip
