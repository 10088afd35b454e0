"""Fourier principles for emotion-based animation (Unuma, Anjyo & Takeuchi 1995).

As summarised in Kraus's survey of emotional-motion synthesis: a periodic motion (a walk) is a
Fourier series per channel in *normalised* time ``u = t / P`` (P: the cycle period),

    F(t) = a₀ + d·t + Σ_{h=1..H} a_h cos(2π h t / P) + b_h sin(2π h t / P),

fitted by least squares over the whole clip, with a linear drift ``d`` (per second) for the
parts that do not come back (root progression, slow turning). Rotation channels are unwrapped
first so no 360° jump enters the fit.

* Interpolation/extrapolation (Kraus eq. 6): ``Ξ(s) = (1 - s)·F_a + s·F_b`` on the coefficients,
  which are functions of normalised time, with the blended period ``(1 - s)·P_a + s·P_b`` and the
  blended drift per cycle. ``s`` outside [0, 1] extrapolates.
* Emotion component (eq. 7): ``E = F_emotion - F_neutral`` (coefficients and drift per cycle,
  plus the period ratio), after shifting F_emotion in time to the neutral cycle's phase.
* Superposition (eqs. 8-9): ``F_new + s·E`` on a new neutral motion, period ``P_new·(P_e/P_n)^s``.

Cycles are found by the autocorrelation of the joint-angle signals (:func:`detect_period`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar

from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError, SkeletonMismatchError


@dataclass(frozen=True, eq=False)
class FourierModel:
    """A motion as a Fourier series in normalised time (module docstring).

    Attributes:
        skeleton: the skeleton whose channels are modelled.
        period: P, seconds per cycle.
        a0: (C,) constant terms. a, b: (H, C) cosine and sine coefficients of harmonics 1..H.
        drift: (C,) linear drift per second.
        fps: frame rate used by :func:`fourier_eval` by default.
    """

    skeleton: Skeleton
    period: float
    a0: np.ndarray
    a: np.ndarray
    b: np.ndarray
    drift: np.ndarray
    fps: float = 30.0

    @property
    def n_harmonics(self) -> int:
        return self.a.shape[0]

    def values(self, t: np.ndarray) -> np.ndarray:
        """(N,) times in seconds -> (N, C) channel values."""
        t = np.asarray(t, dtype=np.float64)
        w = 2 * np.pi * np.outer(t, np.arange(1, self.n_harmonics + 1)) / self.period  # (N, H)
        return self.a0 + np.outer(t, self.drift) + np.cos(w) @ self.a + np.sin(w) @ self.b


def _unwrapped(motion: Motion) -> np.ndarray:
    v = np.array(motion.values)
    rot = motion.rotation_mask()
    v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
    return v


def _cycle_channels(motion: Motion) -> np.ndarray:
    """(C,) mask of rotation channels other than the root's (the joint-angle signal)."""
    mask = motion.rotation_mask()
    mask[: len(motion.skeleton.channels[0])] = False
    return mask


