"""Per-frame affective pose features as a model's pose space (``HGPDM(pose_space="affective")``).

A joint-angle codec (:class:`~bayesmotion.codecs.pose.PoseCodec`) makes the bottom
layer explain every joint angle, and between clips of one actor the joint angles change most
with what the actor does (walking ahead, back, sideways), not with the emotion. The 18 pose
features of Bhattacharya et al. (2021; :mod:`bayesmotion.features.pose`) are invariant to
translation, rotation and uniform scale of the body and describe posture: angles at the neck,
shoulders and root, and ratios of distances and triangle areas between hands, feet, head and
torso. With them as Y the same hierarchy (GP-LVM, style interaction layer, second-order GPDM)
models how the posture evolves, and an emotion inferred from a clip of an action the training
clips did not pair with that emotion does not have to get past the action's joint angles.

The price: the features do not determine a pose, so a model in this space cannot generate
motion (:meth:`AffectiveCodec.decode` raises). Generation needs a joint-angle model.

Before the features are read, a motion goes through the same label-free steps as in a
joint-angle codec (the mover's ancestors' translation folded into the mover; with a canonical
side, motions to the actor's right mirrored, which swaps the left- and right-hand features).
Rest frames change joint angles only, never joint positions, so they do not apply here.

With a pose reference (``HGPDM(pose_reference="content")``) each clip's features are taken
relative to the mean posture of the training clips that share its level of that label (its
content: walk, bow, ...), pooled over their emotions, and scaled by the within-level standard
deviation. What is left is how the posture departs from the action's typical posture, which is
where an emotion shows across actions. The reference is fitted without the emotion labels; a
clip is encoded against its own level's mean, so inference needs the clip's level (a Trial's
label, or ``infer_emotion(..., reference=...)``) and refuses a level the training clips lack.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from bayesmotion.codecs.pose import Encoded, PoseCodec, check_layout
from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError
from bayesmotion.features.pose import POSE_FEATURE_NAMES, affective_features

POSE_SPACES = ("angles", "affective")


@dataclass(frozen=True, eq=False)
class AffectiveCodec:
    """Fitted map from one actor slot's motions to standardised affective pose features.

    Attributes:
        base: the joint-angle codec whose :meth:`PoseCodec.prepare` (root folding, canonical
            side) every motion goes through first; its channel statistics are not used.
        mean: (18,) per-feature mean over the training frames.
        scale: (18,) per-feature standard deviation over the training frames (1 where a
            feature is constant, to rounding); with a pose reference, the standard deviation
            about each frame's reference mean.
        reference: None, or the label whose levels the features are taken relative to (e.g.
            ``"content"``).
        reference_levels: the levels of ``reference`` in the training clips, in order.
        reference_means: (L, 18) mean features of the training frames of each level (None
            without a reference).
    """

    base: PoseCodec
    mean: np.ndarray
    scale: np.ndarray
    reference: str | None = None
    reference_levels: tuple[str, ...] = ()
    reference_means: np.ndarray | None = None
    decodes: ClassVar[bool] = False
    pose_space: ClassVar[str] = "affective"

    @property
    def skeleton(self):
        return self.base.skeleton

    @property
    def root_mode(self) -> str:
        return self.base.root_mode

    @property
    def fps(self):
        return self.base.fps

    @property
    def side(self):
        return self.base.side

    @property
    def dim(self) -> int:
        return int(self.mean.size)

    @property
    def channel_names(self) -> tuple[str, ...]:
        return POSE_FEATURE_NAMES

    @classmethod
    def fit(cls, motions, partners=None, root_mode: str = "velocity",
            canonical_side: bool = False, side_threshold: float = 0.15,
            reference: str | None = None, reference_labels=None) -> AffectiveCodec:
        """Fit the preparation steps and the features' means and scales on training motions
        (one actor slot; arguments as :meth:`PoseCodec.fit`). With ``reference`` (a label
        name), ``reference_labels`` gives each motion's level of it, and the features are
        centred on each level's mean (module docstring)."""
        motions = list(motions)
        base = PoseCodec.fit(motions, partners, root_mode, "type", False, canonical_side,
                             side_threshold)
        proto = cls(base, np.zeros(len(POSE_FEATURE_NAMES)), np.ones(len(POSE_FEATURE_NAMES)))
        per_motion = [proto._features(m)[0] for m in motions]
        F = np.concatenate(per_motion)
        mean = F.mean(0)
        levels, means = (), None
        if reference is None:
            std = F.std(0)
        else:
            labels = list(reference_labels) if reference_labels is not None else []
            if len(labels) != len(motions) or not all(isinstance(v, str) for v in labels):
                raise BayesmotionError(f"pose reference {reference!r}: every training clip "
                                       f"needs a {reference!r} label (a level name)")
            levels = tuple(sorted(set(labels)))
            means = np.stack([np.concatenate([f for f, v in zip(per_motion, labels,
                                                                 strict=True) if v == lv]).mean(0)
                              for lv in levels])
            centred = np.concatenate([f - means[levels.index(v)]
                                      for f, v in zip(per_motion, labels, strict=True)])
            std = np.sqrt(np.mean(centred**2, axis=0))
        # a feature constant but for rounding keeps scale 1 (not noise blown up to unit sd)
        scale = np.where(std > 1e-9 * (1.0 + np.abs(mean)), std, 1.0)
        return cls(base, mean, scale, reference, levels, means)

    def prepare(self, motion: Motion) -> tuple[Motion, bool]:
        """The motion as the features read it (root folded, on the canonical side) and whether
        it was mirrored."""
        return self.base.prepare(motion)

    def _features(self, motion: Motion) -> tuple[np.ndarray, bool]:
        check_layout(self.skeleton, motion.skeleton)
        prepared, mirrored = self.prepare(motion)
        F = affective_features(prepared)
        bad = ~np.all(np.isfinite(F), axis=1)
        if bad.any():
            names = [POSE_FEATURE_NAMES[j] for j in np.flatnonzero(~np.isfinite(F).all(0))]
            raise BayesmotionError(
                f"{motion.name or 'motion'}: affective features {names} are undefined in "
                f"{int(bad.sum())} frame(s), first {int(np.flatnonzero(bad)[0])} (a ratio's "
                f"reference distance or area is zero: joints that coincide)")
        return F, mirrored

    def centre(self, reference_level: str | None = None) -> np.ndarray:
        """(18,) the features' centre for a clip: the training mean, or with a pose reference
        the mean of the clip's level (BayesmotionError when it is missing or unknown)."""
        if self.reference is None:
            return self.mean
        if reference_level is None:
            raise BayesmotionError(
                f"this model's pose space is relative to each clip's {self.reference!r} "
                f"(HGPDM(pose_reference={self.reference!r})): give the clip's level, as a "
                f"Trial label or infer_emotion(..., reference=...); the model knows "
                f"{list(self.reference_levels)}")
        if reference_level not in self.reference_levels:
            raise BayesmotionError(
                f"{self.reference} {reference_level!r} is not among the training clips' "
                f"levels {list(self.reference_levels)}: the model has no reference posture "
                f"for it")
        return self.reference_means[self.reference_levels.index(reference_level)]

    def encode(self, motion: Motion, partner: Motion | None = None,
               reference_level: str | None = None) -> Encoded:
        """Motion -> (Y (T, 18) standardised features, anchor (empty: nothing to decode),
        mirrored). ``partner`` is accepted for the codec interface and not read: each actor's
        features are its own. ``reference_level``: the clip's level of the pose reference
        (needed exactly when the codec has one)."""
        centre = self.centre(reference_level)
        F, mirrored = self._features(motion)
        return Encoded((F - centre) / self.scale, np.zeros(0), mirrored)

    def decode(self, *args, **kwargs):
        raise BayesmotionError(
            "this model's pose space is the 18 affective pose features "
            "(HGPDM(pose_space='affective')): they do not determine joint angles, so it infers "
            "emotion but cannot generate motion; fit HGPDM(pose_space='angles') to generate")

    decode_rig = decode

    # ---------------------------------------------------------------- saving
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        out = {**self.base.to_arrays(prefix), f"{prefix}feature_mean": self.mean,
               f"{prefix}feature_scale": self.scale}
        if self.reference is not None:
            out[f"{prefix}reference_means"] = self.reference_means
        return out

    def to_meta(self) -> dict:
        meta = {**self.base.to_meta(), "pose_space": self.pose_space}
        if self.reference is not None:
            meta.update(reference=self.reference, reference_levels=list(self.reference_levels))
        return meta

    @classmethod
    def from_saved(cls, meta: dict, arrays, prefix: str) -> AffectiveCodec:
        """The codec written by :meth:`to_arrays`/:meth:`to_meta`; ValueError on bad arrays."""
        base = PoseCodec.from_saved(meta, arrays, prefix)
        n = len(POSE_FEATURE_NAMES)
        mean = np.asarray(arrays[f"{prefix}feature_mean"], dtype=float)
        scale = np.asarray(arrays[f"{prefix}feature_scale"], dtype=float)
        if mean.shape != (n,) or scale.shape != (n,):
            raise ValueError(f"{prefix.rstrip('/')}: feature mean and scale must have shape "
                             f"({n},), got {mean.shape} and {scale.shape}")
        # the scale divides every feature: its reciprocal, squared, must stay finite too
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(scale))
                and np.all(scale >= 1e-150)):
            raise ValueError(f"{prefix.rstrip('/')}: feature mean and scale must be finite, "
                             f"the scale positive (at least 1e-150)")
        reference = meta.get("reference")
        if reference is None:
            return cls(base, mean, scale)
        levels = meta.get("reference_levels")
        if (not isinstance(reference, str) or not isinstance(levels, list) or not levels
                or not all(isinstance(v, str) for v in levels) or len(set(levels)) != len(levels)):
            raise ValueError(f"{prefix.rstrip('/')}: the pose reference must be a label name "
                             f"with a list of distinct level names")
        key = f"{prefix}reference_means"
        if key not in arrays:
            raise ValueError(f"{prefix.rstrip('/')}: the pose reference's means are missing")
        means = np.asarray(arrays[key], dtype=float)
        if means.shape != (len(levels), n) or not np.all(np.isfinite(means)):
            raise ValueError(f"{prefix.rstrip('/')}: the pose reference's means must be finite, "
                             f"of shape ({len(levels)}, {n}), got {means.shape}")
        return cls(base, mean, scale, reference, tuple(levels), means)


