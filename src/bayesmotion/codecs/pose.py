"""The pose representation Y that the GP model sees, and its exact inverse.

One concept: the joint-angle codec (:class:`PoseCodec`, with its fitted rig steps and the
private helpers only it uses), kept in one module although it is longer than the others.

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
* **Joint frames and walking side** (optional, both label-free and stored with the codec, so a
  new clip goes through the same steps): ``rest_frames=True`` turns each joint's frame to its
  mean rotation over the training motions (:func:`bayesmotion.data.mirror.rest_frames`), which
  takes joints such as Bandai's spine out of gimbal lock; ``canonical_side=True`` mirrors every
  motion that moves to the actor's right (:func:`bayesmotion.data.mirror.canonical_side`), so
  walks to either side share one representation. :meth:`PoseCodec.decode` turns the frames back
  (the result is on the original rig) and mirrors back when told the clip was mirrored
  (``Encoded.mirrored``); generated motion is on the canonical side.
* **Constant channels** (range below ``1e-9`` over all training frames) are dropped and restored.
* **Normalisation**: every kept channel is centred on its own mean and divided by a per-channel
  scale stored with the codec. By default (``scaling="type"``) the scale is the pooled standard
  deviation of the channel's kind (rotations, root translation, other positions), so joint
  angles keep their physical weighting. The other positions' pool leaves out channels whose
  standard deviation is below 1% of the kind's largest: exporters such as Bandai's write every
  bone offset as a position channel, constant but for rounding (57 such channels, standard
  deviations of 1e-5 to 0.02 cm), and pooled with them the hips' height (2.2 cm) was scaled up
  to 7.5 standard units, half the weight of all 62 joint angles together.
  ``scaling="channel"`` standardises each channel alone, which inflates near-constant channels
  (fingers, toes) to the weight of the hips.

``decode(encode(m))`` reproduces the joint positions of ``m`` to float64 precision (tested to
< 1e-6 of the skeleton's size on the real data).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import ClassVar, Literal, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from bayesmotion.data import mirror as mr
from bayesmotion.data.bvh import FRAME_TIME_RANGE
from bayesmotion.data.fk import (
    circular_mean_deg,
    euler_matrices,
    np_axis_rotation,
    numpy_positions,
    other_euler_solution,
)
from bayesmotion.data.mirror import (
    MirrorPlan,
    lateral_ratio,
    mirror,
    mirrored_skeleton,
    reframe,
    reframed_skeleton,
    world_and_local,
)
from bayesmotion.data.motion import Motion, find_mover
from bayesmotion.data.skeleton import ROTATION_CHANNELS, UP_AXIS, Skeleton, horizontal_columns
from bayesmotion.errors import BayesmotionError, SkeletonMismatchError

RootMode = Literal["heading", "velocity", "partner", "absolute"]
ROOT_MODES = ("heading", "velocity", "partner", "absolute")


class Encoded(NamedTuple):
    """One actor's motion in model space.

    Attributes:
        Y: (T, D) normalised pose features.
        anchor: what decoding needs besides Y: (2,) first horizontal root position
            ("velocity"), (3,) first horizontal position and heading in radians ("heading"),
            (T, 2) partner midpoint ("partner"), or (0,) ("absolute"); in the mirrored world
            when ``mirrored``.
        mirrored: the codec mirrored the motion to its canonical side before encoding it.
    """

    Y: np.ndarray
    anchor: np.ndarray
    mirrored: bool = False


def _matrices_to_euler(order: str, R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`bayesmotion.data.fk.euler_matrices` (intrinsic Tait-Bryan), unwrapped
    in time."""
    e = Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)
    return np.unwrap(e, period=360.0, axis=0)


