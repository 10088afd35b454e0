"""Verbs and adverbs (Rose, Cohen & Bodenheimer 1998): interpolating examples over emotions.

A *verb* is a set of example motions of one action; each sits at a point of an *adverb* space,
here emotion coordinates (:func:`emotion_coordinates`: neutral at the origin, one unit axis per
emotion, so ``0.5 · e_happy`` is half-happy) or a 1-d strength. Synthesis at a new point:

1. **Time normalisation.** Every example is warped to a common normalised time ``u ∈ [0, 1]``
   and sampled at ``n_samples`` points: linearly, or piecewise linearly between matching
   keyframes (``keytimes``), whose canonical normalised times are the examples' mean.
2. **Scattered-data interpolation** of the sampled channels, the duration and the normalised key
   times with a linear polynomial plus radial basis functions (Rose et al. §4.2)::

       y(p) = Σ_i c_i φ(‖p - p_i‖) + a₀ + aᵀ p,    with  Σ_i c_i = 0,  Σ_i c_i p_i = 0,

   solved as one augmented linear system ``[[Φ, Π], [Πᵀ, 0]] [c; a] = [Y; 0]``. The polynomial
   part reproduces linear functions of the adverbs exactly; φ is ``r³`` by default (or
   ``r² log r``, ``-r``, ``exp(-(εr)²)``).
3. **Time de-normalisation** with the interpolated duration and key times.

Rotation channels are unwrapped, and each example's channels shifted by whole turns to lie
nearest the first example's, before anything is averaged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError, SkeletonMismatchError

KERNELS = {
    "cubic": lambda r, eps: r**3,
    "thin_plate": lambda r, eps: np.where(r > 0, r**2 * np.log(np.where(r > 0, r, 1.0)), 0.0),
    "linear": lambda r, eps: -r,
    "gaussian": lambda r, eps: np.exp(-((eps * r) ** 2)),
}


def _distances(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.linalg.norm(x[:, None, :] - y[None, :, :], axis=-1)


def _poly(x: np.ndarray, degree: int) -> np.ndarray:
    """(M, P) -> (M, 0 | 1 | 1 + P) monomials up to ``degree`` (-1, 0 or 1)."""
    cols = [np.ones((len(x), 1))] if degree >= 0 else []
    return np.concatenate(cols + ([x] if degree >= 1 else []), axis=1) if cols else \
        np.zeros((len(x), 0))


@dataclass(frozen=True, eq=False)
class RBFInterpolant:
    """y(p) = Σ c_i φ(‖p - p_i‖) + polynomial(p). centres: (N, P), c: (N, D), a: (Q, D)."""

    centres: np.ndarray
    c: np.ndarray
    a: np.ndarray
    kernel: str = "cubic"
    epsilon: float = 1.0
    degree: int = 1

    def __call__(self, x) -> np.ndarray:
        """(M, P) or (P,) points -> (M, D) or (D,) values."""
        x = np.asarray(x, dtype=np.float64)
        single = x.ndim == 1
        x = np.atleast_2d(x)
        phi = KERNELS[self.kernel](_distances(x, self.centres), self.epsilon)
        y = phi @ self.c + _poly(x, self.degree) @ self.a
        return y[0] if single else y


def fit_rbf(points, values, kernel: str = "cubic", epsilon: float = 1.0, degree: int = 1,
            smoothing: float = 0.0) -> RBFInterpolant:
    """Solve the augmented RBF system (module docstring, step 2).

    Args:
        points: (N, P) example locations. values: (N, D) or (N,) example values.
        kernel: a key of ``KERNELS``. epsilon: shape parameter (gaussian only).
        degree: polynomial degree -1 (none), 0 (constant) or 1 (linear, as in Rose et al.).
        smoothing: added to Φ's diagonal (0: exact interpolation).
    """
    X = np.atleast_2d(np.asarray(points, dtype=np.float64))
    Y = np.asarray(values, dtype=np.float64).reshape(len(X), -1)
    if kernel not in KERNELS:
        raise BayesmotionError(f"unknown RBF kernel {kernel!r}; choose one of {list(KERNELS)}")
    N = len(X)
    Pi = _poly(X, degree)
    Q = Pi.shape[1]
    A = np.zeros((N + Q, N + Q))
    A[:N, :N] = KERNELS[kernel](_distances(X, X), epsilon) + smoothing * np.eye(N)
    A[:N, N:], A[N:, :N] = Pi, Pi.T
    rhs = np.concatenate([Y, np.zeros((Q, Y.shape[1]))])
    try:
        sol = np.linalg.solve(A, rhs)
    except np.linalg.LinAlgError:
        raise BayesmotionError(
            f"RBF system is singular: {N} examples in {X.shape[1]}-d with a degree-{degree} "
            "polynomial need distinct points, at least P+1 of them not on one hyperplane"
        ) from None
    return RBFInterpolant(X, sol[:N], sol[N:], kernel, epsilon, degree)


def emotion_coordinates(labels: Sequence[str], emotions: Sequence[str],
                        neutral: str = "neutral", strength: Sequence[float] | None = None
                        ) -> np.ndarray:
    """(N, E) adverb points: neutral at 0, ``emotions[k]`` at ``strength · e_k``."""
    s = np.ones(len(labels)) if strength is None else np.asarray(strength, dtype=np.float64)
    out = np.zeros((len(labels), len(emotions)))
    for i, lab in enumerate(labels):
        if lab != neutral:
            if lab not in emotions:
                raise BayesmotionError(f"label {lab!r} is neither {neutral!r} nor one of "
                                       f"{list(emotions)}")
            out[i, list(emotions).index(lab)] = s[i]
    return out


def _warp(n: int, keys, ref) -> np.ndarray:
    """Source positions (in frames) of n normalised samples; keys: frames, ref: normalised."""
    u = np.linspace(0.0, 1.0, n)
    return np.interp(u, ref, keys)


def time_normalise(values: np.ndarray, n_samples: int, keys=None, ref_keys=None) -> np.ndarray:
    """(T, C) -> (n_samples, C) on normalised time; ``keys`` (K,) frames map to ``ref_keys``."""
    T = len(values)
    keys = [0.0, T - 1.0] if keys is None else np.asarray(keys, dtype=np.float64)
    ref_keys = [0.0, 1.0] if ref_keys is None else ref_keys
    src = _warp(n_samples, keys, ref_keys)
    return np.stack([np.interp(src, np.arange(T), v) for v in values.T], axis=1)


def time_denormalise(samples: np.ndarray, n_frames: int, keys=None, ref_keys=None) -> np.ndarray:
    """Inverse of :func:`time_normalise`: (n_samples, C) -> (n_frames, C)."""
    keys = [0.0, n_frames - 1.0] if keys is None else np.asarray(keys, dtype=np.float64)
    ref_keys = [0.0, 1.0] if ref_keys is None else ref_keys
    u = np.interp(np.arange(n_frames), keys, ref_keys)
    grid = np.linspace(0.0, 1.0, len(samples))
    return np.stack([np.interp(u, grid, v) for v in samples.T], axis=1)


def _aligned_values(motions: Sequence[Motion]) -> list[np.ndarray]:
    """Unwrapped channels, each example's rotations shifted by whole turns towards example 0."""
    rot = motions[0].rotation_mask()
    out = []
    for m in motions:
        v = np.array(m.values)
        v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
        if out:
            turns = np.round((out[0][:, rot].mean(0) - v[:, rot].mean(0)) / 360.0)
            v[:, rot] += 360.0 * turns
        out.append(v)
    return out


