"""Differential-evolution ensemble MCMC in pure JAX: the whole run is one ``lax.scan``.

The move is emcee's ``DEMove`` (ter Braak 2006, as implemented by Nelson et al. 2013) with
emcee's red-blue updating: each step the W walkers are split at random into two halves; each
walker of the first half proposes q = x + gamma (c_b - c_a), with (a, b) an ordered pair of
distinct walkers drawn uniformly from the other half and gamma = gamma0 (1 + sigma N(0, 1)),
gamma0 = 2.38 / sqrt(2 d); it moves to q with probability min(1, p(q) / p(x)); then the
second half does the same against the updated first. The proposal is symmetric, so no
Hastings factor. Same distribution of chains as ``emcee.EnsembleSampler(moves=DEMove())``,
not the same random numbers.

Why: emcee calls the log-density from the host once per half-step, so a run of n steps is 2 n
host round trips; on a GPU each one costs a dispatch and a transfer, which dominate when the
density is cheap (the style posterior of :func:`bayesmotion.emotion.infer.infer_emotion`).
Here the run is one compiled program; ``log_prob`` must be a pure JAX function of a batch of
points, (n, d) -> (n,).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.target import in_halves


class EnsembleRun(NamedTuple):
    chain: jnp.ndarray  # (n_steps, W, d) positions after each step
    log_prob: jnp.ndarray  # (n_steps, W)
    accepted: jnp.ndarray  # (W,) accepted proposals per walker


def _half_update(log_prob, x, lp, key, move, keep, g0, sigma):
    """Walkers ``move`` (indices, W/2) propose against walkers ``keep`` (the other half)."""
    k_a, k_b, k_g, k_u = jax.random.split(key, 4)
    n = move.shape[0]
    nc = keep.shape[0]
    a = jax.random.randint(k_a, (n,), 0, nc)
    b = jax.random.randint(k_b, (n,), 0, nc - 1)
    b = b + (b >= a)  # uniform over the ordered pairs a != b
    c = x[keep]
    gamma = g0 * (1.0 + sigma * jax.random.normal(k_g, (n, 1), x.dtype))
    q = x[move] + gamma * (c[b] - c[a])
    lq = log_prob(q)
    # NaN or -inf at q never moves a walker (the comparison is False)
    ok = lq - lp[move] > jnp.log(jax.random.uniform(k_u, (n,), x.dtype))
    x = x.at[move].set(jnp.where(ok[:, None], q, x[move]))
    lp = lp.at[move].set(jnp.where(ok, lq, lp[move]))
    return x, lp, ok


@partial(jax.jit, static_argnames=("log_prob", "n_steps", "static"))
def _run(log_prob, args, x0, lp0, key, n_steps: int, g0, sigma, static=()):
    kw = dict(static)
    f = lambda q: log_prob(q, *args, **kw)
    W = x0.shape[0]
    h = W // 2

    def step(carry, k):
        x, lp, acc = carry
        k_p, k_0, k_1 = jax.random.split(k, 3)
        perm = jax.random.permutation(k_p, W)
        first, second = perm[:h], perm[h:]
        x, lp, ok0 = _half_update(f, x, lp, k_0, first, second, g0, sigma)
        x, lp, ok1 = _half_update(f, x, lp, k_1, second, first, g0, sigma)
        acc = acc.at[first].add(ok0.astype(acc.dtype)).at[second].add(ok1.astype(acc.dtype))
        return (x, lp, acc), (x, lp)

    (_, _, acc), (chain, lps) = jax.lax.scan(
        step, (x0, lp0, jnp.zeros(W, jnp.int32)), jax.random.split(key, n_steps))
    return EnsembleRun(chain, lps, acc)


def run_de(log_prob, args: tuple, p0, n_steps: int, seed: int = 0, *, static: tuple = (),
           gamma0: float | None = None, sigma: float = 1.0e-5) -> EnsembleRun:
    """``n_steps`` DE ensemble steps from the walkers ``p0`` (W, d), in one compiled call.

    Args:
        log_prob: a pure JAX function ``log_prob(points, *args, **dict(static))`` -> (n,) for
            points (n, d); hashable (a module-level function), as it is a static argument.
        args: its array arguments (traced: a new clip reuses the compiled program).
        p0: (W, d) starting walkers, W even and at least 2 d + 2 (emcee's rule of thumb,
            otherwise the ensemble cannot span the space); their densities must be finite.
        n_steps: steps; the chain holds every step (no burn-in dropped, no thinning).
        seed: seeds the moves.
        static: hashable keyword arguments of ``log_prob`` as (name, value) pairs.
        gamma0: the move's scale (default 2.38 / sqrt(2 d), emcee's).
        sigma: the scale's relative jitter (emcee's default).
    Returns:
        EnsembleRun: chain (n_steps, W, d), log_prob (n_steps, W), accepted (W,).
    """
    p0 = jnp.asarray(p0)
    if p0.ndim != 2:
        raise BayesmotionError(f"p0 must be (walkers, dimensions), got shape {p0.shape}")
    W, d = p0.shape
    if W % 2 or W < 2 * d + 2:
        raise BayesmotionError(f"the DE ensemble needs an even number of walkers >= 2 d + 2 = "
                               f"{2 * d + 2}, got {W}")
    if isinstance(n_steps, bool) or not isinstance(n_steps, int | np.integer) or n_steps < 1:
        raise BayesmotionError(f"n_steps must be a positive integer, got {n_steps!r}")
    kw = dict(static)
    # in the half-ensembles the moves evaluate, as draw_start does: one compilation
    lp0 = jnp.asarray(in_halves(lambda x: log_prob(x, *args, **kw), np.asarray(p0), W),
                      dtype=p0.dtype)
    if not bool(jnp.all(jnp.isfinite(lp0))):
        raise BayesmotionError("every starting walker needs a finite log-density; "
                               f"{int(jnp.sum(~jnp.isfinite(lp0)))} of {W} have none")
    g0 = 2.38 / np.sqrt(2 * d) if gamma0 is None else float(gamma0)
    return _run(log_prob, tuple(args), p0, lp0, jax.random.PRNGKey(seed), int(n_steps),
                jnp.asarray(g0, p0.dtype), jnp.asarray(sigma, p0.dtype), tuple(static))
