"""How far an observed clip lies from the training data: per-frame predictive residuals of the
projected clip against the leave-one-out residuals of the training frames.

A new clip is a whole recording the model has not seen, so the reference is the training
recordings held out one at a time. For a GP layer with noisy Gram matrix K (noise included),
outputs Y and the rows b of one training recording, the predictive of Y_b given every other
recording has residual ``C^-1 [K^-1 Y]_b`` and covariance ``C^-1``, where ``C = [K^-1]_bb``
(the block form of Rasmussen & Williams 2006, eq. 5.12), so each held-out frame's standardised
squared residual, averaged over the D output columns, is

    z2_t = mean_d (C^-1 [K^-1 Y]_b)_{td}^2 / (C^-1)_tt.

A clip is scored the same way at its projected latents (MAP X*, I*): ``z2_t = mean_d (y_td -
mu_td)^2 / (var_t + noise)``, with mu, var the layer's predictive; the projection fits the
latents to the clip, so in-distribution clips score at or below the reference. Two layers are
scored: the bottom layer (how well the poses are reconstructed: a foreign rig, impossible
poses) and the dynamics layer (how well the latent trajectory follows the learned dynamics:
motionless or foreign motion).

Each layer is also scored by its negative log predictive density per output column,
nlpd_t = (z2_t + log(2 pi (var_t + noise))) / 2, against the training frames' held-out values:
a clip projected far from every training latent has a wide predictive, so its residuals look
ordinary while its density does not.

A clip is flagged out of distribution when, in any of these four statistics, the median of its
frames exceeds the 99th percentile of the held-out training frames: more than half of its
frames are less likely than 99% of the frames of held-out training recordings; or when the
recording check below exceeds its limit. A non-finite value counts as beyond.

Frame by frame, a clip of another action can look ordinary: its latents are fitted to it, and
a flexible pose space (the 18 affective features) reconstructs a bow as well as a walk. The
recording as a whole does not: its summary -- per pose channel, the mean, the sd and the mean
absolute frame-to-frame change -- is compared with the training recordings' (each channel
scaled by its sd across them). With d the root-mean-square distance to the nearest training
recording and d_ref the largest such distance of a training recording to the others (each
held out in turn), r = d / d_ref. A clip shorter than the training recordings is compared with
their non-overlapping stretches of its own length instead. A new recording like the training
ones exceeds every training recording's distance (r > 1) with probability at most 1 / (n + 1)
for n training recordings (exchangeability: a conformal p-value); it is flagged at r > 1.5.
``benchmarks/results/bandai_inference.json`` (key ``foreign_actions``) sends the other actions
of the shared Bandai clips through the model fitted on the 16 walks.

The emotion answer weighs the model's evidence by how much of the clip looks like training
data (:func:`in_distribution_weight`), w = min(w_frames, w_recording): with a fraction b of its
frames beyond the threshold in the worst statistic (about 1 - 0.99 for a held-out training
recording), w_frames = min(1, (1 - b) / 0.99); w_recording = 1 for r <= 1, 0 for r >= 2, linear
between. The label probabilities are w p(level | clip) + (1 - w) p(level): a clip unlike every
training recording gets the prior, not a confident label.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.errors import BayesmotionError
from bayesmotion.gp.sparse import held_out_blocks
from bayesmotion.model.layers import DynamicsIndex
from bayesmotion.model.predict import (
    LayerFit,
    Predictor,
    SparseLayer,
    noise_variances,
    predict_bottom,
    predict_dynamics,
    whiten,
)

#: quantile of the training frames' leave-one-out z2 that a clip's median frame must exceed
REFERENCE_QUANTILE = 0.99
#: distance ratio r (module docstring) beyond which a recording is flagged
RECORDING_FLAG = 1.5
#: per layer, the standardised residual and the negative log predictive density per output
#: column: a clip projected far from every training latent has a wide predictive, so its
#: residuals look ordinary while its density does not
STATISTICS = ("bottom", "dynamics", "bottom_density", "dynamics_density")


class OutOfDistributionWarning(UserWarning):
    """The clip lies outside the training data: its emotion probabilities are shrunk towards
    the prior (``info["in_distribution_weight"]``); the unshrunk ones, in
    ``info["probabilities_in_distribution"]``, are the model's nearest explanation, not
    evidence about the clip."""


class UnseenStyleWarning(UserWarning):
    """Some emotion level was never seen in training together with the clip's given styles
    (``info["unseen_levels"]``): with one-hot styles such a level is judged by its layers'
    GP prior (with the default stable dynamics, around their shared autoregression), so its
    evidence is not comparable with the other levels'."""


