"""The pose representation Y that the GP model sees, and its exact inverse.

``PoseCodec`` turns a :class:`Motion` into a matrix ``Y: (T, D)`` and back:

* **Rotations: unwrapped Euler angles.** The BVH channels are Euler angles; unwrapping them in
  time (``np.unwrap`` with period 360 deg) removes the 360 deg jumps while staying *exactly*
  invertible (BVH accepts any angle), keeps one number per channel (no 3 -> 4 or 3 -> 9 blow-up),
  and keeps the channel layout of Taubert et al., who model joint angles. The exponential map is
  smoother near gimbal lock, but converting back is not bit-exact and the real data here never
  comes near it (checked in tests: frame-to-frame steps stay small after unwrapping).
* **Root translation.** The *mover* is the first joint whose horizontal position channels change
  in the training data: the root in CMU files, ``Hips`` under Bandai's static ``joint_Root``.
  Its horizontal position channels (the vertical one is kept) are represented as
  ``"heading"`` -- velocity in the mover's own heading frame plus the heading's rate of turn,
  with the mover's rotation stored with its heading removed; the first position and heading are
  the anchor. A walk to the left and a walk to the right then look alike: only how the body
  moves relative to where it faces is modelled (the default for one-actor clips such as gaits,
  where the walking direction carries no style);
  ``"velocity"`` -- per-second horizontal velocity in the world frame, with the first position
  stored as an anchor;
  ``"partner"`` -- position relative to the midpoint of the two actors' roots, with the midpoint
  trajectory stored as the anchor (two-actor trials: the approach is the interaction);
  ``"absolute"`` -- unchanged.
* **Constant channels** (range below ``1e-9`` over all training frames) are dropped and restored.
* **Normalisation**: every kept channel is centred on its own mean and divided by a per-channel
  scale stored with the codec. By default (``scaling="type"``) the scale is the pooled standard
  deviation of the channel's kind (rotations, root translation), so joint angles keep their
  physical weighting; ``scaling="channel"`` standardises each channel alone, which inflates
  near-constant channels (fingers, toes) to the weight of the hips.

``decode(encode(m))`` reproduces the joint positions of ``m`` to float64 precision (tested to
< 1e-6 of the skeleton's size on the real data).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import BayesmotionError, SkeletonMismatchError
from .fk import _np_axis_rotation, euler_matrices
from .motion import Motion
from .skeleton import ROTATION_CHANNELS, Skeleton

RootMode = Literal["heading", "velocity", "partner", "absolute"]
ROOT_MODES = ("heading", "velocity", "partner", "absolute")
UP_AXIS = 1  # Y is up in BVH files from CMU and Bandai


class Encoded(NamedTuple):
    """One actor's motion in model space.

    Attributes:
        Y: (T, D) normalised pose features.
        anchor: what decoding needs besides Y: (2,) first horizontal root position
            ("velocity"), (3,) first horizontal position and heading in radians ("heading"),
            (T, 2) partner midpoint ("partner"), or (0,) ("absolute").
    """

    Y: np.ndarray
    anchor: np.ndarray


def _root_horizontal_columns(skeleton: Skeleton, mover: int = 0) -> np.ndarray:
    cols = skeleton.position_layout()[mover]
    return np.array([cols[a] for a in range(3) if a != UP_AXIS and cols[a] >= 0], dtype=int)


def find_mover(motions) -> int:
    """The joint whose horizontal position channels travel the most (0 when none moves).

    BVH exporters differ: CMU translates the root, Bandai keeps a ``joint_Root`` at the origin
    and translates ``Hips`` below it. "Travel" is the median frame-to-frame horizontal step,
    summed over the motions, so that a joint which moves in a few clips only is not taken for
    the one that walks in all (Bandai's ``joint_Root`` sits at the origin in every walk but the
    short walk-back normal one, where it carries the translation)."""
    sk = motions[0].skeleton
    best, best_step = 0, 0.0
    for j in range(sk.n_joints):
        h = _root_horizontal_columns(sk, j)
        if h.size == 0:
            continue
        step = sum(float(np.median(np.linalg.norm(np.diff(m.values[:, h], axis=0), axis=-1)))
                   for m in motions if m.n_frames > 1)
        if step > best_step:
            best, best_step = j, step
    return best


def _matrices_to_euler(order: str, R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`bayesmotion.data.fk.euler_matrices` (intrinsic Tait-Bryan), unwrapped
    in time."""
    e = Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)
    return np.unwrap(e, period=360.0, axis=0)


