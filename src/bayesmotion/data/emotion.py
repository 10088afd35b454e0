"""Emotion transforms of joint-angle motion, after Amaya, Bruderlin & Calvert (1996).

Amaya et al. describe an emotion as a change of a neutral movement's **speed/timing** and
**spatial amplitude**, per body part. This module implements those pieces as pure NumPy functions
of a :class:`~bayesmotion.data.Motion` (BVH Euler channels, degrees), plus the **posture
offsets** and root **bounce** used for the built-in emotional handshakes:

* :func:`time_warp` -- resample the channel curves along a warped clock ``tau(t)``:
  ``tau(t) = speed * t * (1 + a (1 - t / D'))`` with ``a = peak_shift`` and ``D'`` the new
  duration (``a > 0`` plays the early part faster, so peaks come earlier); each body-part
  category may lag by ``timing[category]`` seconds. Duration becomes ``D / speed``.
* :func:`scale_amplitude` -- ``theta' = theta_ref + f_category * (theta - theta_ref)`` per
  rotation channel, with ``theta_ref`` the clip's mean posture or a given reference.
* :func:`add_posture` -- add fixed (X, Y, Z) angles to named joints.
* :func:`add_bounce` -- a vertical sine on the root's Y position.
* :func:`apply_emotion` -- all of them from one :class:`EmotionStyle`.

Rotation channels are unwrapped in time (period 360 deg) before any interpolation or scaling and
are returned unwrapped (BVH accepts any angle), so a curve crossing +-180 never jumps by 360.
Body-part categories come from a joint-name -> category mapping (``"torso"``: spine, neck and
head; ``"arms"``: clavicles to fingers; ``"legs"``: hips to toes); the joint that carries the
global position and heading (the root in CMU files, ``Hips`` below Bandai's static
``joint_Root``: :func:`motion_mover`) and its ancestors belong to no category and are never
scaled or lagged.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from bayesmotion.data.motion import Motion, find_mover
from bayesmotion.data.skeleton import ROTATION_CHANNELS, UP_AXIS, Skeleton
from bayesmotion.errors import BayesmotionError

CATEGORIES = ("torso", "arms", "legs")

CMU_BODY_PARTS: Mapping[str, str] = MappingProxyType({
    **{n: "torso" for n in ("LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head")},
    **{f"{s}{n}": "arms" for s in ("Left", "Right")
       for n in ("Shoulder", "Arm", "ForeArm", "Hand", "FingerBase", "HandIndex1")},
    "LThumb": "arms", "RThumb": "arms",
    "LHipJoint": "legs", "RHipJoint": "legs",
    **{f"{s}{n}": "legs" for s in ("Left", "Right") for n in ("UpLeg", "Leg", "Foot", "ToeBase")},
})
"""Body-part category of every non-root joint of the CMU 31-joint skeleton."""

_NAME_RULES = (  # first match wins; applied to the lower-cased joint name
    ("torso", r"^(hips|pelvis)$|spine|back|chest|torso|neck|head|abdomen"),
    ("arms", r"shoulder|clav|arm|elbow|wrist|hand|finger|thumb|index"),
    ("legs", r"hip|leg|thigh|knee|shin|foot|ankle|toe"),
)


def body_parts(skeleton: Skeleton) -> dict[str, str]:
    """Guess each non-root joint's category from its name.

    Works for the CMU and Bandai skeletons (for CMU it equals :data:`CMU_BODY_PARTS`). Joints
    whose names match no rule get no category and are left alone by the transforms.

    Returns:
        joint name -> ``"torso"`` / ``"arms"`` / ``"legs"``.
    """
    out = {}
    for name in skeleton.names[1:]:
        low = name.lower()
        cat = next((c for c, rule in _NAME_RULES if re.search(rule, low)), None)
        if cat is not None:
            out[name] = cat
    return out


@dataclass(frozen=True)
class EmotionStyle:
    """Parameters of an Amaya-style emotion transform (see :func:`apply_emotion`).

    Attributes:
        speed: global speed factor (> 0); the duration becomes ``duration / speed``.
        amplitude: category -> factor on rotation deviations from the reference (missing: 1).
        posture: joint name -> (3,) degrees added to its (X, Y, Z) rotation channels.
        bounce: amplitude of a vertical root oscillation, as a fraction of ``skeleton.size()``.
        bounce_hz: its frequency.
        peak_shift: time-warp shape ``a`` in (-1, 1); > 0 plays the start faster, peaks earlier.
        timing: category -> lag in seconds (> 0: that body part moves later).
    """

    speed: float = 1.0
    amplitude: Mapping[str, float] = field(default_factory=dict)
    posture: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    bounce: float = 0.0
    bounce_hz: float = 2.0
    peak_shift: float = 0.0
    timing: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self):
        if not (np.isfinite(self.speed) and self.speed > 0):
            raise BayesmotionError(f"EmotionStyle: speed must be positive, got {self.speed}")
        if not abs(self.peak_shift) < 1:
            raise BayesmotionError(
                f"EmotionStyle: peak_shift must lie in (-1, 1) to keep time monotone, "
                f"got {self.peak_shift}")
        if not (self.bounce >= 0 and self.bounce_hz > 0):
            raise BayesmotionError(f"EmotionStyle: bounce must be >= 0 and bounce_hz > 0, got "
                                   f"{self.bounce} and {self.bounce_hz}")
        for name, table in (("amplitude", self.amplitude), ("timing", self.timing)):
            bad = sorted(set(table) - set(CATEGORIES))
            if bad:
                raise BayesmotionError(f"EmotionStyle.{name}: unknown categories {bad}; "
                                       f"use {list(CATEGORIES)}")
        if any(not (np.isfinite(f) and f >= 0) for f in self.amplitude.values()):
            raise BayesmotionError(f"EmotionStyle: amplitude factors must be finite and >= 0, "
                                   f"got {dict(self.amplitude)}")
        posture = {j: tuple(float(a) for a in np.broadcast_to(np.asarray(v, float), (3,)))
                   for j, v in self.posture.items()}
        object.__setattr__(self, "speed", float(self.speed))
        object.__setattr__(self, "amplitude", MappingProxyType(
            {k: float(v) for k, v in self.amplitude.items()}))
        object.__setattr__(self, "posture", MappingProxyType(posture))
        object.__setattr__(self, "timing", MappingProxyType(
            {k: float(v) for k, v in self.timing.items()}))


EMOTION_PRESETS: Mapping[str, EmotionStyle] = MappingProxyType({
    # Identity.
    "neutral": EmotionStyle(),
    # Faster, slightly larger, bouncy, upright: spine and neck extended a little.
    "happy": EmotionStyle(
        speed=1.15, amplitude={"torso": 1.1, "arms": 1.15, "legs": 1.05},
        posture={"LowerBack": (-3, 0, 0), "Spine": (-2, 0, 0), "Neck": (-4, 0, 0)},
        bounce=0.012, bounce_hz=2.0, peak_shift=0.1),
    # Faster and larger, leaning forward from the lower back, head pushed forward.
    "angry": EmotionStyle(
        speed=1.25, amplitude={"torso": 1.2, "arms": 1.3, "legs": 1.1},
        posture={"LowerBack": (6, 0, 0), "Spine": (4, 0, 0), "Neck": (4, 0, 0)},
        peak_shift=0.15),
    # Slower and smaller; spine and neck flexed, head down, both shoulders lowered.
    "sad": EmotionStyle(
        speed=0.75, amplitude={"torso": 0.8, "arms": 0.7, "legs": 0.85},
        posture={"LowerBack": (4, 0, 0), "Spine": (4, 0, 0), "Spine1": (3, 0, 0),
                 "Neck": (10, 0, 0), "Neck1": (8, 0, 0), "Head": (6, 0, 0),
                 "LeftShoulder": (0, 0, -6), "RightShoulder": (0, 0, 6)},
        peak_shift=-0.1),
})
"""Emotion presets for the CMU skeleton (posture joints are CMU names; in its local frames +X
flexes the spine/neck forward and -Z / +Z lowers the left / right clavicle)."""


def compose_styles(*styles: EmotionStyle) -> EmotionStyle:
    """One style applying several: speeds and amplitudes multiply, the rest adds.

    ``peak_shift`` values add (the result must stay in (-1, 1)); the bounce frequency is the
    first non-zero bounce's.
    """
    amp, post, timing = {}, {}, {}
    for s in styles:
        for k, f in s.amplitude.items():
            amp[k] = amp.get(k, 1.0) * f
        for j, v in s.posture.items():
            post[j] = tuple(np.add(post.get(j, (0.0, 0.0, 0.0)), v))
        for k, lag in s.timing.items():
            timing[k] = timing.get(k, 0.0) + lag
    hz = next((s.bounce_hz for s in styles if s.bounce > 0), 2.0)
    return EmotionStyle(float(np.prod([s.speed for s in styles])), amp, post,
                        sum(s.bounce for s in styles), hz,
                        sum(s.peak_shift for s in styles), timing)


# ------------------------------------------------------------------------------ helpers
def unwrapped(motion: Motion) -> np.ndarray:
    """(T, C) channel values with rotation channels unwrapped in time (period 360 deg)."""
    v = motion.values.copy()
    rot = motion.rotation_mask()
    v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
    return v


def channel_categories(skeleton: Skeleton, categories: Mapping[str, str] | None = None,
                       mover: int = 0) -> np.ndarray:
    """(C,) category of each rotation channel ("" for position channels and uncategorised joints).

    Args:
        skeleton: the joint tree.
        categories: joint name -> category; defaults to :func:`body_parts`.
        mover: the joint that carries the global position and heading (see
            :func:`motion_mover`); it and its ancestors get no category. The skeleton's root
            for CMU files; ``Hips`` below Bandai's static ``joint_Root``.
    """
    categories = body_parts(skeleton) if categories is None else categories
    bad = sorted(set(categories.values()) - set(CATEGORIES))
    if bad:
        raise BayesmotionError(f"unknown body-part categories {bad}; use {list(CATEGORIES)}")
    glob, j = set(), int(mover)
    while j >= 0:
        glob.add(j)
        j = skeleton.parents[j]
    out = []
    for j, (name, chans) in enumerate(zip(skeleton.names, skeleton.channels, strict=True)):
        cat = "" if j in glob else categories.get(name, "")
        out += [cat if c in ROTATION_CHANNELS else "" for c in chans]
    return np.array(out, dtype=object)


def motion_mover(*motions: Motion) -> int:
    """The joint carrying the motions' global position and heading: the one whose horizontal
    position channels travel most (:func:`bayesmotion.data.motion.find_mover`)."""
    return find_mover(list(motions))


def mean_posture(motion: Motion) -> np.ndarray:
    """(C,) mean of every channel over time, rotations unwrapped first."""
    return unwrapped(motion).mean(axis=0)


def _wrap180(a: np.ndarray) -> np.ndarray:
    return (a + 180.0) % 360.0 - 180.0


# ---------------------------------------------------------------------------- transforms
def resample_at(motion: Motion, times, *, fps: float | None = None,
                timing: Mapping[str, float] | None = None,
                categories: Mapping[str, str] | None = None) -> Motion:
    """Channel curves read off at arbitrary times of the motion's own clock.

    Linear interpolation of the unwrapped channels; times outside the clip hold the end frame.

    Args:
        motion: the source motion.
        times: (T',) seconds on the source clock, one per output frame.
        fps: frame rate of the output (default the source's).
        timing: category -> lag in seconds; a lagged channel is read at ``times - lag``.
        categories: joint name -> category (default :func:`body_parts`).
    Returns:
        the resampled motion, (T', C) values at ``fps``.
    """
    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)):
        raise BayesmotionError(f"times must be a non-empty finite 1-D array, got shape "
                               f"{times.shape}")
    cats = channel_categories(motion.skeleton, categories, motion_mover(motion))
    lags = np.array([dict(timing or {}).get(c, 0.0) if c else 0.0 for c in cats])
    last = motion.n_frames - 1
    pos = np.clip((times[:, None] - lags[None]) * motion.fps, 0, last)  # (T', C) in frames
    pos = np.where(np.abs(pos - np.round(pos)) < 1e-9, np.round(pos), pos)  # exact on frames
    i0 = np.floor(pos).astype(int)
    w = pos - i0
    v = unwrapped(motion)
    cols = np.arange(v.shape[1])[None]
    lo, hi = v[i0, cols], v[np.minimum(i0 + 1, last), cols]
    return motion.replace(values=np.where(w == 0, lo, lo + w * (hi - lo)),
                          fps=motion.fps if fps is None else fps)


def warp_times(n_frames: int, fps: float, speed: float, peak_shift: float = 0.0) -> np.ndarray:
    """Source times of a time warp: ``tau(t) = speed * t * (1 + a (1 - t / D'))``.

    Args:
        n_frames: frames of the source clip; its duration is ``D = (n_frames - 1) / fps``.
        fps: frame rate (kept by the warped clip).
        speed: speed factor; the warped duration is ``D' = D / speed`` (rounded down to frames).
        peak_shift: ``a`` in (-1, 1); keeps ``tau(0) = 0`` and ``tau(D') = D``.
    Returns:
        (T',) source times in seconds, ``T' = floor(D' * fps) + 1``.
    """
    style = EmotionStyle(speed=speed, peak_shift=peak_shift)  # validates
    duration = (n_frames - 1) / fps / style.speed
    t = np.arange(int(np.floor(duration * fps + 1e-9)) + 1) / fps
    if style.peak_shift == 0.0 or duration == 0:
        return style.speed * t
    return style.speed * t * (1.0 + style.peak_shift * (1.0 - t / duration))


def time_warp(motion: Motion, speed: float = 1.0, *, peak_shift: float = 0.0,
              timing: Mapping[str, float] | None = None,
              categories: Mapping[str, str] | None = None) -> Motion:
    """Play a motion ``speed`` times faster along a warped clock (see :func:`warp_times`).

    ``speed=1`` with no peak shift or lags returns the same values (rotations unwrapped);
    ``speed=2`` halves the duration.

    Args:
        motion: (T, C) source.
        speed: global speed factor (> 0).
        peak_shift: warp shape in (-1, 1).
        timing: category -> lag in seconds.
        categories: joint name -> category (default :func:`body_parts`).
    Returns:
        the warped motion, about ``T / speed`` frames at the same fps.
    """
    times = warp_times(motion.n_frames, motion.fps, speed, peak_shift)
    return resample_at(motion, times, timing=timing, categories=categories)


def scale_amplitude(motion: Motion, factors: Mapping[str, float] | float, *, reference=None,
                    categories: Mapping[str, str] | None = None) -> Motion:
    """Scale each rotation channel's deviation from a reference posture, per category.

    ``theta' = theta_ref + f * (theta - theta_ref)``: ``f = 1`` is the identity, ``f = 0`` the
    reference posture. Deviations are taken on the unwrapped curve, starting from the shortest
    angle between the first frame and the reference, so they never jump by 360.

    Args:
        motion: (T, C) source.
        factors: category -> factor (missing categories: 1), or one factor for all categories.
        reference: (C,) reference channel values (e.g. a neutral posture); default the clip's
            :func:`mean_posture`. Only its rotation channels are used.
        categories: joint name -> category (default :func:`body_parts`).
    Returns:
        the scaled motion (position channels and the root unchanged).
    """
    cats = channel_categories(motion.skeleton, categories, motion_mover(motion))
    if not isinstance(factors, Mapping):
        factors = dict.fromkeys(CATEGORIES, float(factors))
    f = np.array([factors.get(c, 1.0) if c else 1.0 for c in cats], dtype=np.float64)
    v = unwrapped(motion)
    ref = mean_posture(motion) if reference is None else np.asarray(reference, np.float64)
    if ref.shape != (v.shape[1],):
        raise BayesmotionError(f"reference must be ({v.shape[1]},) channel values, "
                               f"got shape {ref.shape}")
    on = np.array([bool(c) for c in cats])
    dev = _wrap180(v[0, on] - ref[on]) + (v[:, on] - v[0, on])  # (T, n_on) continuous
    v[:, on] = ref[on] + f[on] * dev
    return motion.replace(values=v)


def add_posture(motion: Motion, posture: Mapping[str, tuple[float, float, float]]) -> Motion:
    """Add fixed angles to joints' rotation channels.

    Args:
        motion: (T, C) source.
        posture: joint name -> (3,) degrees added to its (Xrotation, Yrotation, Zrotation).
    Returns:
        the offset motion.
    Raises:
        BayesmotionError: a joint is not in the skeleton, or lacks a channel for a non-zero
            offset.
    """
    sk = motion.skeleton
    missing = sorted(set(posture) - set(sk.names))
    if missing:
        raise BayesmotionError(f"posture offsets name joints {missing} that the skeleton does "
                               f"not have; give offsets for this skeleton's joints")
    v = motion.values.copy()
    starts = sk.channel_offsets
    for name, offset in posture.items():
        j = sk.index(name)
        for axis, deg in zip("XYZ", np.broadcast_to(np.asarray(offset, float), (3,)),
                             strict=True):
            col = f"{axis}rotation"
            if col in sk.channels[j]:
                v[:, starts[j] + sk.channels[j].index(col)] += deg
            elif deg != 0:
                raise BayesmotionError(f"joint {name!r} has no {col} channel for an offset of "
                                       f"{deg} deg")
    return motion.replace(values=v)


def add_bounce(motion: Motion, amplitude: float, hz: float, *, phase: float = 0.0) -> Motion:
    """Add ``amplitude * sin(2 pi hz t + phase)`` to the root's vertical (Y) position.

    Args:
        motion: (T, C) source; its root must have a Yposition channel.
        amplitude: in the file's length unit.
        hz: frequency.
        phase: radians at ``t = 0``.
    """
    col = motion.skeleton.root_position_columns[UP_AXIS]
    if col < 0:
        raise BayesmotionError("cannot bounce: the root has no Yposition channel")
    v = motion.values.copy()
    t = np.arange(motion.n_frames) / motion.fps
    v[:, col] += amplitude * np.sin(2 * np.pi * hz * t + phase)
    return motion.replace(values=v)


def apply_emotion(motion: Motion, style: EmotionStyle, *, reference=None,
                  categories: Mapping[str, str] | None = None) -> Motion:
    """Apply an emotion style: amplitude, posture, time warp, then bounce.

    Args:
        motion: (T, C) a (neutral) motion.
        style: the transform's parameters, e.g. ``EMOTION_PRESETS["sad"]``.
        reference: (C,) reference posture for :func:`scale_amplitude` (default the clip mean).
        categories: joint name -> category (default :func:`body_parts`).
    Returns:
        the emotional motion, about ``T / style.speed`` frames at the same fps.
    """
    m = scale_amplitude(motion, style.amplitude, reference=reference, categories=categories)
    m = add_posture(m, style.posture)
    m = time_warp(m, style.speed, peak_shift=style.peak_shift, timing=style.timing,
                  categories=categories)
    if style.bounce > 0:
        m = add_bounce(m, style.bounce * m.skeleton.size(), style.bounce_hz)
    return m
