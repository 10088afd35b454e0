"""Time registration of motion paths and their blend along a registration curve.

A rollout between two emotions can be made from each emotion's own rollout: the multifactor
kernel is linear in each input's style vector, so the predictive mean at coordinates ``c``
over levels with one-hot training styles is ``sum_k c_k m_k(z)`` (``m_k``: level k's part of
the GP mean). Each level's training latents lie in a region of their own, so at one latent
point ``z`` all levels but one fall back towards the prior mean (0). A registered rollout
evaluates each ``m_k`` on its own level's path instead, ``sum_k c_k m_k(z_k(tau_k(t)))``,
with time warps ``tau_k`` that put the same phase of the movement at the same output time:
the registration curves of Kovar & Gleicher (2003, "Flexible automatic motion blending with
registration curves"), found here by dynamic time warping with slopes in [1/2, 2].

Pure NumPy: the warps are found on mean paths that are already computed, once per rollout.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from bayesmotion.errors import BayesmotionError

MAX_SLOPE = 2
"""A warp advances the other path by 1/2 to 2 frames per reference frame (steps (1, 1),
(1, 2) and (2, 1) of the dynamic time warping)."""
SMOOTH_SECONDS = 0.1
"""Standard deviation (seconds, at least one frame) of the Gaussian that smooths a warp's
integer steps, so the blended motion does not jerk where the warp steps by 0 or 2 frames."""
TIE_BREAK = 1e-9
"""Extra cost of a (1, 2) or (2, 1) step, relative to the first frame's mean cost: equal
paths resolve to the diagonal."""


def registration_features(path: np.ndarray) -> np.ndarray:
    """(T, D) poses -> (T, 2 D) poses and their frame-to-frame velocities (the last frame's
    repeated), so a pose passed on the way forward is told from the same pose on the way
    back."""
    vel = np.diff(path, axis=0, append=path[-1:] * 2 - path[-2:-1])
    return np.concatenate([path, vel], axis=1)


def time_warp(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The frame of ``other`` matched to each frame of ``ref`` by dynamic time warping.

    Every frame of ``ref`` (La, F) is matched (it is the reference's timeline); ``other``
    (Lb, F) is matched along a subsequence (open begin and end), so the two paths may start
    at different phases of a movement. Steps (1, 1), (1, 2) and (2, 1) keep the local slope
    in [1/2, 2]; a path's cost is the sum over the reference's frames of the squared distance
    to its matched frame, so every path has La terms and paths of any slope compare fairly.

    Args:
        ref: (La, F) features of the reference path.
        other: (Lb, F) features of the other path, Lb >= ceil(La / 2).
    Returns:
        (La,) int array, non-decreasing, steps of 0, 1 or 2.
    """
    ref, other = np.asarray(ref, np.float64), np.asarray(other, np.float64)
    La, Lb = len(ref), len(other)
    if La < 2 or Lb < -(-La // MAX_SLOPE):
        raise BayesmotionError(f"cannot register a path of {La} frames against one of {Lb}: "
                               f"the other needs at least {max(2, -(-La // MAX_SLOPE))} frames")
    sq_other = np.sum(other**2, 1)

    def cost(i):  # (Lb,) squared distances of ref[i] to every frame of other
        return np.maximum(sq_other - 2 * other @ ref[i] + ref[i] @ ref[i], 0.0)

    def shift(v, k):  # v[j - k], inf where j < k
        out = np.full_like(v, np.inf)
        out[k:] = v[:-k]
        return out

    choice = np.zeros((La, Lb), np.int8)  # 1: (1, 1), 2: (1, 2), 3: (2, 1), 0: path start
    c_prev, D_prev = cost(0), cost(0)  # open begin: any frame of other can match ref[0]
    # a slope change costs a negligible amount more than the diagonal, so that where poses
    # repeat (a body at rest) equal costs resolve to the diagonal, not to slope 1/2
    tie = TIE_BREAK * (1.0 + float(np.mean(c_prev)))
    D_prev2 = None
    for i in range(1, La):
        c = cost(i)
        cand = np.stack([shift(D_prev, 1), shift(D_prev, 2) + tie,
                         (c_prev if D_prev2 is None else shift(D_prev2, 1) + c_prev) + tie])
        k = np.argmin(cand, axis=0)
        choice[i] = k + 1
        D_prev2, D_prev, c_prev = D_prev, c + cand[k, np.arange(Lb)], c
    j = int(np.argmin(D_prev))  # open end
    if not np.isfinite(D_prev[j]):
        raise BayesmotionError("time registration found no path (non-finite poses?)")
    match = np.empty(La, dtype=np.int64)
    i = La - 1
    while i >= 0:
        match[i] = j
        step = int(choice[i, j]) if i > 0 else 0
        if step == 3:
            match[i - 1] = j
            i, j = i - 2, j - 1
        else:
            i, j = i - 1, j - step  # (1, 1): j - 1; (1, 2): j - 2
    return match


def smooth_warp(match: np.ndarray, fps: float, smooth_s: float = SMOOTH_SECONDS) -> np.ndarray:
    """A warp's integer matches -> a smooth non-decreasing float warp with the same first
    frame: its steps (0, 1 or 2 frames) smoothed by a Gaussian of ``smooth_s`` seconds (at
    least one frame) and summed again. Smoothing the steps, not the positions, keeps a warp
    of slope 1 the identity and its start where the warping put it; non-negative steps stay
    non-negative."""
    match = np.asarray(match, np.float64)
    if len(match) < 2:
        return match
    sigma = max(1.0, smooth_s * fps)
    steps = gaussian_filter1d(np.diff(match), sigma, mode="nearest")
    return match[0] + np.concatenate([[0.0], np.cumsum(steps)])


def blend_timeline(warps: list[np.ndarray], weights: np.ndarray) -> np.ndarray:
    """The blended motion's time at each reference frame: the weighted mean of the paths'
    elapsed times ``sum_k w_k (tau_k(i) - tau_k(0))`` with weights normalised to sum to 1
    (Kovar & Gleicher's timing of a blend). Raises when it does not increase (coordinates so
    far off the simplex that the blend would run backwards)."""
    w = np.asarray(weights, np.float64)
    if w.sum() <= 0:
        raise BayesmotionError(f"a registered blend needs coordinates with a positive sum, got "
                               f"{w.tolist()}")
    w = w / w.sum()
    u = sum(wk * (tau - tau[0]) for wk, tau in zip(w, warps, strict=True))
    if np.any(np.diff(u) <= 0):
        raise BayesmotionError(f"coordinates {np.asarray(weights).tolist()} lie too far off the "
                               f"simplex for a registered blend: its timing would run backwards")
    return u


def at_times(path: np.ndarray, times: np.ndarray, axis: int = 0) -> np.ndarray:
    """``path`` linearly interpolated at fractional frame ``times`` along ``axis``; times are
    clipped to the path."""
    path = np.moveaxis(np.asarray(path), axis, 0)
    t = np.clip(np.asarray(times, np.float64), 0, len(path) - 1)
    lo = np.minimum(np.floor(t).astype(np.int64), len(path) - 2)
    f = (t - lo).reshape((-1,) + (1,) * (path.ndim - 1))
    return np.moveaxis(path[lo] * (1 - f) + path[lo + 1] * f, 0, axis)


def registration(paths: list[np.ndarray], weights: np.ndarray, ref: int, n_frames: int,
                 fps: float) -> list[np.ndarray]:
    """Where to read each path for every frame of the blend.

    Args:
        paths: per level, (L_k, F) mean features (e.g. decoded poses) of its rollout.
        weights: (n_levels,) the style coordinates of the levels.
        ref: index of the reference path (the largest weight): its frames are all matched.
        n_frames: frames of the blend.
        fps: frame rate (for the warps' smoothing).
    Returns:
        per level, (n_frames,) fractional frames of its path.
    """
    if min(len(p) for p in paths) < 2:
        raise BayesmotionError("registration needs paths of at least 2 frames")
    feats = [registration_features(p) for p in paths]
    pooled = np.concatenate(feats)
    # every feature centred and on one scale; one that does not vary is left as it is
    # (centred: 0), so no constant offset enters the distances' rounding
    sd = np.std(pooled, axis=0)
    scale = np.where(sd > 1e-12 * max(float(sd.max()), 1e-300), sd, 1.0)
    feats = [(f - pooled.mean(0)) / scale for f in feats]
    warps = [np.arange(len(paths[ref]), dtype=np.float64) if k == ref else
             smooth_warp(time_warp(feats[ref], f), fps)
             for k, f in enumerate(feats)]
    u = blend_timeline(warps, weights)
    if u[-1] < n_frames - 1:
        raise BayesmotionError(f"the registered paths cover {u[-1] + 1:.0f} frames of the "
                               f"blend, fewer than the {n_frames} asked for")
    i = np.interp(np.arange(n_frames, dtype=np.float64), u, np.arange(len(u), dtype=np.float64))
    return [np.interp(i, np.arange(len(tau), dtype=np.float64), tau) for tau in warps]


def blend(paths: list[np.ndarray], times: list[np.ndarray], weights, axis: int = 0,
          power: int = 1) -> np.ndarray:
    """``sum_k w_k**power path_k(times_k)``: the blend of the paths read at their registered
    times (``power=2`` blends variances of independent paths)."""
    return sum(float(w)**power * at_times(p, t, axis)
               for p, t, w in zip(paths, times, weights, strict=True))
