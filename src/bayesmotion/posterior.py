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

i.e. :class:`bayesmotion.model.LogPosterior` with the latents fixed. emcee receives it jitted
and ``vmap``-ped over walkers (``vectorize=True``); NUTS (numpyro) gets the same potential.
emcee's default moves: differential evolution, exact rotations along the style vectors'
symmetry orbits (:mod:`bayesmotion.moves`), and an independence Metropolis step on the
hyperparameters, whose proposal adapts once (see ``sample_posterior(independence=...)``).
Only the first line and gamma's prior term depend on gamma, and they depend on nothing else that
is sampled: the posterior is the product p(gamma | Y, X) p(beta, alpha, S | X, I), and with
``factorise=True`` emcee samples the two factors with separate ensembles.
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .chainfile import ChainFile, open_h5
from .errors import BayesmotionError
from .model import LAYERS
from .moves import (
    EnsembleHMC,
    IndependenceMove,
    Sequence,
    StyleRotations,
    style_slices,
)
from .optim import map_optimize
from .params import STYLE_PREFIX, simplex_to_style, style_to_simplex

SAMPLED_HYPER = ("log_gamma", "log_beta", "log_alpha")
# With the latents fixed the posterior factorises: p(gamma | Y, X) p(beta, alpha, S | X, I).
# block -> the layers whose likelihood it needs. "bottom" samples BOTTOM_KEYS, "upper" the rest.
BOTTOM_KEYS = ("log_gamma",)
BLOCKS = {"bottom": ("bottom",), "upper": ("interaction", "dynamics")}
# the independence move: a rotated style coordinate whose Laplace sd is below PINNED_SD (logit
# units) is pinned by the likelihood (the rotations keep each style vector's norm, and near its
# vertex one stick coordinate is that norm), so it joins the non-rotated block; the first
# min(ADAPT_STEPS, n_steps // 4) steps propose from the Laplace approximation, the rest from
# the moments of the adaptation's last two thirds
PINNED_SD = 0.1
ADAPT_STEPS = 150


class ChainTooShortWarning(UserWarning):
    """The chain is shorter than 50 integrated autocorrelation times (emcee's rule)."""


def sampled_start(model) -> dict:
    """Initial sampled parameters: MAP hyperparameters, style vectors from the model (or each
    level's Dirichlet prior mean when the MAP kept them one-hot). Factors with a single level
    have nothing to sample and stay fixed."""
    p = {k: np.asarray(model.params[k]) for k in SAMPLED_HYPER}
    conc = model.log_posterior_fn.style_prior.concentration
    for f in model.spec.factors:
        key = STYLE_PREFIX + f
        if len(model.levels[f]) < 2:
            continue
        if key in model.params:
            p[key] = np.asarray(model.params[key])
        else:
            p[key] = np.asarray(simplex_to_style(conc[f] / conc[f].sum(1, keepdims=True)))
    return p


class Target:
    """The sampled log-density at one flat-vector boundary.

    ``Target(model)`` exposes ``x0`` (flat start), ``names`` (one per coordinate), ``unravel``,
    ``logp(x)`` (jitted), ``logp_batch(xs)`` (jitted vmap over walkers) and ``full(x)`` (the
    complete parameter dict with the fixed latents).
    """

    def __init__(self, model, jitter: float | None = None, block: str | None = None):
        self.model = model
        self.jitter = model.diagnostics.get("jitter", 1e-8) if jitter is None else jitter
        start = sampled_start(model)
        if block is not None:
            if block not in BLOCKS:
                raise BayesmotionError(f"block must be one of {sorted(BLOCKS)}, got {block!r}")
            start = {k: v for k, v in start.items()
                     if (k in BOTTOM_KEYS) == (block == "bottom")}
        which = LAYERS if block is None else BLOCKS[block]
        x0, self.unravel = ravel_pytree({k: jnp.asarray(v) for k, v in start.items()})
        self.x0 = np.asarray(x0)
        self.fixed = {"X": jnp.asarray(model.params["X"]), "I": jnp.asarray(model.params["I"])}
        self.names = _flat_names(start)
        lp = model.log_posterior_fn
        jitter = self.jitter

        def logp(x):
            return lp({**self.fixed, **self.unravel(x)}, jitter, which)

        self._logp = logp
        self.logp = jax.jit(logp)
        # one compiled value-and-gradient, shared by the conditional MAP and the Laplace step
        self._neg_vg = jax.jit(jax.value_and_grad(
            lambda x, j: -lp({**self.fixed, **self.unravel(x)}, j, which)))
        self.logp_batch = jax.jit(jax.vmap(logp))

    @property
    def ndim(self) -> int:
        return self.x0.size

    def full(self, x) -> dict:
        return {**{k: np.asarray(v) for k, v in self.fixed.items()},
                **{k: np.asarray(v) for k, v in self.unravel(jnp.asarray(x)).items()}}

    def conditional_map(self, max_iter=500, progress=False, start=None):
        """Maximise the sampled density with the latents fixed (the walkers' centre), from
        ``start`` (flat; default ``x0``)."""
        x = self.x0 if start is None else np.asarray(start, dtype=np.float64)
        start = {k: np.asarray(v) for k, v in self.unravel(jnp.asarray(x)).items()}
        params, diag = map_optimize(lambda p, j: self.model.log_posterior_fn(
            {**self.fixed, **p}, j), start, max_iter=max_iter, progress=progress,
            desc="conditional MAP", value_and_grad=self._neg_vg)
        x, _ = ravel_pytree({k: jnp.asarray(v) for k, v in params.items()})
        return np.asarray(x), diag

    def laplace(self, centre) -> np.ndarray:
        """Covariance of the Laplace approximation at ``centre``: the inverse Hessian of the
        negative log-density, by central differences of the JAX gradient (step 1e-4; compiling
        ``jax.hessian`` through the Cholesky factors took 15 s at N = 340, the differences 7 s).
        Directions where the Hessian is not positive definite (a saddle or a flat ridge) get the
        prior's variance, 9 in log units."""
        grad = lambda x: self._neg_vg(x, self.jitter)[1]
        h, n = 1e-4, centre.size
        H = np.empty((n, n))
        for i in range(n):
            e = np.zeros(n)
            e[i] = h
            H[:, i] = (np.asarray(grad(jnp.asarray(centre + e)))
                       - np.asarray(grad(jnp.asarray(centre - e)))) / (2 * h)
        if not np.all(np.isfinite(H)):
            raise BayesmotionError("the Hessian at the conditional MAP is not finite")
        return capped_covariance(H, 9.0)