def detect_period(X: np.ndarray, fps: float, min_period: float = 0.4,
                  max_period: float = 2.5) -> float:
    """Cycle period (seconds) of a multichannel signal by autocorrelation.

    Each channel is detrended (least-squares line) and scaled to unit variance; the channels'
    biased autocorrelations are summed, and the highest peak with lag in
    ``[min_period, max_period]`` (at most half the clip) is refined by a parabola through it
    and its neighbours.

    Args:
        X: (T, D) signals, e.g. unwrapped joint angles. fps: frames per second.
    """
    X = np.asarray(X, dtype=np.float64).reshape(len(X), -1)
    T = X.shape[0]
    t = np.arange(T)
    A = np.stack([np.ones(T), t - t.mean()], axis=1)
    R = X - A @ np.linalg.lstsq(A, X, rcond=None)[0]
    sd = R.std(axis=0)
    R = R[:, sd > 1e-12 * max(sd.max(), 1e-300)] / sd[sd > 1e-12 * max(sd.max(), 1e-300)]
    lo, hi = max(2, int(np.floor(min_period * fps))), min(int(np.ceil(max_period * fps)), T // 2)
    if R.shape[1] == 0 or hi < lo + 1:
        raise BayesmotionError(
            f"cannot detect a period in [{min_period}, {max_period}] s from {T} frames at "
            f"{fps} fps: need two cycles and a varying signal")
    n = 1 << int(np.ceil(np.log2(2 * T)))
    spec = np.fft.rfft(R, n=n, axis=0)
    ac = np.fft.irfft(np.abs(spec) ** 2, n=n, axis=0)[:T].sum(axis=1) / (T * R.shape[1])
    lags = np.arange(lo, hi + 1)
    peaks = lags[(ac[lags] >= ac[lags - 1]) & (ac[lags] >= ac[lags + 1])]
    if peaks.size == 0:
        raise BayesmotionError(f"no autocorrelation peak in [{min_period}, {max_period}] s; "
                               "the motion does not look periodic")
    k = int(peaks[np.argmax(ac[peaks])])
    y0, y1, y2 = ac[k - 1], ac[k], ac[k + 1]
    den = y0 - 2 * y1 + y2
    return float((k + (0.5 * (y0 - y2) / den if den < 0 else 0.0)) / fps)


def motion_period(motion: Motion, **limits) -> float:
    """:func:`detect_period` of a motion's non-root joint angles (unwrapped)."""
    return detect_period(_unwrapped(motion)[:, _cycle_channels(motion)], motion.fps, **limits)


def fourier_fit(motion: Motion, n_harmonics: int = 8, period: float | None = None) -> FourierModel:
    """Least-squares Fourier model of a periodic motion.

    Args:
        motion: the clip (at least one cycle; more cycles average out noise).
        n_harmonics: H.
        period: seconds per cycle; detected by :func:`motion_period` when None.
    """
    P = motion_period(motion) if period is None else float(period)
    T = motion.n_frames
    if T < 2 * n_harmonics + 2:
        raise BayesmotionError(f"{T} frames cannot determine {2 * n_harmonics + 2} coefficients "
                               f"per channel; use fewer harmonics")
    t = np.arange(T) / motion.fps
    w = 2 * np.pi * np.outer(t, np.arange(1, n_harmonics + 1)) / P
    A = np.concatenate([np.ones((T, 1)), t[:, None], np.cos(w), np.sin(w)], axis=1)
    coef = np.linalg.lstsq(A, _unwrapped(motion), rcond=None)[0]     # (2 + 2H, C)
    H = n_harmonics
    return FourierModel(motion.skeleton, P, coef[0], coef[2:2 + H], coef[2 + H:], coef[1],
                        motion.fps)


def fourier_eval(model: FourierModel, n_frames: int | None = None, fps: float | None = None,
                 t0: float = 0.0, name: str = "fourier") -> Motion:
    """A motion sampled from the model at ``t0 + k / fps``, k < n_frames (default: 2 cycles)."""
    fps = model.fps if fps is None else fps
    n = int(round(2 * model.period * fps)) + 1 if n_frames is None else int(n_frames)
    return Motion(model.skeleton, model.values(t0 + np.arange(n) / fps), fps, name)


def _harmonics(model: FourierModel, H: int) -> tuple[np.ndarray, np.ndarray]:
    pad = ((0, H - model.n_harmonics), (0, 0))
    return np.pad(model.a, pad), np.pad(model.b, pad)


def _check_pair(fa: FourierModel, fb: FourierModel) -> None:
    if not fa.skeleton.same_layout(fb.skeleton):
        raise SkeletonMismatchError("Fourier models of different skeleton layouts cannot be "
                                    "combined; retarget one motion first")


def blend(fa: FourierModel, fb: FourierModel, s: float) -> FourierModel:
    """Ξ(s) = (1 - s)·F_a + s·F_b with the blended period (Kraus eq. 6); s=0: F_a, s=1: F_b."""
    _check_pair(fa, fb)
    H = max(fa.n_harmonics, fb.n_harmonics)
    (aa, ba), (ab, bb) = _harmonics(fa, H), _harmonics(fb, H)
    P = (1 - s) * fa.period + s * fb.period
    per_cycle = (1 - s) * fa.drift * fa.period + s * fb.drift * fb.period
    return replace(fa, period=P, a0=(1 - s) * fa.a0 + s * fb.a0, a=(1 - s) * aa + s * ab,
                   b=(1 - s) * ba + s * bb, drift=per_cycle / P)


def shift(model: FourierModel, tau: float) -> FourierModel:
    """The model of ``t -> F(t + tau)`` (tau in seconds)."""
    phi = 2 * np.pi * tau / model.period * np.arange(1, model.n_harmonics + 1)[:, None]
    c, s = np.cos(phi), np.sin(phi)
    return replace(model, a0=model.a0 + model.drift * tau, a=model.a * c + model.b * s,
                   b=model.b * c - model.a * s)


def align_phase(reference: FourierModel, model: FourierModel) -> FourierModel:
    """``model`` shifted in time so its joint-angle cycle correlates best with ``reference``'s.

    The correlation over a cycle is ``½ Σ_h Σ_c (a_ref a' + b_ref b')`` on the non-root rotation
    channels; it is maximised over the phase by a 720-point grid and a bounded refinement.
    """
    _check_pair(reference, model)
    mask = _cycle_channels(Motion(model.skeleton, np.zeros((1, len(model.a0))), model.fps))
    H = min(reference.n_harmonics, model.n_harmonics)
    ar, br = reference.a[:H, mask], reference.b[:H, mask]
    a, b = model.a[:H, mask], model.b[:H, mask]
    h = np.arange(1, H + 1)[:, None]

    def neg_corr(phi):
        c, s = np.cos(h * phi), np.sin(h * phi)
        return -np.sum(ar * (a * c + b * s) + br * (b * c - a * s))

    grid = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    best = grid[np.argmin([neg_corr(p) for p in grid])]
    step = grid[1]
    phi = minimize_scalar(neg_corr, bounds=(best - step, best + step), method="bounded",
                          options={"xatol": 1e-10}).x
    phi = (phi + np.pi) % (2 * np.pi) - np.pi          # the shortest shift, within half a cycle
    return shift(model, phi / (2 * np.pi) * model.period)


@dataclass(frozen=True, eq=False)
class EmotionComponent:
    """E = F_emotion - F_neutral (Kraus eq. 7).

    Attributes:
        da0: (C,), da, db: (H, C) coefficient differences; d_cycle: (C,) drift-per-cycle
        difference; period_ratio: P_emotion / P_neutral.
    """

    da0: np.ndarray
    da: np.ndarray
    db: np.ndarray
    d_cycle: np.ndarray
    period_ratio: float


def emotion_component(f_emotion: FourierModel, f_neutral: FourierModel,
                      align: bool = True) -> EmotionComponent:
    """The emotion's difference from neutral, after phase alignment when ``align``."""
    _check_pair(f_emotion, f_neutral)
    fe = align_phase(f_neutral, f_emotion) if align else f_emotion
    H = max(fe.n_harmonics, f_neutral.n_harmonics)
    (ae, be), (an, bn) = _harmonics(fe, H), _harmonics(f_neutral, H)
    return EmotionComponent(fe.a0 - f_neutral.a0, ae - an, be - bn,
                            fe.drift * fe.period - f_neutral.drift * f_neutral.period,
                            fe.period / f_neutral.period)


def superpose(f_new: FourierModel, component: EmotionComponent, s: float = 1.0) -> FourierModel:
    """F_new + s·E with period P_new·ratio^s (Kraus eqs. 8-9)."""
    H = max(f_new.n_harmonics, component.da.shape[0])
    a, b = _harmonics(f_new, H)
    pad = ((0, H - component.da.shape[0]), (0, 0))
    if component.da0.shape != f_new.a0.shape:
        raise SkeletonMismatchError(f"emotion component has {component.da0.shape[0]} channels, "
                                    f"the motion {f_new.a0.shape[0]}")
    P = f_new.period * component.period_ratio ** s
    return replace(f_new, period=P, a0=f_new.a0 + s * component.da0,
                   a=a + s * np.pad(component.da, pad), b=b + s * np.pad(component.db, pad),
                   drift=(f_new.drift * f_new.period + s * component.d_cycle) / P)