def _yaw(angle: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations about the up axis by ``angle`` radians."""
    return np_axis_rotation("XYZ"[UP_AXIS], angle)


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
        frames: (J, 3, 3) per-joint rest frames applied before encoding
            (:func:`bayesmotion.data.mirror.reframe`), or None.
        side: the :class:`bayesmotion.data.mirror.MirrorPlan` that mirrors motions moving to
            the actor's right before encoding, or None (no canonical side).
        side_threshold: a motion is mirrored when its lateral ratio is below minus this.
        fold_root: the translation of the mover's ancestors is moved into the mover's own
            position channels before encoding (:func:`fold_ancestor_translation`); False in
            files written before it existed.
        angle_reference: (C,) circular mean of every channel over the training motions on
            their own rig (after the canonical side, before the rest frames): decoding turns
            the frames back onto the Euler branch and turn nearest it (with ``frames`` only).
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
    frames: np.ndarray | None = None
    side: object | None = None
    side_threshold: float = 0.15
    fold_root: bool = False
    angle_reference: np.ndarray | None = None
    decodes: ClassVar[bool] = True
    pose_space: ClassVar[str] = "angles"

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
        return horizontal_columns(skeleton or self.skeleton, self.mover)

    # ---------------------------------------------------------------- fitting
    @classmethod
    def fit(cls, motions, partners=None, root_mode: RootMode = "velocity",
            scaling: str = "type", rest_frames: bool = False, canonical_side: bool = False,
            side_threshold: float = 0.15) -> PoseCodec:
        """Fit drops, means and scales on training motions (one actor slot).

        Args:
            motions: motions of this actor slot, all with the same channel layout.
            partners: the partner's motion for each (``root_mode="partner"`` only).
            root_mode: see the module docstring.
            scaling: "type" (pooled per channel kind) or "channel".
            rest_frames: turn each joint's frame to its mean rotation over ``motions`` (after
                the canonical side) before encoding (the mover and its ancestors keep theirs).
            canonical_side: mirror every motion that moves to the actor's right (lateral ratio
                below ``-side_threshold``) before encoding, with one plan fitted on ``motions``;
                needs left-right joint names, and not ``root_mode="partner"`` (mirroring one
                actor of a pair would break the interaction).
            side_threshold: see ``canonical_side``.
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
        motions = [fold_ancestor_translation(m, mover) for m in motions]

        side, frames = None, None
        if canonical_side:
            if root_mode == "partner":
                raise BayesmotionError("canonical_side mirrors one actor alone; it cannot be "
                                       "used with root_mode='partner' (two-actor trials)")
            if not (np.isfinite(side_threshold) and side_threshold >= 0):
                raise BayesmotionError(f"side_threshold must be >= 0, got {side_threshold!r}")
            try:
                side = mr.mirror_plan(sk, motions)
            except BayesmotionError as e:
                raise BayesmotionError(f"canonical_side needs left-right joint pairs read from "
                                       f"the joint names: {e}. Rename the joints, or mirror the "
                                       f"clips yourself with bayesmotion.mirror(motion, "
                                       f"mirror_plan(skeleton, pairs=...))") from None
            motions, _ = mr.canonical_side(motions, side_threshold, side)
        reference = None
        if rest_frames:
            frames = mr.rest_frames(motions)
            reference = circular_mean_deg(np.concatenate([m.values for m in motions]))
            motions = [mr.reframe(m, frames) for m in motions]
        axis = -1
        if root_mode == "heading":
            axis = _heading_axis(motions, mover)
        width = sk.n_channels + (root_mode == "heading")
        proto = cls(sk, root_mode, np.arange(width), np.zeros(width), np.zeros(width),
                    np.ones(width), scaling, mover, axis)
        parts = [proto._untangled(m, None if partners is None else partners[i])[0]
                 for i, m in enumerate(motions)]
        rot = proto._kinds() == 0
        branch = np.full(width, np.nan)
        branch[rot] = circular_mean_deg(np.concatenate(parts)[:, rot])
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
                pool = sel
                if k == 2:  # bone offsets written as channels: constant but for rounding
                    pool = sel & (std >= 0.01 * std[sel].max())
                scale[sel] = np.sqrt(np.mean(std[pool] ** 2)) or 1.0
        return cls(sk, root_mode, keep, raw[0].copy(), mean, scale, scaling, mover, axis, branch,
                   float(motions[0].fps), frames, side, float(side_threshold), True, reference)

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

    def prepare(self, motion: Motion) -> tuple[Motion, bool]:
        """The motion on the codec's canonical side and in its joint frames (what the channel
        transforms see), and whether it was mirrored."""
        mirrored = False
        if self.fold_root:
            motion = fold_ancestor_translation(motion, self.mover)
        if self.side is not None and motion.n_frames >= 2:
            if lateral_ratio(motion, self.side) < -self.side_threshold:
                motion, mirrored = mirror(motion, self.side), True
        if self.frames is not None:
            motion = reframe(motion, self.frames)
        return motion, mirrored

    def encode(self, motion: Motion, partner: Motion | None = None) -> Encoded:
        """Motion -> (Y (T, D), anchor, mirrored)."""
        check_layout(self.skeleton, motion.skeleton)
        motion, mirrored = self.prepare(motion)
        v, anchor = self._transform(motion, partner)
        return Encoded((v[:, self.keep] - self.mean) / self.scale, anchor, mirrored)

    def decode(self, Y, anchor=None, skeleton: Skeleton | None = None, fps: float | None = None,
               name: str = "", mirrored: bool = False) -> Motion:
        """(T, D) -> Motion.

        Args:
            Y: (T, D) model-space poses.
            anchor: from :meth:`encode`; ``None`` places a "velocity" or "heading" root at the
                origin (heading 0) and a "partner" root around a fixed midpoint of zero.
            skeleton: skeleton whose offsets to use (defaults to the codec's).
            fps: frame rate of the result (also converts velocities back to positions);
                default: the rate the codec was fitted at, so with ``e = encode(m)``,
                ``decode(e.Y, e.anchor, mirrored=e.mirrored)`` is ``m`` for a motion at that
                rate (to float precision in its joint positions when the codec has rest frames
                or a canonical side; the angles then come back on the Euler branch nearest the
                training clips').
            mirrored: mirror the result back (``Encoded.mirrored``); needs a canonical side.
        """
        sk = self.skeleton if skeleton is None else skeleton
        if not isinstance(sk, Skeleton):
            raise BayesmotionError(f"skeleton must be a Skeleton or None, got "
                                   f"{type(sk).__name__} (pass mirrored= by name)")
        check_layout(self.skeleton, sk)
        return self.from_rig(self.decode_rig(Y, anchor, sk, fps, name, mirrored), sk, mirrored)

    def rig_skeleton(self, skeleton: Skeleton | None = None, mirrored: bool = False) -> Skeleton:
        """The skeleton of ``skeleton``'s motions as the channel transforms see them (mirrored,
        then in the rest frames)."""
        sk = self.skeleton if skeleton is None else skeleton
        if mirrored:
            self._check_side()
            sk = mirrored_skeleton(sk, self.side)
        return sk if self.frames is None else reframed_skeleton(sk, self.frames)

    def from_rig(self, motion: Motion, skeleton: Skeleton | None = None,
                 mirrored: bool = False) -> Motion:
        """A motion of :meth:`decode_rig` back on ``skeleton``'s rig: the rest frames turned
        back, and mirrored back when ``mirrored``. Joint positions are unchanged."""
        sk = self.skeleton if skeleton is None else skeleton
        if self.frames is not None:
            motion = reframe(motion, np.swapaxes(self.frames, -1, -2), self.angle_reference)
            motion = motion.replace(skeleton=sk if not mirrored else motion.skeleton)
        if mirrored:
            self._check_side()
            motion = mirror(motion, self.side).replace(name=motion.name)
        return motion

    def _check_side(self) -> None:
        if self.side is None:
            raise BayesmotionError("mirrored=True needs a codec with a canonical side "
                                   "(PoseCodec.fit(..., canonical_side=True))")

    def channel_variance(self, motion: Motion, var: np.ndarray) -> np.ndarray:
        """Channel variances (T, C) of a :meth:`decode_rig` motion, carried to the original rig
        (:meth:`from_rig`, not mirrored) to first order: the rotation channels of a joint whose
        frame turned get ``sum_i J_ki^2 var_i`` with ``J`` the Jacobian of its original Euler
        angles in its rig angles, its position channels ``sum_i B_p[k, i]^2 var_i`` (the
        translation turns with its parent's frame ``B_p``; cross-covariances dropped, and a
        missing position channel counts as variance 0). Other channels are unchanged."""
        var = np.array(var, dtype=np.float64)
        if self.frames is None:
            return var
        sk = motion.skeleton
        rot_idx, orders = sk.rotation_layout()
        pos_idx = sk.position_layout()
        eye = np.eye(3)
        out = var.copy()
        for j, p in enumerate(sk.parents):
            Bp = eye if p < 0 else self.frames[p]
            if np.allclose(Bp, eye) and np.allclose(self.frames[j], eye):
                continue
            if len(orders[j]) == 3:
                cols = rot_idx[j, :3]
                J = _euler_jacobian(orders[j], motion.values[:, cols], Bp, self.frames[j])
                out[:, cols] = np.einsum("tki,ti->tk", J ** 2, var[:, cols])
            has = pos_idx[j] >= 0
            if has.any() and not np.allclose(Bp, eye):  # translations turn with the parent
                full = np.zeros((var.shape[0], 3))
                full[:, has] = var[:, pos_idx[j][has]]
                out[:, pos_idx[j][has]] = (full @ (Bp ** 2).T)[:, has]
        return out

    def decode_rig(self, Y, anchor=None, skeleton: Skeleton | None = None,
                   fps: float | None = None, name: str = "", mirrored: bool = False) -> Motion:
        """(T, D) -> Motion in the codec's frames and side, on :meth:`rig_skeleton`: what
        :meth:`decode` returns before :meth:`from_rig` (the same motion when the codec has
        neither rest frames nor a canonical side)."""
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
        sk = self.rig_skeleton(sk, mirrored)
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
        if self.frames is not None:
            out[f"{prefix}frames"] = self.frames
            if self.angle_reference is not None:
                out[f"{prefix}angle_reference"] = self.angle_reference
        if self.side is not None:
            out.update({f"{prefix}side_{k}": np.asarray(v)
                        for k, v in self.side._asdict().items()})
        return out

    def to_meta(self) -> dict:
        return {"pose_space": self.pose_space, "root_mode": self.root_mode,
                "scaling": self.scaling, "mover": self.mover,
                "heading_axis": self.heading_axis, "skeleton": self.skeleton.to_dict(),
                "fps": self.fps, "side_threshold": self.side_threshold,
                "fold_root": self.fold_root}

    @classmethod
    def from_saved(cls, meta: dict, arrays, prefix: str) -> PoseCodec:
        """The codec written by :meth:`to_arrays`/:meth:`to_meta`. Raises ValueError when the
        metadata or an array does not fit the format (types, shapes, ranges), or the rest
        frames or the mirror plan do not fit the skeleton."""
        codec = cls._from_saved(_saved_meta(meta, prefix), arrays, prefix)
        codec._check_saved(prefix)
        codec._check_rig(prefix)
        return codec

    def _check_saved(self, prefix: str) -> None:
        """Shapes, index ranges and scales of the channel arrays (ValueError naming them)."""
        def bad(msg):
            raise ValueError(f"{prefix.rstrip('/')}: {msg}")

        sk, C = self.skeleton, self.skeleton.n_channels
        width = C + (self.root_mode == "heading")
        if not 0 <= self.mover < sk.n_joints:
            bad(f"mover {self.mover} is not a joint index (0-{sk.n_joints - 1})")
        h = self.horizontal_columns()
        if self.root_mode == "heading" and (h.size != 2 or self.heading_axis not in (0, 1, 2)):
            bad("root_mode 'heading' needs both horizontal position channels on the mover and "
                f"a heading axis 0-2; got {h.size} channel(s) and axis {self.heading_axis}")
        keep, D = self.keep, self.keep.size
        if keep.ndim != 1 or np.unique(keep).size != D or (D and not 0 <= keep.min() <= keep.max()
                                                           < width):
            bad(f"kept columns must be distinct indices into the {width} columns")
        for name, v, shape in (("constant", self.constant, (width,)), ("mean", self.mean, (D,)),
                               ("scale", self.scale, (D,))):
            if v.shape != shape or v.dtype != np.float64:
                bad(f"{name} must be a float array of shape {shape}, got {v.dtype} {v.shape}")
        if D and not np.all(self.scale >= 1.0 / _MAX_SCALE):
            bad(f"scales must be at least {1.0 / _MAX_SCALE:g} (their reciprocal squared "
                "stays finite)")
        if self.branch is not None and (self.branch.shape != (width,)
                                        or self.branch.dtype != np.float64):
            bad(f"branch must be a float array of shape ({width},), got {self.branch.shape}")
        lo, hi = FRAME_TIME_RANGE
        if self.fps is not None and not 1 / hi <= self.fps <= 1 / lo:
            bad(f"fps {self.fps!r} is outside {1 / hi:g} to {1 / lo:g}")
        if self.heading_axis not in (-1, 0, 1, 2):
            bad(f"heading axis must be -1 (none) or 0-2, got {self.heading_axis}")

    def _check_rig(self, prefix: str) -> None:
        J, C = self.skeleton.n_joints, self.skeleton.n_channels

        def bad(msg):  # bayesmotion.model.io.load names the file and raises ModelFileError
            raise ValueError(f"{prefix.rstrip('/')}: {msg}")

        if self.frames is not None:
            F = self.frames
            if F.shape != (J, 3, 3) or not np.all(np.isfinite(F)):
                bad(f"rest frames must be finite ({J}, 3, 3), got {F.shape}")
            if not (np.allclose(F @ np.swapaxes(F, -1, -2), np.eye(3), atol=1e-9)
                    and np.allclose(np.linalg.det(F), 1.0, atol=1e-9)):
                bad("rest frames are not rotations")
            ref = self.angle_reference
            if ref is not None and (ref.shape != (C,) or not np.all(np.isfinite(ref))):
                bad(f"angle reference must be finite ({C},), got {ref.shape}")
        if self.side is not None:
            perm, M, A, left = self.side
            shapes = {"perm": (perm.shape, (J,)), "reflection": (M.shape, (3, 3)),
                      "frames": (A.shape, (J, 3, 3)), "left": (left.shape, (J,))}
            for name, (got, want) in shapes.items():
                if got != want:
                    bad(f"mirror plan {name} must have shape {want}, got {got}")
            if perm.dtype.kind not in "iu" or left.dtype != bool:
                bad("mirror plan partners must be integers and its sides booleans")
            if sorted(perm.tolist()) != list(range(J)) or not np.all(perm[perm] == np.arange(J)):
                bad("mirror plan partners are not a pairing of the joints")
            if not (np.all(np.isfinite(M)) and np.all(np.isfinite(A))):
                bad("mirror plan has non-finite values")
            if not (np.allclose(M @ M.T, np.eye(3), atol=1e-9)
                    and np.isclose(np.linalg.det(M), -1.0, atol=1e-9)):
                bad("mirror plan reflection is not a reflection")
            if not (np.allclose(A @ np.swapaxes(A, -1, -2), np.eye(3), atol=1e-9)
                    and np.allclose(np.linalg.det(A), 1.0, atol=1e-9)):
                bad("mirror plan frames are not rotations")

    @classmethod
    def _from_saved(cls, meta: dict, arrays, prefix: str) -> PoseCodec:
        side = None
        if f"{prefix}side_perm" in arrays:
            side = MirrorPlan(np.asarray(arrays[f"{prefix}side_perm"]),
                              np.asarray(arrays[f"{prefix}side_reflection"], dtype=float),
                              np.asarray(arrays[f"{prefix}side_frames"], dtype=float),
                              np.asarray(arrays[f"{prefix}side_left"]))
        return cls(Skeleton.from_dict(meta["skeleton"]), meta["root_mode"],
                   _integers(arrays[f"{prefix}keep"], f"{prefix}keep"),
                   np.asarray(arrays[f"{prefix}constant"]), np.asarray(arrays[f"{prefix}mean"]),
                   np.asarray(arrays[f"{prefix}scale"]), meta.get("scaling", "type"),
                   int(meta.get("mover", 0)), int(meta.get("heading_axis", -1)),
                   np.asarray(arrays[f"{prefix}branch"]) if f"{prefix}branch" in arrays
                   else None, None if meta.get("fps") is None else float(meta["fps"]),
                   np.asarray(arrays[f"{prefix}frames"], dtype=float)
                   if f"{prefix}frames" in arrays else None, side,
                   float(meta.get("side_threshold", 0.15)), bool(meta.get("fold_root", False)),
                   np.asarray(arrays[f"{prefix}angle_reference"], dtype=float)
                   if f"{prefix}angle_reference" in arrays else None)


