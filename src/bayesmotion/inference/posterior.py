"""The Bayesian layer: MCMC over hyperparameters and training style vectors.

Sampled: ``theta = (log gamma, log beta, log alpha, u_f for each style factor f)``, where
``u_f: (K_f, K_f - 1)`` maps to one style vector per level on the simplex by stick-breaking (each
training trial uses the vector of its label, as in Wang et al.'s multifactor model).
Held at their MAP values: the latents X and I. The target density, in unconstrained space, is

    log p(theta | Y, X, I) = sum_a log N(Y_a | 0, K_Y(X_a; gamma))
                             + log N([X_1 X_2] | 0, K_X(I, S; beta))
                             + log N(I_out | 0, K_I(I_in, S; alpha)) + log N(I_first | 0, v0)
                             + sum log Normal(log theta_h | log m_h, sigma)      (hyperparameters)
                             + sum_k log Dirichlet(s_k | 1 + kappa onehot(k))    (each level k)
                             + sum_k log |det d s_k / d u_k|                      (stick-breaking)
                             + const,

i.e. :class:`bayesmotion.model.logpost.LogPosterior` with the latents fixed. emcee receives it
jitted over a batch of walkers (``vectorize=True``; :func:`bayesmotion.gp.batch.over_points`
lays the batch out); NUTS (numpyro) gets the same potential.
emcee's default moves: differential evolution, exact rotations along the style vectors'
symmetry orbits (:mod:`bayesmotion.inference.moves`), and an independence Metropolis step on the
hyperparameters, whose proposal adapts once (see ``sample_posterior(independence=...)``).
Only the first line and gamma's prior term depend on gamma, and they depend on nothing else that
is sampled: the posterior is the product p(gamma | Y, X) p(beta, alpha, S | X, I), and with
``factorise=True`` emcee samples the two factors with separate ensembles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.special import ndtri

from bayesmotion.errors import BayesmotionError, warn
from bayesmotion.inference.diagnostics import (
    arviz_without_numba,
    import_arviz,
    save_netcdf,
    to_inference_data,
)
from bayesmotion.inference.predictive import generate_posterior
from bayesmotion.inference.target import Target, chain_gram
from bayesmotion.model.generate import SAMPLE_MEMORY
from bayesmotion.model.logpost import constrained
from bayesmotion.model.params import AR_KEY, STYLE_PREFIX, ar_coefficients, style_to_simplex
from bayesmotion.model.predict import condition


class ChainTooShortWarning(UserWarning):
    """The chain is shorter than 50 integrated autocorrelation times (emcee's rule)."""


@dataclass(eq=False)
class Posterior:
    """Posterior draws of (gamma, beta, alpha, training style vectors) given the MAP latents.

    Attributes:
        model: the FittedHGPDM.
        target: the sampled density.
        chains: (n_chains, n_draws, ndim) unconstrained draws after burn-in and thinning.
        log_prob: (n_chains, n_draws).
        acceptance: (n_chains,) acceptance fraction (emcee; with the factorised sampler that
            of the (beta, alpha, styles) ensemble, gamma's in ``info["bottom_acceptance"]``) or
            mean acceptance prob (NUTS).
        method: "emcee" or "nuts".
        info: tau (per sampled coordinate), tau_gram (per style Gram entry,
            :func:`~bayesmotion.inference.target.gram_entries`), burn, thin, seconds, n_steps,
            warnings.
    """

    model: object
    target: Target
    chains: np.ndarray
    log_prob: np.ndarray
    acceptance: np.ndarray
    method: str
    info: dict = field(default_factory=dict)
    _idata: object = None
    _predictors: dict = field(default_factory=dict)

    @property
    def n_draws(self) -> int:
        return self.chains.shape[0] * self.chains.shape[1]

    def flat(self) -> np.ndarray:
        """(n_chains * n_draws, ndim) unconstrained draws."""
        return self.chains.reshape(-1, self.chains.shape[-1])

    def constrained(self) -> dict[str, np.ndarray]:
        """name -> (n_chains, n_draws, ...) gamma, beta, alpha and style_<factor>."""
        C, D, _ = self.chains.shape
        vmapped = jax.jit(jax.vmap(lambda x: _constrain(self.target.unravel(x),
                                                       self.model.spec.mapping_noise_floor)))
        out = vmapped(jnp.asarray(self.flat()))
        return {k: np.asarray(v).reshape(C, D, *v.shape[1:]) for k, v in out.items()}

    def params(self, i: int) -> dict:
        """Full parameter dict (with the MAP latents) of flat draw ``i``."""
        return self.target.full(self.flat()[i])

    @property
    def idata(self):
        if self._idata is None:
            self._idata = to_inference_data(self)
        return self._idata

    def summary(self, **kwargs):
        """arviz summary (mean, sd, HDI, MCSE, bulk/tail ESS, R-hat) of constrained values."""
        az = import_arviz()


        with arviz_without_numba():
            return az.summary(self.idata, **kwargs)

    def plot_trace(self, var_names=None, **kwargs):
        az = import_arviz()

        return az.plot_trace(self.idata, var_names=var_names, **kwargs)

    def plot_pair(self, var_names=("gamma", "beta", "alpha"), **kwargs):
        az = import_arviz()

        return az.plot_pair(self.idata, var_names=list(var_names), **kwargs)

    def to_netcdf(self, path) -> str:
        return save_netcdf(self.idata, path)

    def predictor(self, i: int):
        """The model conditioned on draw i (cached)."""
        if i not in self._predictors:
            self._predictors[i] = condition(self.model, self.params(i), self.target.jitter)
        return self._predictors[i]

    def generate(self, emotion="neutral", couple=None, n_frames=100, n_samples=0, start=None,
                 seed=0, n_draws: int = 16, client=None, workers: int | None = None,
                 sample_memory: int = SAMPLE_MEMORY, lookahead: float = 0.0,
                 dynamics_style: str = "requested", **styles):
        """Posterior-predictive generation; see
        :func:`bayesmotion.inference.predictive.generate_posterior` (``client`` or
        ``workers``: the draws' rollouts as tasks on a Dask cluster; ``sample_memory``,
        ``lookahead`` and ``dynamics_style`` as in :meth:`bayesmotion.FittedHGPDM.generate`)."""
        return generate_posterior(self, emotion, couple, n_frames, n_samples, start, seed,
                                  n_draws, client, workers, sample_memory, lookahead,
                                  dynamics_style=dynamics_style, **styles)


def _constrain(p: dict, mapping_noise_floor: float = 0.0) -> dict:
    out = constrained(p, mapping_noise_floor)
    if AR_KEY in p:
        out["ar"] = ar_coefficients(p[AR_KEY])
    for k, v in p.items():
        if k.startswith(STYLE_PREFIX):
            out["style_" + k[len(STYLE_PREFIX):]] = style_to_simplex(v)  # (K, K)
    return out


def posterior_from_chain(target, chain, lp, acceptance, burn, thin, info, min_burn: int = 0):
    """Burn-in and thinning from the integrated autocorrelation time of the whole chain, taken
    over the sampled coordinates and the style vectors' Gram entries
    (:func:`~bayesmotion.inference.target.gram_entries`, ``info["tau_gram"]``); the burn-in
    covers at least ``min_burn`` steps (an adaptation)."""
    import emcee

    # a walker that never moved in some coordinate makes emcee's autocorrelation 0/0: that
    # coordinate's tau is then NaN, and burn_thin reports the chain as too short
    gram_names, gram = chain_gram(target, chain) if hasattr(target, "unravel") else ([], None)
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.asarray(emcee.autocorr.integrated_time(chain, tol=0), dtype=float)
        tau_gram = (np.asarray(emcee.autocorr.integrated_time(gram, tol=0), dtype=float)
                    if gram_names else np.empty(0))
    both = np.concatenate([tau, tau_gram])
    bt = burn_thin(both, chain.shape[0], burn, thin, min_burn,
                   (info.get("pace") or {}).get("seconds_per_step"), chain.shape[1])
    sel = slice(bt["burn"], None, bt["thin"])
    return Posterior(target.model, target, np.swapaxes(chain[sel], 0, 1),
                     np.swapaxes(lp[sel], 0, 1), np.asarray(acceptance), "emcee",
                     {**bt, "tau": tau,
                      "tau_gram": dict(zip(gram_names, tau_gram.tolist(), strict=True)),
                      "n_walkers": chain.shape[1], "n_steps": chain.shape[0], **info})


def steps_for_rhat(tau, n_walkers: int, min_burn: int = 0, rhat: float = 1.01) -> int:
    """Steps (rounded up to 100) after which max split R-hat over the walkers is expected to
    fall to ``rhat``, for coordinates of integrated autocorrelation times ``tau``.

    With L steps kept after the burn-in (max(2 tau, ``min_burn``)), the m = 2 ``n_walkers``
    half-chains' means vary about tau / (L / 2) as much as the coordinate, so one coordinate's
    split R-hat is about 1 + (tau (1 + e) - 1) / L, where e, the noise of a variance estimated
    from m means, has sd sqrt(2 / (m - 1)). The largest of d coordinates takes e at its
    expected maximum, z_d sd (z_d: the expected largest of d standard normals, Blom's
    approximation). At the demo size (54 walkers, 26 coordinates) that factor is 1.27. On AR(1)
    walkers of known tau run for the steps the rule names, max R-hat comes out near ``rhat``
    (``tests/test_posterior.py``). On a chain whose tau falls as it runs (the default
    sampler's refitted proposal) the rule with the tau of the whole head overstates max R-hat:
    1.021 against the measured 1.0077 after 1,000 steps at the demo size
    (``benchmarks/results/posterior_convergence.json``, key ``checkpoints``).
    """
    tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    t, d, m = float(tau.max()), tau.size, 2 * int(n_walkers)
    z = float(ndtri((d - 0.375) / (d + 0.25))) if d > 1 else 0.0
    factor = 1.0 + max(z, 0.0) * np.sqrt(2.0 / max(m - 1, 1))
    need = max(2 * t, min_burn) + max(t * factor - 1.0, 0.0) / (rhat - 1.0)
    return _round_up(need)


def _round_up(steps: float, to: int = 100) -> int:
    """``steps`` rounded up to a multiple of ``to``."""
    return int(-(-steps // to) * to)


def _run_instead(tau, n_walkers: int | None, min_burn: int,
                 seconds_per_step: float | None) -> str:
    """What to run instead of a too-short chain: 50 x max tau steps (rounded up to 100), and
    (given ``n_walkers``) the steps after which max R-hat over the walkers is expected to reach
    1.01 (:func:`steps_for_rhat`), with their times at this run's pace."""
    tmax = float(np.max(tau)) if np.all(np.isfinite(tau)) else float("inf")
    if not np.isfinite(tmax):
        return ("some coordinate's walkers never moved (tau undefined): run longer, or start "
                "them wider (init='laplace')")
    need = _round_up(50 * tmax)

    def at_pace(n: int) -> str:
        return f", about {format_seconds(n * seconds_per_step)}" if seconds_per_step else ""

    pace = " at this run's pace" if seconds_per_step else ""
    what = f"run n_steps >= {need} (CLI: --steps {need}){at_pace(need)}{pace}"
    if n_walkers:
        rhat = steps_for_rhat(tau, n_walkers, min_burn)
        what += (f"; max R-hat over the walkers is expected to reach 1.01 near {rhat} steps"
                 f"{at_pace(rhat)}")
    return what + "; a backend file resumes a run without redoing its steps"


def format_seconds(s: float) -> str:
    """A duration as people read it: 42 s, 7.5 min, 3.2 h."""
    if s < 90:
        return f"{s:.0f} s"
    if s < 5400:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.1f} h"


def burn_thin(tau, n_steps, burn, thin, min_burn: int = 0,
              seconds_per_step: float | None = None, n_walkers: int | None = None):
    """Burn-in and thinning from the autocorrelation times; a ``ChainTooShortWarning`` (and
    ``info["warning"]``) when the chain is shorter than 50 of them, saying how many steps to
    run instead, given ``n_walkers`` the steps max R-hat needs (:func:`steps_for_rhat`), and,
    given the run's ``seconds_per_step``, about how long they take."""
    info = {}
    tmax = float(np.nanmax(tau)) if np.all(np.isfinite(tau)) else float("inf")
    if n_steps < 50 * tmax:
        msg = (f"chain of {n_steps} steps is shorter than 50 autocorrelation times "
               f"(max tau ~ {tmax:.0f}): the estimates are unreliable; "
               f"{_run_instead(tau, n_walkers, min_burn, seconds_per_step)}")
        warn(msg, ChainTooShortWarning)
        info["warning"] = msg
    if burn is None:
        burn = int(min(2 * tmax, n_steps // 2)) if np.isfinite(tmax) else n_steps // 2
        burn = max(burn, min_burn)
    elif burn < min_burn:
        raise BayesmotionError(f"burn ({burn}) must cover the independence move's {min_burn} "
                               f"adaptation steps (as NUTS's warm-up); pass burn >= {min_burn}, "
                               f"or independence=False")
    if thin is None:
        thin = max(1, int(0.5 * np.nanmin(tau))) if np.all(np.isfinite(tau)) else 1
    if burn >= n_steps:
        raise BayesmotionError(f"burn ({burn}) must be smaller than the {n_steps} steps")
    info.update(burn=int(burn), thin=int(thin))
    return info


