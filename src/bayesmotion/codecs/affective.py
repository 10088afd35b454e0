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

Relative to a group (``HGPDM(pose_space="affective", relative_to="content")``): between
actions the features differ far more than between emotions of one action (a bow's posture is
not a walk's), so a model that pools several actions spends its latent space on the action.
With ``relative_to`` every frame's standardised features minus the mean over the training
frames of the trials sharing its label (its group, e.g. its content) are modelled: how a clip
departs from its action, as :class:`~bayesmotion.baselines.classifier.GroupCentred` does for
the affective-feature classifier. A clip is then read relative to its group's training mean,
so its label must be given (:func:`bayesmotion.emotion.infer.infer_emotion` takes it from the
trial's labels or from ``styles``). A clip of a group the training trials lack has no
reference: it is read relative to the mean over all training frames, and reported as outside
the training data (``EmotionPosterior.info["ood"]["unknown_group"]``) with the evidence given
no weight.
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
            feature is constant, to rounding).
        relative_to: None, or the label (e.g. "content") whose groups' means are subtracted
            (module docstring).
        groups: the training groups' labels, in order (empty without ``relative_to``).
        offsets: (G, 18) each group's mean standardised features over its training frames
            (None without ``relative_to``).
    """

    base: PoseCodec
    mean: np.ndarray
    scale: np.ndarray
    relative_to: str | None = None
    groups: tuple[str, ...] = ()
    offsets: np.ndarray | None = None
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
            relative_to: str | None = None, groups=None) -> AffectiveCodec:
        """Fit the preparation steps and the features' means and scales on training motions
        (one actor slot; arguments as :meth:`PoseCodec.fit`); with ``relative_to``, also
        each group's mean, ``groups`` giving every motion's label (module docstring)."""
        motions = list(motions)
        base = PoseCodec.fit(motions, partners, root_mode, "type", False, canonical_side,
                             side_threshold)
        proto = cls(base, np.zeros(len(POSE_FEATURE_NAMES)), np.ones(len(POSE_FEATURE_NAMES)))
        Fs = [proto._features(m)[0] for m in motions]
        F = np.concatenate(Fs)
        mean, std = F.mean(0), F.std(0)
        # a feature constant but for rounding keeps scale 1 (not noise blown up to unit sd)
        scale = np.where(std > 1e-9 * (1.0 + np.abs(mean)), std, 1.0)
        if relative_to is None:
            return cls(base, mean, scale)
        labels = _group_labels(relative_to, groups, len(motions))
        names = tuple(sorted(set(labels)))
        offsets = np.stack([
            np.concatenate([f for f, g in zip(Fs, labels, strict=True) if g == name]).mean(0)
            for name in names])
        return cls(base, mean, scale, relative_to, names, (offsets - mean) / scale)

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

    def knows(self, group) -> bool:
        """Whether ``group`` is one of the training groups (always True without
        ``relative_to``)."""
        return self.relative_to is None or str(group) in self.groups

    def encode(self, motion: Motion, partner: Motion | None = None,
               group=None) -> Encoded:
        """Motion -> (Y (T, 18) standardised features, anchor (empty: nothing to decode),
        mirrored). ``partner`` is accepted for the codec interface and not read: each actor's
        features are its own. ``group``: the motion's ``relative_to`` label (needed when the
        codec has one; a group the training motions lack is read relative to the mean over all
        training frames, see :meth:`knows`)."""
        F, mirrored = self._features(motion)
        Y = (F - self.mean) / self.scale
        if self.relative_to is not None:
            if group is None:
                raise BayesmotionError(
                    f"{motion.name or 'the motion'}: this model reads poses relative to their "
                    f"{self.relative_to!r} (HGPDM(relative_to={self.relative_to!r})), and the "
                    f"motion has no {self.relative_to!r} label: give it in the trial's labels "
                    f"or as styles={{{self.relative_to!r}: ...}}, one of {list(self.groups)}")
            if self.knows(group):
                Y = Y - self.offsets[self.groups.index(str(group))]
        return Encoded(Y, np.zeros(0), mirrored)

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
        if self.relative_to is not None:
            out[f"{prefix}group_offsets"] = self.offsets
        return out

    def to_meta(self) -> dict:
        meta = {**self.base.to_meta(), "pose_space": self.pose_space}
        if self.relative_to is not None:
            meta.update(relative_to=self.relative_to, groups=list(self.groups))
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
        relative_to = meta.get("relative_to")
        if relative_to is None:
            return cls(base, mean, scale)
        groups = meta.get("groups")
        if (not isinstance(relative_to, str) or not isinstance(groups, list) or not groups
                or not all(isinstance(g, str) for g in groups) or len(set(groups)) != len(groups)):
            raise ValueError(f"{prefix.rstrip('/')}: relative_to must be a label name and "
                             f"groups a list of distinct group names")
        key = f"{prefix}group_offsets"
        if key not in arrays:
            raise ValueError(f"{prefix.rstrip('/')}: the codec reads poses relative to "
                             f"{relative_to!r} but the file holds no group offsets")
        offsets = np.asarray(arrays[key], dtype=float)
        # standardised group means: a few units; a bound keeps the subtraction finite
        if (offsets.shape != (len(groups), n) or not np.all(np.isfinite(offsets))
                or np.max(np.abs(offsets), initial=0.0) > 1e6):
            raise ValueError(f"{prefix.rstrip('/')}: group offsets must be finite, at most 1e6 "
                             f"in size, with shape ({len(groups)}, {n}), got {offsets.shape}")
        return cls(base, mean, scale, relative_to, tuple(groups), offsets)


def _group_labels(relative_to: str, groups, n: int) -> list[str]:
    """Every training motion's ``relative_to`` label, as text; refuses a missing one."""
    if groups is None or len(groups) != n:
        raise BayesmotionError(f"relative_to={relative_to!r} needs every training motion's "
                               f"{relative_to!r} label")
    missing = [i for i, g in enumerate(groups) if g is None]
    if missing:
        raise BayesmotionError(f"relative_to={relative_to!r}: {len(missing)} training trial(s) "
                               f"have no {relative_to!r} label (first: trial {missing[0]}); "
                               f"every training trial needs one")
    return [str(g) for g in groups]


