"""The sampled density: the log-posterior over hyperparameters and training style vectors
with the latents at their MAP, as one flat vector (:class:`Target`), and where walkers start."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from bayesmotion.errors import BayesmotionError
from bayesmotion.gp.batch import over_points
from bayesmotion.model.logpost import LAYERS
from bayesmotion.model.params import (
    AR_KEY,
    LATENT_KEYS,
    STYLE_PREFIX,
    simplex_to_style,
    style_to_simplex,
)
from bayesmotion.optim.minimize import map_optimize

SAMPLED_HYPER = ("log_gamma", "log_beta", "log_alpha", AR_KEY)  # those the model has


# With the latents fixed the posterior factorises: p(gamma | Y, X) p(beta, alpha, S | X, I).
# block -> the layers whose likelihood it needs. "bottom" samples BOTTOM_KEYS, "upper" the rest.
BOTTOM_KEYS = ("log_gamma",)


BLOCKS = {"bottom": ("bottom",), "upper": ("interaction", "dynamics"), "hyper": LAYERS}
"""block -> the layers its density needs. "bottom": gamma, p(gamma | Y, X); "upper": the rest,
p(beta, alpha, S | X, I); "hyper": the hyperparameters (gamma, beta, alpha, the AR
coefficients) with the style vectors held at the model's (one-hot where the MAP kept them so),
p(gamma, beta, alpha, a | S, X, I)."""


def sampled_start(model) -> dict:
    """Initial sampled parameters: MAP hyperparameters, style vectors from the model (or each
    level's Dirichlet prior mean when the MAP kept them one-hot). Factors with a single level
    have nothing to sample and stay fixed."""
    p = {k: np.asarray(model.params[k]) for k in SAMPLED_HYPER if k in model.params}
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
    ``logp(x)`` (jitted), ``logp_batch(xs)`` (jitted, over a batch of walkers:
    :func:`bayesmotion.gp.batch.over_points`) and ``full(x)`` (the
    complete parameter dict with the fixed latents).
    """

    def __init__(self, model, jitter: float | None = None, block: str | None = None):
        self.model = model
        self.jitter = model.diagnostics.get("jitter", 1e-8) if jitter is None else jitter
        start = sampled_start(model)
        # the latents (and a sparse model's inducing inputs) stay at the MAP
        self.fixed = {k: jnp.asarray(model.params[k]) for k in LATENT_KEYS if k in model.params}
        self.block = block
        if block is not None:
            if block not in BLOCKS:
                raise BayesmotionError(f"block must be one of {sorted(BLOCKS)}, got {block!r}")
            if block == "hyper":  # the model's own style vectors (one-hot where it has none)
                self.fixed.update({k: jnp.asarray(v) for k, v in model.params.items()
                                   if k.startswith(STYLE_PREFIX)})
                start = {k: v for k, v in start.items() if not k.startswith(STYLE_PREFIX)}
            else:
                start = {k: v for k, v in start.items()
                         if (k in BOTTOM_KEYS) == (block == "bottom")}
        which = LAYERS if block is None else BLOCKS[block]
        x0, self.unravel = ravel_pytree({k: jnp.asarray(v) for k, v in start.items()})
        self.x0 = np.asarray(x0)
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
        # on a CPU in chunks of walkers, one after another: a whole vmapped half-ensemble of
        # N x N factorisations leaves the caches (bayesmotion.gp.batch)
        self.logp_batch = jax.jit(over_points(logp))

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
        negative log-density, by central differences of the JAX gradient (step 1e-4: one
        compiled gradient instead of ``jax.hessian`` through the Cholesky factors).
        Directions where the Hessian is not positive definite (a saddle or a flat ridge) get the
        prior's variance, 9 in log units."""
        H = difference_hessian(lambda x: self._neg_vg(jnp.asarray(x), self.jitter)[1], centre)
        if not np.all(np.isfinite(H)):
            raise BayesmotionError("the Hessian at the conditional MAP is not finite")
        return capped_covariance(H, 9.0)


def difference_hessian(grad, x, h: float = 1e-4) -> np.ndarray:
    """(n, n) Hessian at ``x`` (n,) by central differences of ``grad`` (x -> (n,) gradient),
    step ``h``: column i is (grad(x + h e_i) - grad(x - h e_i)) / 2h. With ``grad`` an already
    compiled gradient this costs 2 n calls and no compilation, where ``jax.hessian`` compiles a
    program of its own."""
    x = np.asarray(x, dtype=np.float64)
    n = x.size
    H = np.empty((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        H[:, i] = (np.asarray(grad(x + e), dtype=np.float64)
                   - np.asarray(grad(x - e), dtype=np.float64)) / (2 * h)
    return H


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
        bad = ~np.isfinite(in_halves(logp_batch, p, n))
        if not bad.any():
            break
        p[bad] = centre + shrink * rng.standard_normal((bad.sum(), centre.size)) @ L.T
    return p


def in_halves(batch_fn, xs, n_walkers: int) -> np.ndarray:
    """``batch_fn`` over rows of ``xs`` in chunks of ``n_walkers // 2`` (emcee's half-ensemble
    size), so the whole ensemble and its halves share one compilation."""
    h = max(n_walkers // 2, 1)
    return np.concatenate([np.asarray(batch_fn(jnp.asarray(xs[i:i + h])), dtype=np.float64)
                           for i in range(0, len(xs), h)])


def start_points(target, centre, n, init, ball, rng, cov=None):
    """``n`` starting points: ``init="laplace"`` draws from the Laplace approximation (points
    whose density is not finite are redrawn closer to the centre; ``cov``: its covariance when
    already computed); ``"ball"`` a Gaussian ball of radius ``ball`` around ``centre``."""
    if init == "ball":
        return centre + ball * rng.standard_normal((n, centre.size))
    if init != "laplace":
        raise BayesmotionError(f"init must be 'laplace' or 'ball', got {init!r}")
    return draw_start(target.logp_batch, centre, target.laplace(centre) if cov is None else cov,
                      n, rng)


def style_grams(target, xs) -> dict[str, np.ndarray]:
    """factor -> (n, K, K) Gram matrices ``S S^T`` of each sampled factor's level vectors
    (rows of ``S`` on the simplex) at the flat draws ``xs`` (n, ndim): all the likelihood sees
    of the style vectors. The style rotations move the vectors along the orbits that keep it,
    so the vectors' own coordinates can mix fast while the Gram, which carries the emotions'
    likeness to each other, mixes slowly; its entries are the style vectors' identified
    quantities. Empty for a target without style vectors."""
    xs = np.asarray(xs, dtype=np.float64).reshape(-1, target.ndim)
    keys = [k for k in target.unravel(jnp.asarray(target.x0)) if k.startswith(STYLE_PREFIX)]
    if not keys:
        return {}
    fn = _GRAM_FNS.get(id(target))
    if fn is None or fn[0] is not target:

        def grams(x):
            p = target.unravel(x)
            out = {}
            for k in keys:
                S = style_to_simplex(p[k])
                out[k[len(STYLE_PREFIX):]] = S @ S.T
            return out

        fn = (target, jax.jit(jax.vmap(grams)))  # compiled once per target and chunk shape
        _GRAM_FNS.clear()  # one target at a time: a run's diagnostics
        _GRAM_FNS[id(target)] = fn
    rows = xs if len(xs) else np.asarray(target.x0, dtype=np.float64)[None]
    parts = [fn[1](jnp.asarray(rows[i:i + GRAM_CHUNK]))
             for i in range(0, len(rows), GRAM_CHUNK)]
    return {f: np.concatenate([np.asarray(p[f]) for p in parts])[:len(xs)] for f in parts[0]}


GRAM_CHUNK = 8192
"""Draws per call of the compiled Gram map in :func:`style_grams` (bounded memory on long
chains)."""
_GRAM_FNS: dict = {}


def gram_entries(target, xs) -> tuple[list[str], np.ndarray]:
    """(names, (n, m) values) of the Gram entries ``G_ij``, i <= j, of every sampled style factor
    (:func:`style_grams`) at the flat draws ``xs``; names as ``gram:emotion[happy, sad]``."""
    names, cols = [], []
    for f, G in style_grams(target, xs).items():
        # a stand-in target (tests) may have no model levels: the levels' indices then
        levels = list(getattr(getattr(target, "model", None), "levels", {}).get(
            f, range(G.shape[-1])))
        for i, j in zip(*np.triu_indices(G.shape[-1]), strict=True):
            names.append(f"gram:{f}[{levels[i]}, {levels[j]}]")
            cols.append(G[:, i, j])
    n = np.asarray(xs).reshape(-1, target.ndim).shape[0]
    return names, (np.stack(cols, -1) if cols else np.empty((n, 0)))


def chain_gram(target, chain) -> tuple[list[str], np.ndarray]:
    """(names, (steps, walkers, m)) Gram entries (:func:`gram_entries`) along a raw chain."""
    names, g = gram_entries(target, np.asarray(chain).reshape(-1, target.ndim))
    return names, g.reshape(*np.shape(chain)[:2], -1)


def _flat_names(params: dict) -> list[str]:
    names = []
    for k in sorted(params):  # ravel_pytree orders dict keys by sorted order
        v = np.asarray(params[k])
        names += [f"{k}[{', '.join(map(str, i))}]" for i in np.ndindex(v.shape)]
    return names