def capped_covariance(H, max_var: float) -> np.ndarray:
    """The inverse of a negative-log-density Hessian ``H``, direction by direction: directions
    where ``H`` is not positive definite (a saddle, a flat ridge) or flatter than ``1/max_var``
    get the variance ``max_var``."""
    w, V = np.linalg.eigh(0.5 * (np.asarray(H) + np.asarray(H).T))
    var = np.where(w > 1.0 / max_var, 1.0 / np.maximum(w, 1e-300), max_var)
    return (V * var) @ V.T


def draw_start(logp_batch, centre, cov, n: int, rng) -> np.ndarray:
    """``n`` points from N(centre, cov); points whose density is not finite are redrawn closer
    to the centre (at 1/2, 1/4, 1/10 of the spread, then the centre itself).

    Args:
        logp_batch: (n, d) -> (n,) log-density, evaluated in half-ensemble chunks.
    """
    L = np.linalg.cholesky(cov + 1e-12 * np.eye(centre.size))
    p = centre + rng.standard_normal((n, centre.size)) @ L.T
    for shrink in (0.5, 0.25, 0.1, 0.0):
        bad = ~np.isfinite(_in_halves(logp_batch, p, n))
        if not bad.any():
            break
        p[bad] = centre + shrink * rng.standard_normal((bad.sum(), centre.size)) @ L.T
    return p