def fit_codec(pose_space: str, motions, partners=None, root_mode: str = "velocity",
              scaling: str = "type", rest_frames: bool = False, canonical_side: bool = False,
              reference: str | None = None, reference_labels=None):
    """The codec of ``pose_space`` ("angles": :class:`PoseCodec`, "affective":
    :class:`AffectiveCodec`, relative to ``reference`` when given) fitted on one actor slot's
    motions."""
    check_pose_space(pose_space, rest_frames, scaling, reference)
    if pose_space == "angles":
        return PoseCodec.fit(motions, partners, root_mode, scaling, rest_frames, canonical_side)
    return AffectiveCodec.fit(motions, partners, root_mode, canonical_side,
                              reference=reference, reference_labels=reference_labels)


def reference_level(codec, labels: dict, given: str | None = None) -> str | None:
    """The level of ``codec``'s pose reference for a clip: ``given``, else its label (None for a
    codec without a reference)."""
    ref = getattr(codec, "reference", None)
    if ref is None:
        return None
    return given if given is not None else labels.get(ref)


def check_pose_space(pose_space: str, rest_frames: bool = False,
                     scaling: str = "type", reference: str | None = None) -> None:
    """Raise BayesmotionError unless ``pose_space`` is known and its options apply."""
    if pose_space not in POSE_SPACES:
        raise BayesmotionError(f"pose_space must be one of {'/'.join(POSE_SPACES)}, got "
                               f"{pose_space!r}")
    if reference is not None and (not isinstance(reference, str) or not reference):
        raise BayesmotionError(f"pose_reference must be None or a label name such as "
                               f"'content', got {reference!r}")
    if reference is not None and pose_space != "affective":
        raise BayesmotionError(f"pose_reference={reference!r} centres the affective pose "
                               f"features on each level's mean; it needs "
                               f"pose_space='affective' (a joint-angle model must generate "
                               f"absolute poses)")
    if pose_space == "affective" and rest_frames:
        raise BayesmotionError("rest_frames turns joint angles only; the affective pose space "
                               "reads joint positions, which rest frames leave unchanged: "
                               "drop rest_frames")
    if pose_space == "affective" and scaling != "type":
        raise BayesmotionError(f"scaling={scaling!r} chooses joint-angle channel scales; the "
                               f"affective pose space standardises each feature: leave "
                               f"scaling at its default")


def codec_from_saved(meta: dict, arrays, prefix: str):
    """The codec a model file holds (files without ``pose_space`` hold joint-angle codecs)."""
    if not isinstance(meta, dict):
        raise ValueError(f"{prefix.rstrip('/')}: codec metadata must be a mapping, got "
                         f"{type(meta).__name__}")
    space = meta.get("pose_space", "angles")
    if space == "angles":
        return PoseCodec.from_saved(meta, arrays, prefix)
    if space == "affective":
        return AffectiveCodec.from_saved(meta, arrays, prefix)
    raise ValueError(f"{prefix.rstrip('/')}: unknown pose space {space!r}")