def fit_codec(pose_space: str, motions, partners=None, root_mode: str = "velocity",
              scaling: str = "type", rest_frames: bool = False, canonical_side: bool = False,
              relative_to: str | None = None, groups=None):
    """The codec of ``pose_space`` ("angles": :class:`PoseCodec`, "affective":
    :class:`AffectiveCodec`) fitted on one actor slot's motions; ``relative_to`` and
    ``groups`` (every motion's label) as :meth:`AffectiveCodec.fit`."""
    check_pose_space(pose_space, rest_frames, scaling, relative_to)
    if pose_space == "angles":
        return PoseCodec.fit(motions, partners, root_mode, scaling, rest_frames, canonical_side)
    return AffectiveCodec.fit(motions, partners, root_mode, canonical_side,
                              relative_to=relative_to, groups=groups)


def check_pose_space(pose_space: str, rest_frames: bool = False,
                     scaling: str = "type", relative_to: str | None = None) -> None:
    """Raise BayesmotionError unless ``pose_space`` is known and its options apply."""
    if pose_space not in POSE_SPACES:
        raise BayesmotionError(f"pose_space must be one of {'/'.join(POSE_SPACES)}, got "
                               f"{pose_space!r}")
    if relative_to is not None:
        if not isinstance(relative_to, str) or not relative_to:
            raise BayesmotionError(f"relative_to must be None or a label name such as "
                                   f"'content', got {relative_to!r}")
        if relative_to == "emotion":
            raise BayesmotionError("relative_to='emotion' would subtract each emotion's own "
                                   "mean and leave nothing to tell the emotions apart: name "
                                   "another label, such as 'content'")
        if pose_space != "affective":
            raise BayesmotionError(f"relative_to={relative_to!r} subtracts group means from "
                                   f"the affective pose features, which a joint-angle model "
                                   f"would have to add back to generate: use "
                                   f"pose_space='affective' (CLI --pose-space affective)")
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
