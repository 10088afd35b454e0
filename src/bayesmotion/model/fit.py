"""MAP fit of a hierarchical GPDM: ``HGPDM.fit(dataset) -> FittedHGPDM``."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from bayesmotion._config import release_compiled_programs
from bayesmotion.data.motion import MotionDataset
from bayesmotion.errors import BayesmotionError
from bayesmotion.gp.densities import cell_ids
from bayesmotion.model.data import ModelData, fit_codecs, prepare_data
from bayesmotion.model.fitted import FittedHGPDM, trial_records
from bayesmotion.model.layers import DynamicsIndex, InducingPlan
from bayesmotion.model.logpost import LogPosterior
from bayesmotion.model.params import (
    AR_KEY,
    INDUCING_KEYS,
    STYLE_PREFIX,
    ar_pacf,
    simplex_to_style,
)
from bayesmotion.optim.minimize import CONVERGENCE_RTOL, map_optimize

if TYPE_CHECKING:
    from bayesmotion.model.spec import HGPDM

#: how ``fit(init=...)`` can initialise the latents by name
LATENT_INITS = ("pca", "shared")


def fit_hgpdm(spec: HGPDM, dataset: MotionDataset, *, optimize_style: bool | tuple = False,
              max_iter: int = 1000, gtol: float = 1e-5, rtol: float = CONVERGENCE_RTOL,
              max_seconds: float | None = None, seed: int = 0, progress: bool = True,
              init: dict | str | None = None) -> FittedHGPDM:
    """Fit latents X, I and hyperparameters (gamma, beta, alpha) by MAP.

    Args:
        spec: model specification (defaults resolved against the dataset).
        dataset: training trials with labels for every style factor.
        optimize_style: also optimise the style vector of each level on the simplex
            (initialised at their Dirichlet prior mean around the label, or at ``init``'s);
            True for every factor, or the names of the factors to free (e.g. ``("content",)``:
            Wang et al.'s learned content vectors, which let a held-out combination of content
            and emotion borrow from the other contents); otherwise they stay one-hot. Style
            vectors given in ``init`` are optimised too.
        max_iter: the most L-BFGS iterations.
        gtol: projected-gradient tolerance for convergence.
        rtol: the stall test: converged when the objective fell by less than ``rtol`` of its
            magnitude over the last 100 iterations
            (:func:`bayesmotion.optim.minimize.stalled`; 0 turns it off). The criterion and
            whether it was met are in ``diagnostics["convergence"]``.
        max_seconds: stop after the iteration that passes this many seconds of optimisation
            (a time budget; the fit is then reported as not converged).
        seed: seed of the initial perturbation (the fit is deterministic for a seed).
        progress: show a progress bar with the objective.
        init: starting parameters (e.g. a previous fit's, for warm-started refits; they must
            have the shapes this dataset implies), or how to initialise the latents:
            ``"pca"`` (the default): X from each actor's poses and I from the stacked X by
            PCA, so trials of different styles start in different latent regions;
            ``"shared"``: I by PCA of the stacked X with each interaction style cell's mean
            removed, so every cell's trials start in one shared region of I (e.g. one gait
            cycle for every emotion) and the style-specific mappings carry the differences
            (:func:`init_params`). Checked before any work.

    Returns:
        FittedHGPDM with the MAP parameters and convergence diagnostics in ``.diagnostics``.
    """
    release_compiled_programs()  # each fit compiles anew for its shapes: keep the maps bounded
    latents = init if isinstance(init, str) else "pca"
    if latents not in LATENT_INITS:
        raise BayesmotionError(f"init must be a parameter dict or one of {LATENT_INITS}, got "
                               f"{init!r}")
    init = None if isinstance(init, str) else init
    if init is not None and not isinstance(init, Mapping):
        raise BayesmotionError(f"init must be a parameter dict or one of {LATENT_INITS}, got "
                               f"{type(init).__name__}")
    spec = spec.resolved(dataset)
    codecs = fit_codecs(spec, dataset)
    data = prepare_data(spec, dataset, codecs)
    logp = LogPosterior(spec, data)
    params0 = init_params(spec, data, seed, latents=latents)
    free = _free_factors(optimize_style, spec.factors)
    for f, conc in logp.style_prior.concentration.items():
        if f in free or STYLE_PREFIX + f in (init or {}):  # init's style vectors stay free
            mean = conc / conc.sum(1, keepdims=True)
            params0[STYLE_PREFIX + f] = np.asarray(simplex_to_style(mean))
    if init is not None:
        for k, v in init.items():
            if k.startswith(STYLE_PREFIX) and k not in params0:
                raise BayesmotionError(f"init[{k!r}]: the model has no style factor "
                                       f"{k[len(STYLE_PREFIX):]!r}")
            if k in params0 and np.shape(v) != np.shape(params0[k]):
                raise BayesmotionError(f"init[{k!r}] has shape {np.shape(v)}, this dataset "
                                       f"needs {np.shape(params0[k])}")
        params0.update({k: np.asarray(v) for k, v in init.items()})
        if spec.inducing is not None and not set(INDUCING_KEYS) & set(init):
            # inducing inputs where init put the latents, not where PCA did
            params0.update(initial_inducing(np.asarray(params0["X"]), np.asarray(params0["I"]),
                                            logp.index, spec.inducing))
    params, diag = map_optimize(logp, params0, max_iter=max_iter, gtol=gtol, rtol=rtol,
                                max_seconds=max_seconds, progress=progress, desc="MAP fit")
    return FittedHGPDM(spec=spec, params=params, codecs=codecs, levels=dict(dataset.levels),
                       data=data, trials=trial_records(dataset, codecs, spec.root_mode),
                       fps=dataset.fps, diagnostics=diag)


def pca(Y: np.ndarray, q: int) -> np.ndarray:
    """(N, D) -> (N, q) principal-component scores, scaled so the first has unit std."""
    Yc = Y - Y.mean(0)
    U, s, _ = np.linalg.svd(Yc, full_matrices=False)
    q_eff = min(q, s.size)
    Z = U[:, :q_eff] * s[:q_eff]
    if q_eff < q:
        Z = np.concatenate([Z, np.zeros((Y.shape[0], q - q_eff))], axis=1)
    sd = Z[:, 0].std() or 1.0
    return Z / sd


def init_params(spec: HGPDM, data: ModelData, seed: int = 0, jitter_scale: float = 1e-3,
                latents: str = "pca"):
    """PCA initialisation of X (per actor) and I (from the stacked X), default hyperparameters.

    ``latents="shared"``: I from the stacked X with the mean of each interaction style cell
    (the trials sharing all interaction-factor levels) removed, so the cells overlap in I.
    With one-hot styles the interaction kernel vanishes between cells, and so does the
    dynamics kernel when the dynamics factors include every interaction factor (the
    default): then the overlap costs no likelihood, and a rollout at mixed style coordinates
    blends mappings that are all defined where it is. A tiny seeded perturbation breaks
    exact ties (deterministic for a seed).
    """
    if latents not in LATENT_INITS:
        raise BayesmotionError(f"latents must be one of {LATENT_INITS}, got {latents!r}")
    rng = np.random.default_rng(seed)
    X = np.stack([pca(Y, spec.latent_dim) for Y in data.Y])
    Z = np.concatenate(list(X), axis=1)
    if latents == "shared" and spec.interaction_factors:
        tof = data.trial_of_frame
        cells = cell_ids([data.onehot[f][tof] for f in spec.interaction_factors])
        means = np.stack([Z[cells == c].mean(0) for c in range(cells.max() + 1)])
        I = pca(Z - means[cells], spec.interaction_dim)
    else:
        I = pca(Z, spec.interaction_dim)
    X = X + jitter_scale * rng.standard_normal(X.shape)
    I = I + jitter_scale * rng.standard_normal(I.shape)
    var_y = float(np.mean([np.mean(Y**2) for Y in data.Y]))
    var_z = float(np.mean(Z**2))
    var_i = float(np.mean(I**2))
    o = spec.order
    lin = [] if spec.stable_dynamics else [0.5 / o] * o
    params = {
        "X": X,
        "I": I,
        "log_gamma": np.log([var_y, 1.0, 100.0 / var_y]),
        "log_beta": np.log([var_z, 1.0, 100.0 / var_z]),
        "log_alpha": np.log([var_i] + [1.0] * o + lin + [100.0 / var_i]),
    }
    index = DynamicsIndex(data.lengths, o, data.loops)
    if spec.stable_dynamics:
        params[AR_KEY] = initial_ar(I, index)
    if spec.inducing is not None:
        params.update(initial_inducing(X, I, index, spec.inducing))
    return params


def initial_inducing(X: np.ndarray, I: np.ndarray, index: DynamicsIndex, m: int) -> dict:
    """The sparse model's inducing inputs at the evenly spaced training frames of
    :class:`~bayesmotion.model.layers.InducingPlan` (their latents, and the dynamics' lags of
    its output rows)."""
    plan = InducingPlan(I.shape[0], index, m)
    lags = np.stack([I[ix] for ix in index.lag])  # (o, n_out, Q_I)
    return {"Xu": X[:, plan.frames].copy(), "Iu": I[plan.frames].copy(),
            "Du": lags[:, plan.outs].copy()}


def initial_ar(I: np.ndarray, index: DynamicsIndex, max_pacf: float = 0.95) -> np.ndarray:
    """Unconstrained start of the explicit autoregression: the least-squares scalar AR(o) of
    the initial latents pooled over trials and dimensions, its partial autocorrelations
    clipped to +-``max_pacf`` (inside the stationary region, away from its edge)."""
    lags = np.stack([I[ix].ravel() for ix in index.lag], axis=1)  # (n * Q, o)
    a = np.linalg.lstsq(lags, I[index.out].ravel(), rcond=None)[0]
    if a.size == 2:  # pull a non-stationary fit inside the triangle, then read its phi
        a[1] = np.clip(a[1], -max_pacf, max_pacf)
        a[0] = np.clip(a[0], -max_pacf * (1.0 - a[1]), max_pacf * (1.0 - a[1]))
    return np.arctanh(np.clip(ar_pacf(np.clip(a, -max_pacf, max_pacf) if a.size == 1 else a),
                              -max_pacf, max_pacf))


def _free_factors(optimize_style, factors) -> tuple:
    if optimize_style is None or isinstance(optimize_style, bool | np.bool_):
        return tuple(factors) if optimize_style else ()
    free = (optimize_style,) if isinstance(optimize_style, str) else tuple(optimize_style)
    unknown = [f for f in free if f not in factors]
    if unknown:
        raise BayesmotionError(f"optimize_style names {unknown}, which the model does not use; "
                               f"its style factors are {list(factors)}")
    return free
