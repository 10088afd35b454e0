"""MAP fit of a hierarchical GPDM: ``HGPDM.fit(dataset) -> FittedHGPDM``."""

from __future__ import annotations

import numpy as np

from .data.motion import MotionDataset
from .errors import BayesmotionError
from .fitted import FittedHGPDM, trial_records
from .model import HGPDM, LogPosterior, fit_codecs, init_params, prepare_data
from .optim import map_optimize
from .params import STYLE_PREFIX, simplex_to_style


def fit_hgpdm(spec: HGPDM, dataset: MotionDataset, *, optimize_style: bool | tuple = False,
              max_iter: int = 1000, gtol: float = 1e-5, seed: int = 0,
              progress: bool = True, init: dict | None = None) -> FittedHGPDM:
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
        max_iter: L-BFGS iterations.
        gtol: projected-gradient tolerance for convergence.
        seed: seed of the initial perturbation (the fit is deterministic for a seed).
        progress: show a progress bar with the objective.
        init: starting parameters (e.g. a previous fit's, for warm-started refits); must have
            the shapes this dataset implies. Default: PCA initialisation.

    Returns:
        FittedHGPDM with the MAP parameters and convergence diagnostics in ``.diagnostics``.
    """
    spec = spec.resolved(dataset)
    codecs = fit_codecs(spec, dataset)
    data = prepare_data(spec, dataset, codecs)
    logp = LogPosterior(spec, data)
    params0 = init_params(spec, data, seed)
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
    params, diag = map_optimize(logp, params0, max_iter=max_iter, gtol=gtol, progress=progress,
                                desc="MAP fit")
    return FittedHGPDM(spec=spec, params=params, codecs=codecs, levels=dict(dataset.levels),
                       data=data, trials=trial_records(dataset, codecs, spec.root_mode),
                       fps=dataset.fps, diagnostics=diag)


def _free_factors(optimize_style, factors) -> tuple:
    if optimize_style is None or isinstance(optimize_style, bool | np.bool_):
        return tuple(factors) if optimize_style else ()
    free = (optimize_style,) if isinstance(optimize_style, str) else tuple(optimize_style)
    unknown = [f for f in free if f not in factors]
    if unknown:
        raise BayesmotionError(f"optimize_style names {unknown}, which the model does not use; "
                               f"its style factors are {list(factors)}")
    return free