def held_out_z2(fit: LayerFit, groups: np.ndarray) -> np.ndarray:
    """(M,) standardised squared residual of every training row when its group (recording) is
    held out, averaged over the output columns (module docstring)."""
    return held_out_stats(fit, groups)[0]


def held_out_stats(fit: LayerFit | SparseLayer, groups: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(z2, nlpd), each (M,): every training row's standardised squared residual and negative
    log predictive density per output column (nats) when its group is held out (module
    docstring): nlpd = (z2 + log(2 pi v)) / 2 with v = (C^-1)_tt its predictive variance.

    ``fit``: an exact layer's conditioned fit, or a sparse layer
    (:func:`bayesmotion.model.predict.sparse_layers`), whose K is its approximation
    Q + noise I, inverted by Woodbury (:func:`bayesmotion.gp.sparse.held_out_blocks`)."""
    M = fit.outputs.shape[0] if isinstance(fit, SparseLayer) else fit.A.shape[0]
    groups = np.asarray(groups)
    if groups.shape != (M,):
        raise BayesmotionError(f"held_out_stats needs one recording per training row of the "
                               f"layer ({M}), got {groups.shape}")
    z2 = np.empty(M)
    var = np.empty(M)
    for g in np.unique(groups):
        rows = np.flatnonzero(groups == g)
        if isinstance(fit, SparseLayer):
            C, KinvY = held_out_blocks(fit.parts, fit.outputs, rows)
            z, v = _held_out_rows(C, KinvY)
        else:
            z, v = _dense_held_out_rows(fit, jnp.asarray(rows))
        z2[rows], var[rows] = np.asarray(z), np.asarray(v)
    return z2, 0.5 * (z2 + np.log(2 * np.pi * var))


@jax.jit
def _held_out_rows(C, KinvY):
    """(z2, predictive variance) of the held-out rows b from C = [K^-1]_bb and
    [K^-1 Y]_b: residual C^-1 [K^-1 Y]_b, variance diag(C^-1)."""
    Cinv = jnp.linalg.inv(C)
    r = Cinv @ KinvY
    return jnp.mean(r**2, axis=1) / jnp.diag(Cinv), jnp.diag(Cinv)


@jax.jit
def _dense_held_out_rows(fit: LayerFit, rows):
    """:func:`_held_out_rows` of an exact layer's ``rows``, [K^-1]_bb from its whitening: one
    compiled program per group size (a new process pays for each program it compiles)."""
    E = jnp.zeros((fit.A.shape[0], rows.size)).at[rows, jnp.arange(rows.size)].set(1.0)
    V = whiten(fit, E)
    return _held_out_rows(V.T @ V, fit.A[rows])  # [K^-1]_bb, [K^-1 Y]_b


def _summary(z: np.ndarray) -> dict:
    return {"values": z, "median": float(np.median(z)),
            "threshold": float(np.quantile(z, REFERENCE_QUANTILE))}


def training_reference(P: Predictor, trial_of_frame: np.ndarray, order: int,
                       sparse: dict | None = None, loops=None) -> dict:
    """Per statistic (:data:`STATISTICS`): the training frames' held-out-recording values
    (bottom: averaged over actors), their median and ``REFERENCE_QUANTILE`` quantile.

    Args:
        trial_of_frame: (N,) training recording of every frame (each recording's frames
            contiguous); order: the dynamics' order (its outputs are every recording's frames
            after the first ``order``).
        sparse: a sparse model's :func:`bayesmotion.model.predict.sparse_layers` (its
            predictor holds the inducing inputs, not the training rows); None for an exact one.
        loops: a periodic model's loop frames (``ModelData.loops``): its dynamics also has the
            rows that close each loop, held out with their recording.
    """
    tof = np.asarray(trial_of_frame)
    if sparse is not None:
        layers, dyn_layer = sparse["bottom"], sparse["dynamics"]
    else:
        layers = [LayerFit(L, A) for L, A in zip(P.bottom_Linv, P.bottom_A, strict=True)]
        dyn_layer = P.dyn
    bottom = [held_out_stats(fit, tof) for fit in layers]
    starts = np.flatnonzero(np.r_[True, tof[1:] != tof[:-1]])
    if np.unique(tof[starts]).size != starts.size:
        raise BayesmotionError("trial_of_frame must hold each recording's frames together")
    try:
        index = DynamicsIndex(np.diff(np.r_[starts, tof.size]), order, loops)
    except ValueError as e:  # loops of the wrong shape or out of range, too short recordings
        raise BayesmotionError(f"training_reference: {e}") from None
    dyn = held_out_stats(dyn_layer, tof[index.out])
    return {"bottom": _summary(np.mean([b[0] for b in bottom], axis=0)),
            "bottom_density": _summary(np.mean([b[1] for b in bottom], axis=0)),
            "dynamics": _summary(dyn[0]), "dynamics_density": _summary(dyn[1])}


def clip_z2(P: Predictor, X, I, Ys, dyn_styles) -> dict[str, np.ndarray]:
    """Per statistic (:data:`STATISTICS`), the clip's per-frame values at its projected
    latents.

    Args:
        X: (A, T, Q_X) and I: (T, Q_I) projected latents; Ys: per actor (T, D_a) poses in the
            model's space; dyn_styles: per dynamics factor, the clip's (K_f,) style vector.
    Returns:
        ``bottom`` and ``bottom_density``: (T,) averaged over actors; ``dynamics`` and
        ``dynamics_density``: (T - o,) for the frames with o lags.
    """
    out = _clip_z2(P, jnp.asarray(X), jnp.asarray(I), tuple(jnp.asarray(Y) for Y in Ys),
                   tuple(jnp.asarray(s) for s in dyn_styles))
    return {k: np.asarray(v) for k, v in out.items()}


@jax.jit
def _clip_z2(P: Predictor, X, I, Ys, dyn_styles) -> dict:
    """:func:`clip_z2` as one compiled program."""
    noise = noise_variances(P)
    z2, nlpd = [], []
    for a, Y in enumerate(Ys):
        mu, var = predict_bottom(P, a, jnp.asarray(X[a]))
        v = var + noise["Y"]
        z = jnp.mean((jnp.asarray(Y) - mu) ** 2, axis=1) / v
        z2.append(z)
        nlpd.append(0.5 * (z + jnp.log(2 * jnp.pi * v)))
    o = P.dyn_lags.shape[0]
    T = I.shape[0]
    I = jnp.asarray(I)
    lags = jnp.stack([I[o - 1 - k:T - 1 - k] for k in range(o)])
    styles = [jnp.broadcast_to(jnp.asarray(s), (T - o, jnp.asarray(s).shape[-1]))
              for s in dyn_styles]
    mu, var = predict_dynamics(P, lags, styles)
    v = var + noise["I"]
    dyn = jnp.mean((I[o:] - mu) ** 2, axis=1) / v
    return {"bottom": jnp.mean(jnp.stack(z2), axis=0),
            "bottom_density": jnp.mean(jnp.stack(nlpd), axis=0),
            "dynamics": dyn, "dynamics_density": 0.5 * (dyn + jnp.log(2 * jnp.pi * v))}


def assess(reference: dict, z2: dict[str, np.ndarray], recording: dict | None = None) -> dict:
    """The clip's distance from the training data, per statistic and overall.

    Returns a dict: per statistic of :data:`STATISTICS` present in both ``{"median" (the
    clip's median frame), "reference_median", "threshold", "ratio", "beyond" (fraction of the
    clip's frames beyond the threshold)}`` -- for the residuals ``ratio`` is clip median /
    training median (and ``median_z2`` repeats the median), for the densities exp(clip median
    - training median), how many times less likely per output column the clip's median frame
    is; ``recording`` (:func:`recording_distance`, when given); and ``out_of_distribution``
    (bool: a median frame beyond its threshold, or the recording beyond ``RECORDING_FLAG``)
    and ``score`` (the largest ratio)."""
    out = {}
    names = [n for n in STATISTICS if n in reference and n in z2]
    for name in names:
        ref, z = reference[name], z2[name]
        # a non-finite frame value (NaN poses) counts as beyond, never as ordinary
        z = np.where(np.isfinite(z), z, np.inf)
        med = float(np.median(z)) if z.size else float(ref["median"])
        if name.endswith("_density"):
            ratio = float(np.exp(min(med - ref["median"], 700.0)))
        else:
            ratio = med / ref["median"] if ref["median"] > 0 else float("inf")
        out[name] = {"median": med, "reference_median": ref["median"],
                     "threshold": ref["threshold"], "ratio": ratio,
                     "beyond": float(np.mean(z > ref["threshold"])) if z.size else 0.0}
        if not name.endswith("_density"):
            out[name]["median_z2"] = med
    out["out_of_distribution"] = any(out[n]["median"] > out[n]["threshold"] for n in names)
    out["score"] = max(out[n]["ratio"] for n in names)
    if recording is not None:
        out["recording"] = recording
        out["out_of_distribution"] = out["out_of_distribution"] or recording["beyond"]
        out["score"] = max(out["score"], recording["ratio"])
    return out


def worst_statistic(assessment: dict) -> str:
    """The statistic whose median frame lies furthest beyond its threshold (in units of the
    reference's spread between its median and threshold)."""
    names = [n for n in STATISTICS if n in assessment]
    return max(names, key=lambda n: (assessment[n]["median"] - assessment[n]["threshold"])
               / max(assessment[n]["threshold"] - assessment[n]["reference_median"], 1e-12))


def recording_summary(Ys) -> np.ndarray:
    """(3 sum_a D_a,) per actor and pose channel: the mean, the sd and the mean absolute
    frame-to-frame change of a recording's poses (per actor (T, D_a), in the model's space)."""
    parts = []
    for Y in Ys:
        Y = np.asarray(Y, dtype=np.float64)
        step = np.abs(np.diff(Y, axis=0)).mean(0) if Y.shape[0] > 1 else np.zeros(Y.shape[1])
        parts += [Y.mean(0), Y.std(0), step]
    return np.concatenate(parts)


def recording_reference(Y, trial_of_frame, window: int | None = None) -> dict | None:
    """The training recordings' summaries, the channels' scales and each recording's distance
    to its nearest other recording (None with fewer than 3 recordings: no reference).

    Args:
        Y: per actor (N, D_a) training poses; trial_of_frame: (N,) recording of every frame.
        window: compare clips of this many frames: each training recording is cut into
            non-overlapping windows of that length (a shorter recording is one window), so a
            short clip (an online prefix) is compared with stretches of its own length, whose
            means and sds scatter as much as its own; None: whole recordings.
    """
    tof = np.asarray(trial_of_frame)
    ids = np.unique(tof)
    if ids.size < 3:
        return None
    parts, owner = [], []
    for r in ids:
        rows = np.flatnonzero(tof == r)
        w = rows.size if window is None else max(int(window), 2)
        for start in range(0, max(rows.size - w, 0) + 1, w):
            sel = rows[start:start + w]
            parts.append(recording_summary([np.asarray(y)[sel] for y in Y]))
            owner.append(r)
    S = np.stack(parts)
    owner = np.asarray(owner)
    scale = S.std(0)
    scale = np.where(scale > 1e-9 * max(float(scale.max()), 1e-300), scale, np.inf)
    Z = S / scale
    D = np.sqrt(np.mean((Z[:, None] - Z[None]) ** 2, -1))
    D[owner[:, None] == owner[None]] = np.inf  # each held out with its whole recording
    nearest = D.min(1)
    return {"summaries": S, "scale": scale, "owner": owner, "held_out_nearest": nearest,
            "largest": float(nearest.max()), "window": window}


def recording_distance(reference: dict, Ys) -> dict:
    """The clip's distance to its nearest training recording (window) relative to the
    reference's largest (module docstring): ``{"nearest_distance", "reference_largest",
    "ratio", "nearest_recording" (index), "p_value" (conformal, (1 + #{training >= d}) /
    (n + 1)), "beyond" (ratio > RECORDING_FLAG)}``; a non-finite summary (NaN poses) is beyond.
    """
    z = recording_summary(Ys) / reference["scale"]
    d = np.sqrt(np.mean((reference["summaries"] / reference["scale"] - z) ** 2, -1))
    if not np.all(np.isfinite(z)) or not np.any(np.isfinite(d)):
        return {"nearest_distance": float("inf"), "reference_largest": reference["largest"],
                "ratio": float("inf"), "nearest_recording": -1,
                "p_value": 1.0 / (reference["held_out_nearest"].size + 1), "beyond": True}
    k = int(np.argmin(d))
    near = reference["held_out_nearest"]
    ratio = float(d[k] / reference["largest"]) if reference["largest"] > 0 else float("inf")
    return {"nearest_distance": float(d[k]), "reference_largest": reference["largest"],
            "ratio": ratio, "nearest_recording": int(reference["owner"][k]),
            "p_value": float((1 + np.sum(near >= d[k])) / (near.size + 1)),
            "beyond": bool(ratio > RECORDING_FLAG)}


def in_distribution_weight(assessment: dict) -> float:
    """The share of the clip's frames within the training frames' threshold, in its worst
    statistic, relative to the share expected of a training recording
    (``REFERENCE_QUANTILE``); in [0, 1]. The weight of the model's evidence against the prior
    in the emotion answer (module docstring). 0 for a clip of a group (``relative_to``) the
    training trials lack: its poses have no reference of their own."""
    if assessment.get("unknown_group"):
        return 0.0
    inside = min(1.0 - assessment[n]["beyond"] for n in STATISTICS if n in assessment)
    w = float(np.clip(inside / REFERENCE_QUANTILE, 0.0, 1.0))
    if "recording" in assessment:
        r = assessment["recording"]["ratio"]
        w = min(w, float(np.clip(2.0 - r, 0.0, 1.0)) if np.isfinite(r) else 0.0)
    return w if np.isfinite(w) else 0.0