@dataclass(frozen=True, eq=False)
class Verb:
    """Examples of one action interpolated over an adverb space (module docstring)."""

    skeleton: Skeleton
    fps: float
    n_samples: int
    ref_keys: np.ndarray          # (K,) canonical normalised key times, 0 ... 1
    interpolant: RBFInterpolant   # p -> [samples (n·C), duration, interior key times (K-2)]

    def synthesize(self, point, fps: float | None = None, name: str = "verb") -> Motion:
        """The motion at adverb ``point: (P,)``."""
        fps = self.fps if fps is None else fps
        y = self.interpolant(np.asarray(point, dtype=np.float64))
        C = self.skeleton.n_channels
        samples = y[: self.n_samples * C].reshape(self.n_samples, C)
        duration, inner = y[self.n_samples * C], y[self.n_samples * C + 1:]
        n = max(2, int(round(duration * fps)) + 1)
        # extrapolated key times may leave [0, 1] or cross; clip and keep them non-decreasing
        keys = np.concatenate([[0.0], np.maximum.accumulate(np.clip(inner, 0, 1)), [1.0]])
        return Motion(self.skeleton, time_denormalise(samples, n, keys * (n - 1), self.ref_keys),
                      fps, name)


def fit_verb(motions: Sequence[Motion], points, n_samples: int | None = None, keytimes=None,
             kernel: str = "cubic", epsilon: float = 1.0) -> Verb:
    """Build a verb from examples.

    Args:
        motions: (N,) examples of one action, same skeleton layout and fps.
        points: (N, P) adverb coordinates (see :func:`emotion_coordinates`).
        n_samples: normalised-time samples (default: the longest example's frame count).
        keytimes: (N, K) increasing frame indices of matching keyframes, first 0 and last
            T_i - 1; None for a linear time warp.
        kernel: see :func:`fit_rbf`.
        epsilon: see :func:`fit_rbf`.
    """
    if len({(m.skeleton.names, m.skeleton.channels) for m in motions}) > 1:
        raise SkeletonMismatchError("verb examples must share one skeleton layout")
    if len({m.fps for m in motions}) > 1:
        raise BayesmotionError("verb examples must share one frame rate; resample them first")
    T = np.array([m.n_frames for m in motions], dtype=np.float64)
    if keytimes is None:
        keytimes = np.stack([[0.0, t - 1] for t in T])
    keytimes = np.asarray(keytimes, dtype=np.float64)
    if (keytimes.shape[0] != len(motions) or np.any(keytimes[:, 0] != 0)
            or np.any(keytimes[:, -1] != T - 1) or np.any(np.diff(keytimes, axis=1) <= 0)):
        raise BayesmotionError("keytimes must be (N, K) increasing frames from 0 to T_i - 1")
    norm_keys = keytimes / (T - 1)[:, None]
    ref = norm_keys.mean(axis=0)
    n = int(T.max()) if n_samples is None else int(n_samples)
    fps = motions[0].fps
    Y = [np.concatenate([time_normalise(v, n, k, ref).ravel(), [(t - 1) / fps], nk[1:-1]])
         for v, k, t, nk in zip(_aligned_values(motions), keytimes, T, norm_keys, strict=True)]
    interp = fit_rbf(np.asarray(points, dtype=np.float64).reshape(len(motions), -1),
                     np.stack(Y), kernel, epsilon)
    return Verb(motions[0].skeleton, fps, n, ref, interp)
