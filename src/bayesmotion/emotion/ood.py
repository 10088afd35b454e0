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

A clip is flagged out of distribution when, in either layer, the median of its frames' z2
exceeds the 99th percentile of the held-out training frames' z2: more than half of its frames
are less likely than 99% of the frames of held-out training recordings.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from bayesmotion.model.predict import (
    LayerFit,
    Predictor,
    noise_variances,
    predict_bottom,
    predict_dynamics,
    whiten,
)

#: quantile of the training frames' leave-one-out z2 that a clip's median frame must exceed
REFERENCE_QUANTILE = 0.99
LAYERS = ("bottom", "dynamics")


class OutOfDistributionWarning(UserWarning):
    """The clip lies outside the training data: its emotion probabilities describe the model's
    nearest explanation, not evidence about the clip."""


def held_out_z2(fit: LayerFit, groups: np.ndarray) -> np.ndarray:
    """(M,) standardised squared residual of every training row when its group (recording) is
    held out, averaged over the output columns (module docstring)."""
    M = fit.A.shape[0]
    out = np.empty(M)
    for g in np.unique(groups):
        rows = np.flatnonzero(groups == g)
        E = jnp.zeros((M, rows.size)).at[rows, np.arange(rows.size)].set(1.0)
        V = whiten(fit, E)
        C = V.T @ V  # [K^-1]_bb
        Cinv = jnp.linalg.inv(C)
        r = Cinv @ fit.A[rows]
        out[rows] = np.asarray(jnp.mean(r**2, axis=1) / jnp.diag(Cinv))
    return out


def training_reference(P: Predictor, trial_of_frame: np.ndarray, order: int) -> dict:
    """Per layer: the training frames' held-out-recording z2 (bottom: averaged over actors) and
    its median and ``REFERENCE_QUANTILE`` quantile.

    Args:
        trial_of_frame: (N,) training recording of every frame; order: the dynamics' order
            (its outputs are every recording's frames after the first ``order``).
    """
    tof = np.asarray(trial_of_frame)
    bottom = np.mean([held_out_z2(LayerFit(L, A), tof)
                      for L, A in zip(P.bottom_Linv, P.bottom_A, strict=True)], axis=0)
    starts = np.flatnonzero(np.r_[True, tof[1:] != tof[:-1]])
    first = np.zeros(tof.size, bool)
    for k in range(order):
        first[starts + k] = True
    dyn = held_out_z2(P.dyn, tof[~first])
    return {name: {"z2": z, "median": float(np.median(z)),
                   "threshold": float(np.quantile(z, REFERENCE_QUANTILE))}
            for name, z in (("bottom", bottom), ("dynamics", dyn))}


def clip_z2(P: Predictor, X, I, Ys, dyn_styles) -> dict[str, np.ndarray]:
    """Per layer, the clip's per-frame z2 at its projected latents.

    Args:
        X: (A, T, Q_X) and I: (T, Q_I) projected latents; Ys: per actor (T, D_a) poses in the
            model's space; dyn_styles: per dynamics factor, the clip's (K_f,) style vector.
    Returns:
        ``bottom``: (T,) averaged over actors; ``dynamics``: (T - o,) for the frames with o lags.
    """
    noise = noise_variances(P)
    bottom = []
    for a, Y in enumerate(Ys):
        mu, var = predict_bottom(P, a, jnp.asarray(X[a]))
        bottom.append(jnp.mean((jnp.asarray(Y) - mu) ** 2, axis=1) / (var + noise["Y"]))
    o = P.dyn_lags.shape[0]
    T = I.shape[0]
    I = jnp.asarray(I)
    lags = jnp.stack([I[o - 1 - k:T - 1 - k] for k in range(o)])
    styles = [jnp.broadcast_to(jnp.asarray(s), (T - o, jnp.asarray(s).shape[-1]))
              for s in dyn_styles]
    mu, var = predict_dynamics(P, lags, styles)
    dyn = jnp.mean((I[o:] - mu) ** 2, axis=1) / (var + noise["I"])
    return {"bottom": np.asarray(jnp.mean(jnp.stack(bottom), axis=0)), "dynamics": np.asarray(dyn)}


def assess(reference: dict, z2: dict[str, np.ndarray]) -> dict:
    """The clip's distance from the training data, per layer and overall.

    Returns a dict: per layer ``{"median_z2", "reference_median", "threshold", "ratio"
    (clip median / training median), "beyond" (fraction of the clip's frames beyond the
    threshold)}``, and ``out_of_distribution`` (bool) and ``score`` (the larger ratio)."""
    out = {}
    for name in LAYERS:
        ref, z = reference[name], z2[name]
        med = float(np.median(z)) if z.size else 0.0
        out[name] = {"median_z2": med, "reference_median": ref["median"],
                     "threshold": ref["threshold"],
                     "ratio": med / ref["median"] if ref["median"] > 0 else float("inf"),
                     "beyond": float(np.mean(z > ref["threshold"])) if z.size else 0.0}
    out["out_of_distribution"] = any(out[n]["median_z2"] > out[n]["threshold"] for n in LAYERS)
    out["score"] = max(out[n]["ratio"] for n in LAYERS)
    return out
