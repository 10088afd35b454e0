"""The pose representation Y that the GP model sees, and its exact inverse.

``PoseCodec`` turns a :class:`Motion` into a matrix ``Y: (T, D)`` and back:

* **Rotations: unwrapped Euler angles.** The BVH channels are Euler angles; unwrapping them in
  time (``np.unwrap`` with period 360 deg) removes the 360 deg jumps while staying *exactly*
  invertible (BVH accepts any angle), keeps one number per channel (no 3 -> 4 or 3 -> 9 blow-up),
  and keeps the channel layout of Taubert et al., who model joint angles. The exponential map is
  smoother near gimbal lock, but converting back is not bit-exact and the real data here never
  comes near it (checked in tests: frame-to-frame steps stay small after unwrapping).
* **Root translation** (the root's horizontal position channels; the vertical one is kept):
  ``"velocity"`` -- per-second horizontal velocity, with the first position stored as an anchor
  (one-actor clips such as gaits, where absolute position carries no style);
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

from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

from ..errors import BayesmotionError, SkeletonMismatchError
from .motion import Motion
from .skeleton import ROTATION_CHANNELS, Skeleton

RootMode = Literal["velocity", "partner", "absolute"]
UP_AXIS = 1  # Y is up in BVH files from CMU and Bandai


class Encoded(NamedTuple):
    """One actor's motion in model space.

    Attributes:
        Y: (T, D) normalised pose features.
        anchor: what decoding needs besides Y: (2,) first horizontal root position
            ("velocity"), (T, 2) partner midpoint ("partner"), or (0,) ("absolute").
    """

    Y: np.ndarray
    anchor: np.ndarray


def _root_horizontal_columns(skeleton: Skeleton) -> np.ndarray:
    cols = skeleton.root_position_columns
    return np.array([cols[a] for a in range(3) if a != UP_AXIS and cols[a] >= 0], dtype=int)


def _unwrap(values: np.ndarray, rot: np.ndarray) -> np.ndarray:
    v = np.array(values, dtype=np.float64)
    v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
    return v


def _midpoint(motion: Motion, partner: Motion) -> np.ndarray:
    h = _root_horizontal_columns(motion.skeleton)
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
        constant: (C,) values restored for dropped channels.
        mean: (D,) per-channel mean of the kept channels.
        scale: (D,) per-channel scale of the kept channels.
        scaling: "type" or "channel" (how ``scale`` was chosen).
    """

    skeleton: Skeleton
    root_mode: str
    keep: np.ndarray
    constant: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    scaling: str = "type"

    @property
    def dim(self) -> int:
        return int(self.keep.size)

    @property
    def channel_names(self) -> tuple[str, ...]:
        names = self.skeleton.channel_names
        return tuple(names[c] for c in self.keep)

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
        if root_mode not in ("velocity", "partner", "absolute"):
            raise BayesmotionError(
                f"root_mode must be velocity/partner/absolute, got {root_mode!r}")
        if root_mode == "partner" and (partners is None or len(partners) != len(motions)):
            raise BayesmotionError("root_mode='partner' needs one partner motion per motion")
        if scaling not in ("type", "channel"):
            raise BayesmotionError(f"scaling must be 'type' or 'channel', got {scaling!r}")
        sk = motions[0].skeleton
        for m in motions[1:]:
            check_layout(sk, m.skeleton)
        proto = cls(sk, root_mode, np.arange(sk.n_channels), np.zeros(sk.n_channels),
                    np.zeros(sk.n_channels), np.ones(sk.n_channels), scaling)
        raw = np.concatenate([proto._transform(m, None if partners is None else partners[i])[0]
                              for i, m in enumerate(motions)])
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
        return cls(sk, root_mode, keep, raw[0].copy(), mean, scale, scaling)

    def _kinds(self) -> np.ndarray:
        """(C,) 0 for rotation channels, 1 for root horizontal, 2 for other positions."""
        rot = np.array([c in ROTATION_CHANNELS for ch in self.skeleton.channels for c in ch])
        kinds = np.where(rot, 0, 2)
        kinds[_root_horizontal_columns(self.skeleton)] = 1
        return kinds

    def _rotation_mask(self) -> np.ndarray:
        return self._kinds() == 0

    # ------------------------------------------------------------- transforms
    def _transform(self, motion: Motion, partner: Motion | None):
        v = _unwrap(motion.values, self._rotation_mask())
        h = _root_horizontal_columns(self.skeleton)
        if self.root_mode == "velocity" and h.size:
            anchor = v[0, h].copy()
            vel = np.diff(v[:, h], axis=0, prepend=v[:1, h]) * motion.fps
            if motion.n_frames > 1:
                vel[0] = vel[1]  # no artificial stop at frame 0; decoding ignores vel[0]
            v[:, h] = vel
        elif self.root_mode == "partner" and h.size:
            if partner is None:
                raise BayesmotionError("root_mode='partner' needs the partner's motion")
            anchor = _midpoint(motion, partner)
            v[:, h] -= anchor
        else:
            anchor = np.zeros(0)
        return v, anchor

    def encode(self, motion: Motion, partner: Motion | None = None) -> Encoded:
        """Motion -> (Y (T, D), anchor)."""
        check_layout(self.skeleton, motion.skeleton)
        v, anchor = self._transform(motion, partner)
        return Encoded((v[:, self.keep] - self.mean) / self.scale, anchor)

    def decode(self, Y, anchor=None, skeleton: Skeleton | None = None, fps: float = 30.0,
               name: str = "") -> Motion:
        """(T, D) -> Motion.

        Args:
            Y: (T, D) model-space poses.
            anchor: from :meth:`encode`; ``None`` places a "velocity" root at the training
                origin and a "partner" root around a fixed midpoint of zero.
            skeleton: skeleton whose offsets to use (defaults to the codec's).
            fps: frame rate of the result (also converts velocities back to positions).
        """
        Y = np.asarray(Y, dtype=np.float64)
        if Y.ndim != 2 or Y.shape[1] != self.dim:
            raise BayesmotionError(f"decode expects Y of shape (T, {self.dim}), got {Y.shape}")
        sk = self.skeleton if skeleton is None else skeleton
        check_layout(self.skeleton, sk)
        v = np.tile(self.constant, (Y.shape[0], 1))
        v[:, self.keep] = Y * self.scale + self.mean
        h = _root_horizontal_columns(sk)
        if self.root_mode == "velocity" and h.size:
            start = np.zeros(h.size) if anchor is None or np.size(anchor) == 0 else anchor
            steps = v[1:, h] / fps
            v[:, h] = np.concatenate([np.asarray(start)[None], start + np.cumsum(steps, 0)])
        elif self.root_mode == "partner" and h.size:
            mid = np.zeros((Y.shape[0], h.size)) if anchor is None else np.asarray(anchor)
            v[:, h] += np.broadcast_to(mid, (Y.shape[0], h.size))
        return Motion(sk, v, fps, name)

    # ---------------------------------------------------------- serialisation
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {f"{prefix}keep": self.keep, f"{prefix}constant": self.constant,
                f"{prefix}mean": self.mean, f"{prefix}scale": self.scale}

    def to_meta(self) -> dict:
        return {"root_mode": self.root_mode, "scaling": self.scaling,
                "skeleton": self.skeleton.to_dict()}

    @classmethod
    def from_saved(cls, meta: dict, arrays, prefix: str) -> PoseCodec:
        return cls(Skeleton.from_dict(meta["skeleton"]), meta["root_mode"],
                   np.asarray(arrays[f"{prefix}keep"], dtype=int),
                   np.asarray(arrays[f"{prefix}constant"]), np.asarray(arrays[f"{prefix}mean"]),
                   np.asarray(arrays[f"{prefix}scale"]), meta.get("scaling", "type"))


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
                                "channel layout; retarget it with bayesmotion.data.retarget")