def _yaw(angle: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations about the up axis by ``angle`` radians."""
    return _np_axis_rotation("XYZ"[UP_AXIS], angle)


def _horizontal_angle(vec: np.ndarray) -> np.ndarray:
    """Angle psi of the horizontal part of vectors (T, 3) such that yaw(-psi) turns it onto +X."""
    unit = np.zeros((vec.shape[0], 3))
    unit[:, 0] = 1.0
    side = np.cross(unit, vec)[:, UP_AXIS]  # sin psi * |v_h|, sign fixed by the yaw convention
    return np.unwrap(np.arctan2(side, vec[:, 0]))


def _unwrap(values: np.ndarray, rot: np.ndarray) -> np.ndarray:
    v = np.array(values, dtype=np.float64)
    v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
    return v


def _midpoint(motion: Motion, partner: Motion, h: np.ndarray) -> np.ndarray:
    if partner.n_frames != motion.n_frames:
        raise BayesmotionError("partner motion must have the same number of frames")
    return 0.5 * (motion.values[:, h] + partner.values[:, h])


@dataclass(frozen=True, eq=False)
class PoseCodec:
    """Fitted map between one actor slot's motions and Y.

    Attributes:
        skeleton: reference skeleton (channel layout; offsets used by default when decoding).
        root_mode: how the root's horizontal translation is represented (module docstring).
        keep: (D,) channel columns kept in Y (in the transformed channel space).
        constant: (C,) values restored for dropped channels ((C + 1,) in "heading" mode).
        mean: (D,) per-channel mean of the kept channels.
        scale: (D,) per-channel scale of the kept channels.
        scaling: "type" or "channel" (how ``scale`` was chosen).
        mover: the joint whose horizontal translation is the root motion (:func:`find_mover`).
        heading_axis: ("heading" only) the mover's local axis whose horizontal direction defines
            its heading: the axis closest to horizontal in the training data. The transformed
            channel space then has one extra last column, the heading's rate (deg/s).
        branch: per transformed column, the reference angle (degrees; NaN for non-rotation
            columns) that picks each clip's 360-degree branch: a clip's unwrapped angle is
            shifted by whole turns so that its mean lies within 180 degrees of the reference,
            the circular mean of the training data. Unwrapping alone keeps one clip continuous
            but leaves two clips of the same pose a turn apart (Bandai's Hips near +-180 deg).
            None (files written before it existed): no shift.
        fps: frame rate of the training motions, the default of :meth:`decode` (None in files
            written before it was stored).
    """

    skeleton: Skeleton
    root_mode: str
    keep: np.ndarray
    constant: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    scaling: str = "type"
    mover: int = 0
    heading_axis: int = -1
    branch: np.ndarray | None = None
    fps: float | None = None

    @property
    def dim(self) -> int:
        return int(self.keep.size)

    @property
    def channel_names(self) -> tuple[str, ...]:
        names = list(self.skeleton.channel_names)
        if self.root_mode == "heading":
            names.append(f"{self.skeleton.names[self.mover]}:heading_rate")
        return tuple(names[c] for c in self.keep)

    def horizontal_columns(self, skeleton: Skeleton | None = None) -> np.ndarray:
        """Columns of the mover's horizontal position channels."""
        return _root_horizontal_columns(skeleton or self.skeleton, self.mover)

    # ---------------------------------------------------------------- fitting
    @classmethod
    def fit(cls, motions, partners=None, root_mode: RootMode = "velocity",
            scaling: str = "type") -> PoseCodec:
        """Fit drops, means and scales on training motions (one actor slot).

        Args:
            motions: motions of this actor slot, all with the same channel layout.
            partners: the partner's motion for each (``root_mode="partner"`` only).
            root_mode: see the module docstring.
            scaling: "type" (pooled per channel kind) or "channel".
        """
        motions = list(motions)
        if not motions:
            raise BayesmotionError("PoseCodec.fit needs at least one motion")
        if root_mode not in ROOT_MODES:
            raise BayesmotionError(f"root_mode must be one of {'/'.join(ROOT_MODES)}, "
                                   f"got {root_mode!r}")
        if root_mode == "partner" and (partners is None or len(partners) != len(motions)):
            raise BayesmotionError("root_mode='partner' needs one partner motion per motion")
        if scaling not in ("type", "channel"):
            raise BayesmotionError(f"scaling must be 'type' or 'channel', got {scaling!r}")
        sk = motions[0].skeleton
        for m in motions[1:]:
            check_layout(sk, m.skeleton)
        mover = find_mover(motions)
        axis = -1
        if root_mode == "heading":
            axis = _heading_axis(motions, mover)
        width = sk.n_channels + (root_mode == "heading")
        proto = cls(sk, root_mode, np.arange(width), np.zeros(width), np.zeros(width),
                    np.ones(width), scaling, mover, axis)
        parts = [proto._untangled(m, None if partners is None else partners[i])[0]
                 for i, m in enumerate(motions)]
        rot = proto._kinds() == 0
        rad = np.deg2rad(np.concatenate(parts)[:, rot])
        branch = np.full(width, np.nan)
        branch[rot] = np.rad2deg(np.arctan2(np.sin(rad).mean(0), np.cos(rad).mean(0)))
        proto = replace(proto, branch=branch)
        raw = np.concatenate([proto._on_branch(v) for v in parts])
        rng = raw.max(0) - raw.min(0)
        keep = np.flatnonzero(rng > 1e-9 * (1.0 + np.abs(raw).max(0)))
        kept = raw[:, keep]
        mean = kept.mean(0)
        std = kept.std(0)
        if scaling == "channel":
            scale = np.where(std > 0, std, 1.0)
        else:
            kind = proto._kinds()[keep]
            scale = np.ones_like(mean)
            for k in np.unique(kind):
                sel = kind == k
                scale[sel] = np.sqrt(np.mean(std[sel] ** 2)) or 1.0
        return cls(sk, root_mode, keep, raw[0].copy(), mean, scale, scaling, mover, axis, branch,
                   float(motions[0].fps))

    def _kinds(self) -> np.ndarray:
        """(C[+1],) 0 for rotation channels, 1 for root horizontal, 2 for other positions,
        3 for the heading rate."""
        rot = np.array([c in ROTATION_CHANNELS for ch in self.skeleton.channels for c in ch])
        kinds = np.where(rot, 0, 2)
        kinds[self.horizontal_columns()] = 1
        if self.root_mode == "heading":
            kinds = np.append(kinds, 3)
        return kinds

    def _rotation_mask(self) -> np.ndarray:
        return (self._kinds() == 0)[:self.skeleton.n_channels]

    def _mover_rotation(self, skeleton: Skeleton):
        return _mover_rotation(skeleton, self.mover)

    # ------------------------------------------------------------- transforms
    def _transform(self, motion: Motion, partner: Motion | None):
        v, anchor = self._untangled(motion, partner)
        return self._on_branch(v), anchor

    def _on_branch(self, v: np.ndarray) -> np.ndarray:
        """Shift each rotation column of one clip by whole turns towards ``branch``."""
        if self.branch is not None:
            rot = np.isfinite(self.branch)
            turns = np.round((v[:, rot].mean(0) - self.branch[rot]) / 360.0)
            v[:, rot] -= 360.0 * turns
        return v

    def _untangled(self, motion: Motion, partner: Motion | None):
        v = _unwrap(motion.values, self._rotation_mask())
        h = self.horizontal_columns()
        if self.root_mode == "heading":
            return self._to_heading(v, h, motion.fps)
        if self.root_mode == "velocity" and h.size:
            anchor = v[0, h].copy()
            vel = np.diff(v[:, h], axis=0, prepend=v[:1, h]) * motion.fps
            if motion.n_frames > 1:
                vel[0] = vel[1]  # no artificial stop at frame 0; decoding ignores vel[0]
            v[:, h] = vel
        elif self.root_mode == "partner" and h.size:
            if partner is None:
                raise BayesmotionError("root_mode='partner' needs the partner's motion")
            anchor = _midpoint(motion, partner, h)
            v[:, h] -= anchor
        else:
            anchor = np.zeros(0)
        return v, anchor

    def _to_heading(self, v, h, fps):
        """Channels (T, C) -> (T, C + 1): mover rotation without heading, body-frame horizontal
        velocity, heading rate (deg/s) appended; anchor (x0, z0, psi0)."""
        if h.size != 2:
            raise BayesmotionError("root_mode='heading' needs both horizontal position "
                                   "channels on the moving joint")
        cols, order = self._mover_rotation(self.skeleton)
        R = euler_matrices(order, v[:, cols])
        # measured from the axis's rest direction, so that the rotation left after removing the
        # heading stays near the rest pose (from +X instead, a local Z axis would leave a fixed
        # quarter turn: gimbal lock for Bandai's Hips, 180 deg jumps per frame)
        rest = _horizontal_angle(np.eye(3)[self.heading_axis][None])[0]
        psi = _horizontal_angle(R[:, :, self.heading_axis]) - rest
        un_yaw = _yaw(-psi)
        v[:, cols] = _matrices_to_euler(order, un_yaw @ R)
        vel = np.diff(v[:, h], axis=0, prepend=v[:1, h]) * fps
        rate = np.rad2deg(np.diff(psi, prepend=psi[:1])) * fps
        if v.shape[0] > 1:
            vel[0], rate[0] = vel[1], rate[1]  # decoding ignores frame 0
        anchor = np.array([*v[0, h], psi[0]])
        v[:, h] = _rotate_horizontal(un_yaw, vel)
        return np.concatenate([v, rate[:, None]], axis=1), anchor

    def _from_heading(self, v, anchor, sk, fps):
        """Inverse of :meth:`_to_heading` on (T, C + 1) -> (T, C)."""
        h = self.horizontal_columns(sk)
        cols, order = self._mover_rotation(sk)
        a = np.zeros(3) if anchor is None or np.size(anchor) == 0 else np.asarray(anchor)
        psi = a[2] + np.concatenate([[0.0], np.cumsum(np.deg2rad(v[1:, -1]) / fps)])
        yaw = _yaw(psi)
        v = v[:, :-1]
        v[:, cols] = _matrices_to_euler(order, yaw @ euler_matrices(order, v[:, cols]))
        vel = _rotate_horizontal(yaw, v[:, h])
        v[:, h] = np.concatenate([a[None, :2], a[:2] + np.cumsum(vel[1:] / fps, 0)])
        return v

    def encode(self, motion: Motion, partner: Motion | None = None) -> Encoded:
        """Motion -> (Y (T, D), anchor)."""
        check_layout(self.skeleton, motion.skeleton)
        v, anchor = self._transform(motion, partner)
        return Encoded((v[:, self.keep] - self.mean) / self.scale, anchor)

    def decode(self, Y, anchor=None, skeleton: Skeleton | None = None, fps: float | None = None,
               name: str = "") -> Motion:
        """(T, D) -> Motion.

        Args:
            Y: (T, D) model-space poses.
            anchor: from :meth:`encode`; ``None`` places a "velocity" or "heading" root at the
                origin (heading 0) and a "partner" root around a fixed midpoint of zero.
            skeleton: skeleton whose offsets to use (defaults to the codec's).
            fps: frame rate of the result (also converts velocities back to positions);
                default: the rate the codec was fitted at, so ``decode(*encode(m))`` is ``m``
                for a motion at that rate.
        """
        if fps is None:
            if self.fps is None:
                raise BayesmotionError("this codec does not know its frame rate (saved before "
                                       "it was stored): pass fps= to decode")
            fps = self.fps
        if not np.isfinite(fps) or fps <= 0:
            raise BayesmotionError(f"fps must be positive, got {fps}")
        Y = np.asarray(Y, dtype=np.float64)
        if Y.ndim != 2 or Y.shape[1] != self.dim:
            raise BayesmotionError(f"decode expects Y of shape (T, {self.dim}), got {Y.shape}")
        sk = self.skeleton if skeleton is None else skeleton
        check_layout(self.skeleton, sk)
        v = np.tile(self.constant, (Y.shape[0], 1))
        v[:, self.keep] = Y * self.scale + self.mean
        h = self.horizontal_columns(sk)
        if self.root_mode == "heading":
            v = self._from_heading(v, anchor, sk, fps)
        elif self.root_mode == "velocity" and h.size:
            start = np.zeros(h.size) if anchor is None or np.size(anchor) == 0 else anchor
            steps = v[1:, h] / fps
            v[:, h] = np.concatenate([np.asarray(start)[None], start + np.cumsum(steps, 0)])
        elif self.root_mode == "partner" and h.size:
            mid = np.zeros((Y.shape[0], h.size)) if anchor is None else np.asarray(anchor)
            v[:, h] += np.broadcast_to(mid, (Y.shape[0], h.size))
        return Motion(sk, v, fps, name)

    # ---------------------------------------------------------- serialisation
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out = {f"{prefix}keep": self.keep, f"{prefix}constant": self.constant,
               f"{prefix}mean": self.mean, f"{prefix}scale": self.scale}
        if self.branch is not None:
            out[f"{prefix}branch"] = self.branch
        return out

    def to_meta(self) -> dict:
        return {"root_mode": self.root_mode, "scaling": self.scaling, "mover": self.mover,
                "heading_axis": self.heading_axis, "skeleton": self.skeleton.to_dict(),
                "fps": self.fps}

    @classmethod
    def from_saved(cls, meta: dict, arrays, prefix: str) -> PoseCodec:
        return cls(Skeleton.from_dict(meta["skeleton"]), meta["root_mode"],
                   np.asarray(arrays[f"{prefix}keep"], dtype=int),
                   np.asarray(arrays[f"{prefix}constant"]), np.asarray(arrays[f"{prefix}mean"]),
                   np.asarray(arrays[f"{prefix}scale"]), meta.get("scaling", "type"),
                   int(meta.get("mover", 0)), int(meta.get("heading_axis", -1)),
                   np.asarray(arrays[f"{prefix}branch"]) if f"{prefix}branch" in arrays
                   else None, None if meta.get("fps") is None else float(meta["fps"]))


def _rotate_horizontal(R: np.ndarray, hv: np.ndarray) -> np.ndarray:
    """Apply rotations about the up axis (T, 3, 3) to horizontal vectors (T, 2)."""
    full = np.zeros((hv.shape[0], 3))
    full[:, [a for a in range(3) if a != UP_AXIS]] = hv
    out = np.einsum("tij,tj->ti", R, full)
    return out[:, [a for a in range(3) if a != UP_AXIS]]


def _mover_rotation(skeleton: Skeleton, mover: int):
    """Rotation channel columns and Euler order of the moving joint ("heading" needs three)."""
    idx, orders = skeleton.rotation_layout()
    if len(orders[mover]) != 3:
        raise BayesmotionError(f"root_mode='heading' needs three rotation channels on "
                               f"{skeleton.names[mover]!r}, it has {orders[mover]!r}")
    return idx[mover], orders[mover]


def _heading_axis(motions, mover: int) -> int:
    """The mover's local axis that stays closest to horizontal over the training motions."""
    cols, order = _mover_rotation(motions[0].skeleton, mover)
    R = np.concatenate([euler_matrices(order, m.values[:, cols]) for m in motions])
    return int(np.argmin(np.mean(np.abs(R[:, UP_AXIS, :]), axis=0)))


def check_layout(expected: Skeleton, got: Skeleton) -> None:
    """Raise SkeletonMismatchError naming missing/extra joints unless the layouts agree."""
    if expected.same_layout(got):
        return
    missing = [n for n in expected.names if n not in got.names]
    extra = [n for n in got.names if n not in expected.names]
    if missing or extra:
        raise SkeletonMismatchError(
            f"skeleton does not match the model: missing joints {missing}, unexpected {extra}")
    raise SkeletonMismatchError("skeleton has the model's joints but a different tree or "
                                "channel layout (parents, channel order or Euler orders "
                                "differ); bayesmotion does not retarget: export the clip with "
                                "the model's skeleton layout")