def _in_halves(batch_fn, xs, n_walkers: int) -> np.ndarray:
    """``batch_fn`` over rows of ``xs`` in chunks of ``n_walkers // 2`` (emcee's half-ensemble
    size), so the whole ensemble and its halves share one compilation."""
    h = max(n_walkers // 2, 1)
    return np.concatenate([np.asarray(batch_fn(jnp.asarray(xs[i:i + h])), dtype=np.float64)
                           for i in range(0, len(xs), h)])


def _start_points(target, centre, n, init, ball, rng, cov=None):
    """``n`` starting points: ``init="laplace"`` draws from the Laplace approximation (points
    whose density is not finite are redrawn closer to the centre; ``cov``: its covariance when
    already computed); ``"ball"`` a Gaussian ball of radius ``ball`` around ``centre``."""
    if init == "ball":
        return centre + ball * rng.standard_normal((n, centre.size))
    if init != "laplace":
        raise BayesmotionError(f"init must be 'laplace' or 'ball', got {init!r}")
    return draw_start(target.logp_batch, centre, target.laplace(centre) if cov is None else cov,
                      n, rng)


def _flat_names(params: dict) -> list[str]:
    names = []
    for k in sorted(params):  # ravel_pytree orders dict keys by sorted order
        v = np.asarray(params[k])
        names += [f"{k}[{', '.join(map(str, i))}]" for i in np.ndindex(v.shape)]
    return names


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
        info: tau, burn, thin, seconds, n_steps, warnings.
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
        vmapped = jax.jit(jax.vmap(lambda x: _constrain(self.target.unravel(x))))
        out = vmapped(jnp.asarray(self.flat()))
        return {k: np.asarray(v).reshape(C, D, *v.shape[1:]) for k, v in out.items()}

    def params(self, i: int) -> dict:
        """Full parameter dict (with the MAP latents) of flat draw ``i``."""
        return self.target.full(self.flat()[i])

    @property
    def idata(self):
        if self._idata is None:
            from .diagnostics import to_inference_data

            self._idata = to_inference_data(self)
        return self._idata

    def summary(self, **kwargs):
        """arviz summary (mean, sd, HDI, MCSE, bulk/tail ESS, R-hat) of constrained values."""
        import arviz as az

        from .diagnostics import arviz_without_numba

        with arviz_without_numba():
            return az.summary(self.idata, **kwargs)

    def plot_trace(self, var_names=None, **kwargs):
        import arviz as az

        return az.plot_trace(self.idata, var_names=var_names, **kwargs)

    def plot_pair(self, var_names=("gamma", "beta", "alpha"), **kwargs):
        import arviz as az

        return az.plot_pair(self.idata, var_names=list(var_names), **kwargs)

    def to_netcdf(self, path) -> str:
        from .diagnostics import save_netcdf

        return save_netcdf(self.idata, path)

    def predictor(self, i: int):
        """The model conditioned on draw i (cached)."""
        from .predict import condition

        if i not in self._predictors:
            self._predictors[i] = condition(self.model, self.params(i), self.target.jitter)
        return self._predictors[i]

    def generate(self, emotion="neutral", couple=None, n_frames=100, n_samples=0, start=None,
                 seed=0, n_draws: int = 16, **styles):
        """Posterior-predictive generation; see :func:`bayesmotion.ppc.generate_posterior`."""
        from .ppc import generate_posterior

        return generate_posterior(self, emotion, couple, n_frames, n_samples, start, seed,
                                  n_draws, **styles)


def _constrain(p: dict) -> dict:
    out = {k[4:]: jnp.exp(v) for k, v in p.items() if k.startswith("log_")}
    for k, v in p.items():
        if k.startswith(STYLE_PREFIX):
            out["style_" + k[len(STYLE_PREFIX):]] = style_to_simplex(v)  # (K, K)
    return out


# --------------------------------------------------------------------------- samplers
def sample_posterior(fitted, n_walkers: int | None = None, n_steps: int = 2000,
                     burn: int | None = None, thin: int | None = None, seed: int = 0,
                     backend=None, progress: bool = True, method: str = "emcee",
                     n_chains: int = 2, init: str = "laplace", ball: float = 1e-3,
                     moves=None, factorise: bool = False, gamma_every: int = 4,
                     hmc: bool = False, independence: bool | None = None) -> Posterior:
    """Sample the posterior over hyperparameters and training style vectors.

    Args:
        fitted: a FittedHGPDM.
        n_walkers: emcee walkers (default ``2 * ndim + 2``, even, ndim counting every
            sampled coordinate). When ``factorise``, both ensembles have this many walkers.
        n_steps: emcee steps per walker (NUTS: samples per chain after as many warm-up steps).
        burn, thin: discarded leading steps and thinning; by default chosen from the integrated
            autocorrelation time tau (burn = 2 max tau, thin = max(1, min tau / 2)). NUTS:
            ``burn`` is the number of warm-up (adaptation) steps, default ``n_steps``; 0 means
            no step-size or mass-matrix adaptation.
        seed: seeds the walker ball, the moves and NUTS.
        backend: path of an emcee HDF5 file. An existing file with the same dimensions is resumed
            from its last step until it holds ``n_steps`` steps (nothing already saved is lost).
            Other processes may read it meanwhile: a save waits for their lock
            (:mod:`bayesmotion.chainfile`).
        progress: progress bars.
        method: "emcee" or "nuts".
        n_chains: NUTS chains.
        init: where the walkers (NUTS: chains) start. ``"laplace"`` (default) draws them from
            the Laplace approximation at the conditional MAP (inverse Hessian), so the ensemble
            starts about as wide as the posterior: differential-evolution moves scale with the
            ensemble's spread, so a tight ball first spends many steps expanding (burn-in).
            ``"ball"``: a Gaussian ball of radius ``ball`` (unconstrained units).
        moves: emcee moves (default: ``emcee.moves.DEMove()``, mixing faster than the stretch
            move in tens of dimensions, each step followed by exact Metropolis steps along the
            style vectors' rotation orbits, where the likelihood is constant:
            :class:`bayesmotion.moves.StyleRotations`; then the independence step, see
            ``independence``). When ``factorise``, the moves of the
            (beta, alpha, styles) ensemble, whose coordinates are the target's without gamma's
            (``Target(fitted, block="upper")``); gamma's ensemble always uses DE.
        factorise: with the latents fixed the posterior factorises, p(gamma | Y, X)
            p(beta, alpha, S | X, I): gamma enters only the bottom layer, the most expensive
            one. ``True`` samples the factors with two independent ensembles, so the
            slow-mixing one (beta, alpha, styles) never evaluates the bottom layer, and updates
            gamma once every ``gamma_every`` steps; output step t pairs the two chains' walkers
            at steps t and t // gamma_every. ``False`` (default): one ensemble over every
            coordinate. At the demo size the factorised steps cost 0.31-0.34 s against 0.46 s,
            but two 7,000-step factorised chains mixed worse per step than the joint one (max
            R-hat 1.20 and 1.25, min bulk ESS 171 and 164, against 1.12 and 298), so the joint
            sampler stays the default.
        gamma_every: steps of the upper chain per step of the gamma chain.
        hmc: add, after the default moves, two ensemble-preconditioned HMC steps
            (:class:`bayesmotion.moves.EnsembleHMC`): one on the coordinates the style
            rotations do not move (the hyperparameters and two-level style vectors: nearly
            Gaussian but strongly correlated, where DE crawls, autocorrelation time ~300 steps
            at the demo size), one on the rotated style vectors (heavy-tailed: smaller steps).
            A step costs about 18x a DE step at the demo size (8.4 s against 0.46 s: about 4
            gradients per walker and block). In a 60-step demo-size probe (session 18) the
            hyperparameters reached R-hat 1.09-1.28 and bulk ESS 180-440 after 40 kept steps,
            which the default moves reach only after thousands; per second the slowest
            coordinate (an emotion style coordinate, R-hat 1.57, ESS 113) was no better than
            the default's at 1,000 steps. Not the default until a long run shows the gain.
        independence: add, after DE and the rotations, an independence Metropolis step
            (:class:`bayesmotion.moves.IndependenceMove`) on the coordinates the rotations do not
            move, plus the rotated ones the likelihood pins (Laplace sd < 0.1): a multivariate t (20
            degrees of freedom) proposal from the Laplace approximation at the conditional MAP for
            the first min(150, n_steps // 4) steps, then from the sample mean and covariance of that
            adaptation's last two thirds (every walker pooled). Each phase is a fixed kernel; the
            adaptation is part of the burn-in (``burn`` must cover it, as NUTS's warm-up), and a
            file resumed with ``backend`` switches where its first run did. One more log-density per
            walker and step (at the demo size 0.74 s per step against 0.46 s). ``None`` (default):
            on for the joint emcee sampler with the default moves, off otherwise; ``True`` with
            ``method="nuts"``, user ``moves`` or ``factorise`` raises. At the demo size (session 19,
            54 walkers, ``benchmarks/posterior_convergence.py``) 28% of the second phase's proposals
            were accepted, and 1,000 steps (743 s) gave max R-hat 1.067 and min bulk ESS 527, where
            DE and the rotations alone needed 7,000 steps (3,211 s) for 1.12 and 298; R-hat stayed
            at 1.07-1.09 up to 2,000 steps (walkers stuck on the couple style). Where a
            two-level style factor has a second local mode (its vectors near the simplex's
            centre, the factor idle; :func:`idle_factor_modes` searches for one per factor, at
            the cost of one more conditional MAP and Laplace approximation), the proposal is a
            mixture with one t per mode (weights from their Laplace evidence, each at least
            0.05; in the second phase each mode's moments come from the adaptation's states
            nearest it), so a walker jumps between the modes in one accepted step.

    Returns:
        a Posterior. A ``ChainTooShortWarning`` is issued when the chain is shorter than 50
        autocorrelation times.
    """
    if burn is not None and (burn < 0 or (method == "emcee" and burn >= n_steps)):
        # emcee discards burn of its n_steps; NUTS warms up for burn steps before n_steps draws
        raise BayesmotionError(f"burn must be in [0, n_steps = {n_steps}) for emcee and >= 0 "
                               f"for NUTS, got {burn}")
    if hmc and method != "emcee":
        raise BayesmotionError(f"hmc=True adds HMC steps to emcee's moves; method={method!r} "
                               f"does not use them (NUTS is already Hamiltonian)")
    if hmc and moves is not None:
        raise BayesmotionError("hmc=True adds EnsembleHMC to the default moves; with your own "
                               "moves, add bayesmotion.moves.EnsembleHMC to them instead")
    if independence and (method != "emcee" or moves is not None or factorise):
        raise BayesmotionError("independence=True adds steps to the joint emcee sampler's "
                               "default moves; it does not apply with method='nuts', your own "
                               "moves or factorise=True (add bayesmotion.moves.IndependenceMove "
                               "to your moves instead)")
    if independence is None:
        independence = method == "emcee" and moves is None and not factorise
    if independence and method == "emcee":
        n_adapt = _planned_adapt(backend, n_steps)
        if n_steps <= n_adapt:
            raise BayesmotionError(f"n_steps ({n_steps}) must exceed the {n_adapt} adaptation "
                                   f"steps of the run stored in {backend}")
        if burn is not None and burn < n_adapt:
            raise BayesmotionError(f"burn ({burn}) must cover the independence move's {n_adapt} "
                                   f"adaptation steps (as NUTS's warm-up); pass burn >= "
                                   f"{n_adapt}, or independence=False")
    if int(gamma_every) != gamma_every or gamma_every < 1:
        raise BayesmotionError(f"gamma_every must be a positive integer, got {gamma_every!r}")
    target = Target(fitted)
    centre, cdiag = target.conditional_map(progress=False)
    if method == "emcee" and factorise:
        post = _run_factorised(target, centre, n_walkers, n_steps, burn, thin, seed, backend,
                               progress, init, ball, moves, int(gamma_every), hmc)
    elif method == "emcee":
        post = _run_emcee(target, centre, n_walkers, n_steps, burn, thin, seed, backend,
                          progress, init, ball, moves, hmc, independence)
    elif method == "nuts":
        post = _run_nuts(target, centre, n_steps, burn, thin, seed, progress, n_chains, init,
                         ball)
    else:
        raise BayesmotionError(f"method must be 'emcee' or 'nuts', got {method!r}")
    post.info["conditional_map"] = {k: cdiag[k] for k in ("objective", "iterations", "converged")}
    return post


def _n_walkers(n_walkers, ndim) -> int:
    W = n_walkers or 2 * ndim + 2
    W += W % 2
    if W < 2 * ndim:
        raise BayesmotionError(f"emcee needs at least 2 * ndim = {2 * ndim} walkers, got {W}")
    return W


def _open_backend(backend, name, W, ndim, log_prob):
    """(emcee HDF5 backend or None, steps it already holds); a resumed file must hold a run of
    this shape and of this posterior."""
    if backend is None:
        return None, 0
    be = ChainFile(str(backend), name=name)
    if be.initialized and be.iteration > 0:
        if be.shape != (W, ndim):
            raise BayesmotionError(f"backend {backend} holds a run of shape {be.shape} in its "
                                   f"group {name!r}, this run needs {(W, ndim)}; use another "
                                   f"file (a file of the joint sampler resumes with "
                                   f"factorise=False)")
        _check_resumed_density(be, log_prob, backend)
        return be, be.iteration
    be.reset(W, ndim)
    return be, 0


def _rotated(moves) -> set[int]:
    """Flat indices the style rotations move (none when ``moves`` has no rotations)."""
    return ({int(i) for idx, _ in moves.blocks for i in idx}
            if isinstance(moves, StyleRotations) else set())


def _independence_block(target, cov) -> np.ndarray:
    """The coordinates the independence move draws: all but the rotated style coordinates,
    plus those of them the likelihood pins (Laplace sd < PINNED_SD)."""
    rotated = _rotated(_default_moves(target))
    sd = np.sqrt(np.diag(cov))
    return np.array([i for i in range(target.ndim) if i not in rotated or sd[i] < PINNED_SD],
                    dtype=int)


def idle_factor_modes(target, centre, cov, block) -> list[dict]:
    """Local modes of the sampled density beside the conditional MAP ``centre``: one search
    per style factor whose coordinates the independence move draws (those the rotations do not
    move: two-level factors), started from ``centre`` with that factor's style vectors at the
    simplex's centre, where the factor is idle and the output scales can take up its job.

    At the demo size the couple factor has such a mode 1.4 nats below the main one (Laplace
    evidence 1.2 nats lower, i.e. about a quarter of the mass), 4 posterior sd away in each
    couple coordinate, and DE walkers cross between the two in thousands of steps (session 21).

    Returns one dict per mode, the main one first: ``x`` (flat), ``cov`` (Laplace), ``logp``,
    ``log_evidence`` (logp + log det(cov) / 2) and ``weight`` (normalised evidence); a search
    that ends within 3 Laplace sd of a mode already found, or more than 20 nats of evidence below
    the main mode, adds nothing."""
    def evidence(lp, c):
        return lp + 0.5 * np.linalg.slogdet(c)[1]

    def logp(x):
        return float(np.asarray(target.logp_batch(jnp.asarray(x)[None]))[0])

    lp0 = logp(centre)
    modes = [{"x": centre, "cov": cov, "logp": lp0, "log_evidence": evidence(lp0, cov),
              "searched_from": None}]
    if not hasattr(target, "unravel"):
        return _weighted(modes)
    inside = set(np.asarray(block).tolist())
    for factor, idx in style_slices(target.unravel, target.x0).items():
        if not set(idx.tolist()) <= inside:
            continue
        K = int(round((1 + np.sqrt(1 + 4 * idx.size)) / 2))  # idx holds K (K - 1) entries
        start = np.array(centre, dtype=np.float64)
        start[idx] = np.asarray(simplex_to_style(np.full((K, K), 1.0 / K))).ravel()
        x, diag = target.conditional_map(start=start)
        if not diag.get("converged", True):
            continue
        lp = logp(x)
        c = target.laplace(x)
        ev = evidence(lp, c)
        b = np.asarray(block)
        far = all(np.sqrt(np.sum(np.linalg.solve(np.linalg.cholesky(m["cov"][np.ix_(b, b)]),
                                                 x[b] - m["x"][b]) ** 2)) > 3.0
                  for m in modes)
        if far and np.isfinite(ev) and ev > modes[0]["log_evidence"] - 20.0:
            modes.append({"x": x, "cov": c, "logp": lp, "log_evidence": ev,
                          "searched_from": factor})
    return _weighted(modes)


def _weighted(modes):
    ev = np.array([m["log_evidence"] for m in modes])
    w = np.exp(ev - ev.max())
    for m, wi in zip(modes, w / w.sum(), strict=True):
        m["weight"] = float(wi)
    return modes


def _mixture_proposal(block, modes, z=None):
    """(block, means, covs, weights) of the independence move: each mode's Laplace
    approximation; with ``z`` (adaptation states, block coordinates), each mode's sample
    moments over the states nearest it (Mahalanobis under its Laplace), where it has at least
    2 (d + 1) of them. Weights: the modes' Laplace evidence, at least 0.05 each."""
    means = np.array([m["x"][block] for m in modes])
    covs = np.array([m["cov"][np.ix_(block, block)] for m in modes])
    if z is not None:
        d2 = np.array([np.sum(np.linalg.solve(np.linalg.cholesky(c), (z - mu).T) ** 2, 0)
                       for mu, c in zip(means, covs, strict=True)])
        near = d2.argmin(0)
        for i in range(len(modes)):
            zi = z[near == i]
            if len(zi) >= 2 * (block.size + 1):
                means[i], covs[i] = zi.mean(0), _pooled_cov(zi)
    w = np.maximum([m["weight"] for m in modes], 0.05)
    if len(modes) == 1:
        return block, means[0], covs[0], None
    return block, means, covs, w / w.sum()


def _default_moves(target, hmc: bool = False, proposal=None):
    """DE, each step followed by the style rotations when the target samples style vectors;
    then, with ``proposal = (block, mean, cov[, weights])`` (a mixture when ``mean`` is 2-d),
    an independence step on that block
    (:class:`bayesmotion.moves.IndependenceMove`); then
    (``hmc``) ensemble-preconditioned HMC steps (:class:`bayesmotion.moves.EnsembleHMC`): one
    on the coordinates the rotations do not move, one on those they do.

    Not DESnookerMove: emcee 3.1.6's snooker move does not leave the target invariant (its
    projection divides by sqrt(|z - x|) instead of |z - x|); on 14 iid logit-Beta(11, 1)
    coordinates it returns sd 0.88 for an exact 1.32 (tests/test_posterior.py checks the default
    moves on that target)."""
    import emcee

    moves = emcee.moves.DEMove()
    slices = style_slices(target.unravel, target.x0) if hasattr(target, "unravel") else {}
    if slices:  # cross the style vectors' rotation ridges without GP evaluations
        conc = target.model.log_posterior_fn.style_prior.concentration
        moves = StyleRotations(moves, slices, conc)
    rotated = _rotated(moves)
    extra = []
    if proposal is not None:
        # the hyperparameters are nearly Gaussian, strongly correlated (DE crawls there: tau
        # ~300 steps at the demo size): an accepted independence proposal is a fresh draw
        block, mean, cov, *weights = proposal
        extra = [IndependenceMove(block, mean, cov, weights=weights[0] if weights else None)]
    if not (hmc and hasattr(target, "_logp")):
        return Sequence(moves, *extra) if extra else moves
    # the hyperparameters (and two-level styles) are nearly Gaussian but strongly correlated,
    # where DE crawls (tau ~300 steps at the demo size); the rotated styles are heavy-tailed,
    # so they get their own block, preconditioner and a smaller step
    block = [i for i in range(target.ndim) if i not in rotated]
    hmcs = [EnsembleHMC(target._logp, b, step_size=step, jitter=(0.2, 1.1), shrinkage=shrink)
            for b, step, shrink in ((block, 0.6, 0.05), (sorted(rotated), 0.5, 0.1)) if b]
    return Sequence(moves, *extra, *hmcs)


def _move_stats(moves) -> dict:
    """Acceptance of the style rotations, of the independence step and of the HMC blocks, in
    the order they run (None where absent)."""
    found = {}
    stack = [moves]
    while stack:
        m = stack.pop()
        if isinstance(m, Sequence):
            stack.extend(reversed(m.moves))  # popped in the order they run
        elif isinstance(m, StyleRotations):
            found["rotation_acceptance"] = m.acceptance
            stack.append(m.inner)
        elif isinstance(m, EnsembleHMC):
            found.setdefault("hmc", []).append(m.acceptance)
        elif isinstance(m, IndependenceMove):
            found["independence_acceptance"] = m.acceptance
    hmc = found.get("hmc")
    return {"rotation_acceptance": found.get("rotation_acceptance"),
            "independence_acceptance": found.get("independence_acceptance"),
            "hmc_acceptance": None if hmc is None else float(np.mean(hmc)),
            "hmc_block_acceptance": hmc}


def _phase_stats(ran) -> dict:
    """:func:`_move_stats` over the phases run, each acceptance weighted by its phase's steps
    (None where no phase ran or the move is absent)."""
    stats = [(_move_stats(m), n) for m, n in ran]
    out = {}
    for key in ("rotation_acceptance", "independence_acceptance", "hmc_acceptance"):
        vals = [(s[key], n) for s, n in stats if s[key] is not None and np.isfinite(s[key])]
        out[key] = (float(sum(v * n for v, n in vals) / sum(n for _, n in vals))
                    if vals else None)
    blocks = [(np.asarray(s["hmc_block_acceptance"]), n) for s, n in stats
              if s["hmc_block_acceptance"] is not None]
    out["hmc_block_acceptance"] = ([float(v) for v in sum(a * n for a, n in blocks)
                                    / sum(n for _, n in blocks)] if blocks else None)
    return out


def _initial_state(start, seed):
    import emcee

    # seeded: emcee keeps its generator state in the State (and the backend)
    return emcee.State(start, random_state=np.random.RandomState(seed).get_state())


def _finish(target, chain, lp, acceptance, burn, thin, info, min_burn: int = 0):
    """Burn-in and thinning from the integrated autocorrelation time of the whole chain; the
    burn-in covers at least ``min_burn`` steps (an adaptation)."""
    import emcee

    # a walker that never moved in some coordinate makes emcee's autocorrelation 0/0: that
    # coordinate's tau is then NaN, and _burn_thin reports the chain as too short
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.asarray(emcee.autocorr.integrated_time(chain, tol=0), dtype=float)
    bt = _burn_thin(tau, chain.shape[0], burn, thin, min_burn)
    sel = slice(bt["burn"], None, bt["thin"])
    return Posterior(target.model, target, np.swapaxes(chain[sel], 0, 1),
                     np.swapaxes(lp[sel], 0, 1), np.asarray(acceptance), "emcee",
                     {**bt, "tau": tau, "n_walkers": chain.shape[1], "n_steps": chain.shape[0],
                      **info})


def _adapt_steps(n_steps: int) -> int:
    return min(ADAPT_STEPS, n_steps // 4)


def _run_emcee(target, centre, n_walkers, n_steps, burn, thin, seed, backend, progress, init,
               ball, moves, hmc=False, independence=False):
    """One ensemble over every sampled coordinate. With ``independence``, in two phases: the
    adaptation (its independence proposal is the Laplace approximation) and the rest (the
    proposal is the adaptation's sample moments), each a fixed kernel; a resumed file continues
    in the phase where it stopped, the second phase's proposal recomputed from the file."""
    import emcee

    W = _n_walkers(n_walkers, target.ndim)

    def log_prob(xs):
        return _in_halves(target.logp_batch, xs, W)

    be, done = _open_backend(backend, "mcmc", W, target.ndim, log_prob)
    be = emcee.backends.Backend() if be is None else be  # shared by the phases
    cov, n_adapt = None, 0
    if backend is not None:
        n_adapt = _adapt_record(backend, done, _adapt_steps(n_steps) if independence else None)
    elif independence:
        n_adapt = _adapt_steps(n_steps)
    modes = None
    if independence:
        cov = target.laplace(centre)
        block = _independence_block(target, cov)
        modes = idle_factor_modes(target, centre, cov, block)

        def phase_moves(first: bool):
            if first:
                return _default_moves(target, hmc, _mixture_proposal(block, modes))
            z = be.get_chain()[n_adapt // 3:n_adapt][..., block].reshape(-1, block.size)
            return _default_moves(target, hmc, _mixture_proposal(block, modes, z))

        # (a resumed file's stored adaptation may be longer than this call's n_steps)
        phases = ([(min(n_adapt, n_steps), True), (n_steps, False)] if n_adapt
                  else [(n_steps, True)])
    else:
        phases = [(n_steps, None)]

        def phase_moves(_):
            return _default_moves(target, hmc) if moves is None else moves

    t0 = time.perf_counter()
    ran = []  # (moves, steps) of each phase run by this call
    for end, which in phases:
        if done >= end:
            continue
        used = phase_moves(which)
        ran.append((used, end - done))
        sampler = emcee.EnsembleSampler(W, target.ndim, log_prob, vectorize=True, backend=be,
                                        moves=used)
        if done:
            sampler.run_mcmc(None, end - done, progress=progress)
        else:
            start = _start_points(target, centre, W, init, ball, np.random.default_rng(seed),
                                  cov)
            sampler.run_mcmc(_initial_state(start, seed), end, progress=progress)
        done = end
    seconds = time.perf_counter() - t0
    info = {"seconds": seconds, "factorised": False, **_phase_stats(ran)}
    if independence:
        info["adapt_steps"] = n_adapt
        info["modes"] = [{"weight": m["weight"], "logp": m["logp"],
                          "log_evidence": m["log_evidence"], "searched_from": m["searched_from"],
                          "x": m["x"].tolist()} for m in modes]
    return _finish(target, be.get_chain(), be.get_log_prob(), be.accepted / max(be.iteration, 1),
                   burn, thin, info, min_burn=n_adapt)


ADAPT_ATTR = "bayesmotion_adapt_steps"


def _adapt_record(backend, done: int, n_adapt: int | None) -> int:
    """The adaptation length a backend file's run uses, stored with its chain (so a run resumed
    with another ``n_steps`` switches proposals where the first did); ``None``: this run uses no
    independence move. A resumed file must have been written with the same choice."""
    with open_h5(backend, "r") as f:
        attrs = f["mcmc"].attrs
        stored = int(attrs[ADAPT_ATTR]) if ADAPT_ATTR in attrs else None
    if done and (stored is None) != (n_adapt is None):
        flag = "False (CLI: --no-independence)" if stored is None else "True (the default)"
        raise BayesmotionError(
            f"backend {backend} was written {'without' if stored is None else 'with'} the "
            f"independence move (files written before it existed have none); resume it with "
            f"independence={flag}")
    if n_adapt is None:
        return 0
    if done:
        return stored
    with open_h5(backend, "a") as f:
        f["mcmc"].attrs[ADAPT_ATTR] = n_adapt
    return n_adapt


def _planned_adapt(backend, n_steps: int) -> int:
    """The adaptation length a run will use: a resumed file's, else this run's."""
    if backend is not None and os.path.exists(str(backend)):
        with open_h5(backend, "r") as f:  # waits for a reader's lock; names a foreign file
            attrs = f["mcmc"].attrs if "mcmc" in f else {}
            if ADAPT_ATTR in attrs and int(attrs.get("iteration", 0)) > 0:
                return int(attrs[ADAPT_ATTR])
    return _adapt_steps(n_steps)


def _pooled_cov(z) -> np.ndarray:
    """Sample covariance of the rows of ``z``, with a ridge of 1e-10 of its diagonal."""
    c = np.atleast_2d(np.cov(z.T))
    c[np.diag_indices_from(c)] += 1e-10 * np.maximum(np.diag(c), 1e-300)
    return c


def _run_factorised(target, centre, n_walkers, n_steps, burn, thin, seed, backend, progress,
                    init, ball, moves, gamma_every, hmc=False):
    """Two independent ensembles, one per factor of p(gamma | Y, X) p(beta, alpha, S | X, I).

    The upper ensemble (beta, alpha, styles) takes ``n_steps`` steps and never evaluates the
    bottom layer; the bottom ensemble (gamma, 3 coordinates) takes one step for every
    ``gamma_every`` of them. Output step t pairs upper step t with bottom step
    ``t // gamma_every``, walker by walker. As the factors are independent, this is the chain
    of a valid composite kernel on the joint posterior (the gamma update is applied every
    ``gamma_every`` steps): its draws, autocorrelation times and diagnostics are those of the
    joint chain, with gamma's held values counted as the repeats they are.
    """
    import emcee

    model = target.model
    up = Target(model, target.jitter, "upper")
    bot = Target(model, target.jitter, "bottom")
    iu = np.array([target.names.index(n) for n in up.names])
    ib = np.array([target.names.index(n) for n in bot.names])
    # as many walkers as the joint sampler by default (the demo-size runs used 48 and 54)
    W = _n_walkers(n_walkers or 2 * target.ndim + 2, up.ndim)

    def lp_up(xs):
        return _in_halves(up.logp_batch, xs, W)

    def lp_bot(xs):
        return _in_halves(bot.logp_batch, xs, W)

    be_up, done_up = _open_backend(backend, "mcmc", W, up.ndim, lp_up)
    be_bot, done_bot = _open_backend(backend, "gamma", W, bot.ndim, lp_bot)
    n_steps = max(n_steps, done_up)  # a file holding more steps returns them all (as joint)
    n_bot = -(-n_steps // gamma_every)
    moves_up = _default_moves(up, hmc) if moves is None else moves
    moves_bot = _default_moves(bot, hmc=False)  # DE: gamma has no style coordinates
    s_up = emcee.EnsembleSampler(W, up.ndim, lp_up, vectorize=True, backend=be_up,
                                 moves=moves_up)
    s_bot = emcee.EnsembleSampler(W, bot.ndim, lp_bot, vectorize=True, backend=be_bot,
                                  moves=moves_bot)
    start = None
    if not (done_up and done_bot):
        start = _start_points(target, centre, W, init, ball, np.random.default_rng(seed))
    init_up = s_up._previous_state if done_up else _initial_state(start[:, iu], seed)
    init_bot = s_bot._previous_state if done_bot else _initial_state(start[:, ib], seed + 1)
    t0 = time.perf_counter()
    gen_up = s_up.sample(init_up, iterations=max(0, n_steps - done_up), progress=progress)
    gen_bot = s_bot.sample(init_bot, iterations=max(0, n_bot - done_bot))
    for t in range(done_up, n_steps):  # interleaved, so a killed run leaves both files current
        next(gen_up)
        while done_bot < min(n_bot, t // gamma_every + 1):
            next(gen_bot)
            done_bot += 1
    for _ in gen_bot:  # the bottom steps still missing when the upper chain was complete
        pass
    for _ in gen_up:  # close the generators (each saves a step before it yields it)
        pass
    seconds = time.perf_counter() - t0
    c_up, c_bot = s_up.get_chain()[:n_steps], s_bot.get_chain()[:n_bot]
    l_up, l_bot = s_up.get_log_prob()[:n_steps], s_bot.get_log_prob()[:n_bot]
    held = np.arange(n_steps) // gamma_every
    chain = np.empty((n_steps, W, target.ndim))
    chain[..., iu], chain[..., ib] = c_up, c_bot[held]
    return _finish(target, chain, l_up + l_bot[held], s_up.acceptance_fraction, burn, thin,
                   {"seconds": seconds, "factorised": True, "gamma_every": gamma_every,
                    "bottom_acceptance": np.asarray(s_bot.acceptance_fraction),
                    **_move_stats(moves_up)})


def _check_resumed_density(be, log_prob, backend) -> None:
    """A resumed run continues from the log-densities stored with its last step; they must be
    this posterior's. Recomputed at the stored walkers, they differ (by hundreds of nats) when
    the file was written for another model, e.g. a refit of the same size; the style rotations
    carry the stored values forward by increments, hence the small tolerance."""
    last = be.get_last_sample()
    fresh = log_prob(np.asarray(last.coords))
    stored = np.asarray(last.log_prob, dtype=np.float64)
    if not np.allclose(fresh, stored, rtol=1e-7, atol=1e-6, equal_nan=True):
        worst = float(np.nanmax(np.abs(fresh - stored)))
        raise BayesmotionError(f"backend {backend} holds a run of another posterior: its stored "
                               f"log-densities differ from this model's by up to {worst:.3g} "
                               f"nats at the same walkers; use another file")


def _burn_thin(tau, n_steps, burn, thin, min_burn: int = 0):
    info = {}
    tmax = float(np.nanmax(tau)) if np.all(np.isfinite(tau)) else float("inf")
    if n_steps < 50 * tmax:
        msg = (f"chain of {n_steps} steps is shorter than 50 autocorrelation times "
               f"(max tau ~ {tmax:.0f}): the estimates are unreliable; run longer")
        warnings.warn(msg, ChainTooShortWarning, stacklevel=3)
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


def _run_nuts(target, centre, n_steps, burn, thin, seed, progress, n_chains, init, ball):
    from numpyro.infer import MCMC, NUTS

    warm = n_steps if burn is None else burn
    kernel = NUTS(potential_fn=lambda x: -target._logp(x))
    mcmc = MCMC(kernel, num_warmup=warm, num_samples=n_steps, num_chains=n_chains,
                thinning=thin or 1, progress_bar=progress, chain_method="sequential")
    rng = np.random.default_rng(seed)
    init = jnp.asarray(_start_points(target, centre, n_chains, init, ball, rng))
    t0 = time.perf_counter()
    mcmc.run(jax.random.PRNGKey(seed), init_params=init, extra_fields=("accept_prob",
                                                                        "potential_energy"))
    seconds = time.perf_counter() - t0
    x = np.asarray(mcmc.get_samples(group_by_chain=True))
    ex = mcmc.get_extra_fields(group_by_chain=True)
    return Posterior(target.model, target, x, -np.asarray(ex["potential_energy"]),
                     np.asarray(ex["accept_prob"]).mean(1), "nuts",
                     {"burn": warm, "thin": thin or 1, "seconds": seconds, "n_steps": n_steps,
                      "n_chains": n_chains})
