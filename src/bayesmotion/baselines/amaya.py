"""The Amaya et al. (1996) baseline: an emotion as speed, amplitude and posture changes.

Amaya, Bruderlin & Calvert (1996), "Emotion from motion", estimate an emotional transform from
one neutral/emotional pair of the same movement and apply it to other neutral movements. Here
the transform is an :class:`~bayesmotion.data.emotion.EmotionStyle`:

* ``speed`` = neutral duration / emotional duration (``speed_from="duration"``), or, for pairs
  not spanning the same movement, the ratio of mean joint angular speeds divided by the
  amplitude ratio, per category, median over categories (``"angular_speed"``; both clips are
  smoothed over 30 ms of neutral time first, as capture jitter makes raw angular speeds depend
  on the sampling resolution);
* ``amplitude[category]`` = ``sqrt(sum_c var_emo[c] / sum_c var_neu[c])`` over the category's
  rotation channels (variances about each clip's mean, unwrapped angles);
* ``posture[joint]`` = mean emotional minus mean neutral angle per (X, Y, Z) rotation channel.

Timing lags, the peak shift and the bounce are not identified from a single unaligned pair and
are left at zero. :func:`apply_amaya` applies the fitted style with
:func:`~bayesmotion.data.emotion.apply_emotion`, the same code that builds the built-in
emotional handshakes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

import numpy as np
from scipy.ndimage import gaussian_filter1d

from bayesmotion.data.emotion import (
    CATEGORIES,
    EmotionStyle,
    apply_emotion,
    channel_categories,
    motion_mover,
    unwrapped,
)
from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError, SkeletonMismatchError

SMOOTH_S = 0.03  # Gaussian smoothing (seconds of neutral time) before angular speeds


def _path_rate(v: np.ndarray, fps: float, sigma_s: float) -> float:
    """Mean absolute angular speed (deg/s, summed over channels) after Gaussian smoothing."""
    if len(v) < 2:
        return 0.0
    v = gaussian_filter1d(v, sigma_s * fps, axis=0, mode="nearest")
    return float(np.abs(np.diff(v, axis=0)).sum() * fps / (len(v) - 1))


def _speed_from_angular(vn, ve, fps_n, fps_e, sel: dict, amplitude: dict) -> float:
    """Speed s with ``rate_e / rate_n = s * amplitude``, per category (median over them).

    Capture jitter makes path lengths depend on resolution, so the emotional clip is smoothed
    over ``SMOOTH_S / s`` seconds, matching ``SMOOTH_S`` of neutral time; s is a fixed point.
    """
    rate_n = {c: _path_rate(vn[:, sel[c]], fps_n, SMOOTH_S) for c in amplitude}
    used = [c for c in amplitude if amplitude[c] > 0 and rate_n[c] > 0]
    if not used:
        return float("nan")
    speed = 1.0
    for _ in range(5):
        speed = float(np.median([_path_rate(ve[:, sel[c]], fps_e, SMOOTH_S / speed)
                                 / rate_n[c] / amplitude[c] for c in used]))
        if not (np.isfinite(speed) and speed > 0):
            return float("nan")
    return speed


def _posture(neutral: Motion, mean_diff: np.ndarray, on: np.ndarray) -> dict[str, tuple]:
    """joint -> (X, Y, Z) mean differences, for joints with categorised rotation channels."""
    sk = neutral.skeleton
    starts = sk.channel_offsets
    out = {}
    for j, (name, chans) in enumerate(zip(sk.names, sk.channels, strict=True)):
        axes = {c[0]: starts[j] + k for k, c in enumerate(chans) if on[starts[j] + k]}
        if axes:
            out[name] = tuple(float(mean_diff[axes[a]]) if a in axes else 0.0 for a in "XYZ")
    return out


def fit_amaya(neutral: Motion, emotional: Motion, categories: Mapping[str, str] | None = None,
              *, speed_from: Literal["duration", "angular_speed"] = "duration") -> EmotionStyle:
    """Estimate an emotion style from a neutral and an emotional performance of one movement.

    Args:
        neutral: (T, C) the neutral motion.
        emotional: (T', C) the emotional motion, same skeleton layout.
        categories: joint name -> category (default
            :func:`~bayesmotion.data.emotion.body_parts`).
        speed_from: ``"duration"`` (the pair spans the same movement) or ``"angular_speed"``.
    Returns:
        the style: speed, per-category amplitude, per-joint posture offsets.
    Raises:
        SkeletonMismatchError: the two motions have different joints or channels.
    """
    if not neutral.skeleton.same_layout(emotional.skeleton):
        raise SkeletonMismatchError("fit_amaya: neutral and emotional motions must share one "
                                    "skeleton layout (joints, tree, channels)")
    cats = channel_categories(neutral.skeleton, categories, motion_mover(neutral, emotional))
    on = cats != ""
    vn, ve = unwrapped(neutral)[:, on], unwrapped(emotional)[:, on]
    sel = {c: cats[on] == c for c in CATEGORIES}
    amplitude = {}
    for c in CATEGORIES:
        var_n = vn[:, sel[c]].var(axis=0).sum()
        if sel[c].any() and var_n > 0:
            amplitude[c] = float(np.sqrt(ve[:, sel[c]].var(axis=0).sum() / var_n))
    if speed_from == "duration":
        speed = neutral.duration / emotional.duration if emotional.duration > 0 else np.nan
    elif speed_from == "angular_speed":
        speed = _speed_from_angular(vn, ve, neutral.fps, emotional.fps, sel, amplitude)
    else:
        raise BayesmotionError(f"speed_from must be 'duration' or 'angular_speed', "
                               f"got {speed_from!r}")
    if not (np.isfinite(speed) and speed > 0):
        raise BayesmotionError("fit_amaya: cannot estimate a speed; give motions of more than "
                               "one frame that move")
    diff = np.zeros(len(cats))
    diff[on] = (ve.mean(axis=0) - vn.mean(axis=0) + 180.0) % 360.0 - 180.0
    return EmotionStyle(speed=float(speed), amplitude=amplitude,
                        posture=_posture(neutral, diff, on))


def apply_amaya(style: EmotionStyle, neutral_motion: Motion, *, reference=None,
                categories: Mapping[str, str] | None = None) -> Motion:
    """Apply a (fitted) style to a neutral motion; see
    :func:`~bayesmotion.data.emotion.apply_emotion`.

    Args:
        style: e.g. from :func:`fit_amaya`.
        neutral_motion: (T, C) the motion to transform.
        reference: (C,) reference posture for the amplitude scaling (default the clip mean).
        categories: joint name -> category.
    Returns:
        the transformed motion.
    """
    return apply_emotion(neutral_motion, style, reference=reference, categories=categories)