_MAX_SCALE = 1e150  # a saved scale and its reciprocal stay below this: their squares are finite
_SAVED_META = {"root_mode": str, "scaling": str, "mover": int, "heading_axis": int,
               "fps": (int, float, type(None)), "side_threshold": (int, float), "fold_root": bool,
               "skeleton": dict, "pose_space": str}


def _saved_meta(meta: dict, prefix: str) -> dict:
    """A codec's saved metadata with its types and choices checked (ValueError otherwise)."""
    where = prefix.rstrip("/")
    if not isinstance(meta, dict):
        raise ValueError(f"{where}: codec metadata must be a mapping, got {type(meta).__name__}")
    for key, types in _SAVED_META.items():
        v = meta.get(key)
        if key in meta and (not isinstance(v, types) or (isinstance(v, bool)
                                                         and types is not bool)):
            raise ValueError(f"{where}: codec {key} has type {type(v).__name__}")
    if meta.get("root_mode") not in ROOT_MODES:
        raise ValueError(f"{where}: root_mode must be one of {'/'.join(ROOT_MODES)}, got "
                         f"{meta.get('root_mode')!r}")
    if meta.get("scaling", "type") not in ("type", "channel"):
        raise ValueError(f"{where}: scaling must be 'type' or 'channel', got "
                         f"{meta.get('scaling')!r}")
    if not np.isfinite(meta.get("side_threshold", 0.15)):
        raise ValueError(f"{where}: side_threshold must be finite")
    return meta


def _integers(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind not in "iu":
        raise ValueError(f"{name.rstrip('/')}: must hold integers, got {a.dtype}")
    return a


def fold_ancestor_translation(motion: Motion, mover: int) -> Motion:
    """``motion`` with the position channels of ``mover``'s ancestors at zero and their
    translation carried by ``mover``'s own position channels instead: ``mover`` and every joint
    below it keep their world positions (to float precision), its ancestors rest at the origin.
    The motion itself comes back when those channels are already zero or ``mover`` lacks one of
    its X/Y/Z position channels.

    Bandai's exporter keeps a ``joint_Root`` at the origin and translates ``Hips`` below it in
    every walk but one: in the short walk-back normal clip ``joint_Root`` carries the whole
    translation (120 cm in 31 frames). Left as it is, that clip's ``joint_Root:Zposition``
    channel is kept as a pose channel and, scaled with the other non-root positions (a few cm),
    reaches 125 standard deviations, dwarfing every other channel of every clip."""
    sk = motion.skeleton
    pos = sk.position_layout()
    cols, j = [], sk.parents[mover]
    while j >= 0:
        cols += [int(c) for c in pos[j] if c >= 0]
        j = sk.parents[j]
    v = motion.values
    if not cols or np.min(pos[mover]) < 0 or not np.any(v[:, cols]):
        return motion

    flat = v.copy()
    flat[:, cols] = 0.0
    parent = sk.parents[mover]
    delta = numpy_positions(sk, v)[:, parent] - numpy_positions(sk, flat)[:, parent]
    G = world_and_local(sk, flat)[0][:, parent]
    flat[:, pos[mover]] += np.einsum("tji,tj->ti", G, delta)
    return motion.replace(values=flat)


def _euler_jacobian(order: str, angles: np.ndarray, Bp: np.ndarray, Bj: np.ndarray,
                    step: float = 1e-4) -> np.ndarray:
    """(T, 3, 3) d a / d a' by central differences (degrees per degree), where ``a`` are the
    Euler angles of ``Bp L(a') Bj^T`` and ``L(a')`` the rotation of ``angles`` (T, 3); each
    perturbed rotation's angles are taken on the branch nearest the unperturbed ones."""

    def wrap(x):
        return (x + 180.0) % 360.0 - 180.0

    def euler(a):
        R = Bp @ euler_matrices(order, a) @ Bj.T
        return Rotation.from_matrix(R).as_euler(order.upper(), degrees=True)

    def near(e, base):
        d1, d2 = wrap(e - base), wrap(other_euler_solution(e, order) - base)
        pick = np.sum(d1 ** 2, 1) <= np.sum(d2 ** 2, 1)
        return np.where(pick[:, None], d1, d2)

    J = np.empty((angles.shape[0], 3, 3))
    with warnings.catch_warnings():  # at gimbal lock scipy warns; the rotation is still exact
        warnings.filterwarnings("ignore", "Gimbal lock", UserWarning)
        base = euler(angles)
        for i in range(3):
            d = np.zeros(3)
            d[i] = step
            J[:, :, i] = (near(euler(angles + d), base)
                          - near(euler(angles - d), base)) / (2 * step)
    return J


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
