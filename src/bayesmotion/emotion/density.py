"""Predictive log-density of an observed clip under a conditioned model (pure JAX).

For a clip with poses Y*_a (per actor), latents X*_a, I* and style vectors s* (one per factor):

    log p(Y*, X*, I* | s*, training data)
      = sum_a sum_t log N(Y*_a,t | mu_Y(X*_a,t), (sigma_Y^2 + 1/gamma3) I)        bottom
      + sum_t log N([X*_1,t X*_2,t] | mu_X(I*_t, s*), (sigma_X^2 + 1/beta3) I)  interaction
      + sum_{t>o} log N(I*_t | mu_I(I*_{t-1..t-o}, s*), (sigma_I^2 + 1/alpha_noise) I)
      + sum_{t<=o} log N(I*_t | 0, v0 I)                                          dynamics

with every mu / sigma^2 the GP predictive of the fitted layer (bayesmotion.model.predict). Arrays
are
padded to a frame bucket; ``mask`` marks real frames (padding contributes exactly 0), so clips of
many lengths share one compiled function.
"""

from __future__ import annotations

import itertools
from typing import NamedTuple

import jax.numpy as jnp

from bayesmotion.gp import kernels
from bayesmotion.gp.densities import LOG_2PI
from bayesmotion.model.layers import ar_mean, restart_log_prior
from bayesmotion.model.params import STYLE_PREFIX, style_log_prior, style_to_simplex
from bayesmotion.model.predict import (
    LayerFit,
    Predictor,
    noise_variances,
    predict_bottom,
    predict_dynamics,
    predict_interaction,
    whiten,
)


def _normal(x, mean, var):
    """Sum over the last axis of log N(x | mean, var) with var broadcast per row. -> (B,)"""
    D = x.shape[-1]
    return -0.5 * (jnp.sum((x - mean) ** 2, -1) / var + D * (LOG_2PI + jnp.log(var)))


def styles_from(params: dict, fixed: dict, factors, vectors: dict) -> list[jnp.ndarray]:
    """Per factor (K_f,) style vector: a free one's coordinates ``params["style:<f>"]`` (on the
    simplex) times its level vectors, else the fixed vector."""
    return [style_to_simplex(params[STYLE_PREFIX + f][None])[0] @ vectors[f]
            if (STYLE_PREFIX + f) in params
            else jnp.asarray(fixed[f]) for f in factors]


def _bottom_term(P: Predictor, X, Ys, m):
    noise = noise_variances(P)["Y"]
    bottom = 0.0
    for a, Y in enumerate(Ys):
        mu, var = predict_bottom(P, a, X[a])
        bottom = bottom + jnp.sum(m * _normal(Y, mu, var + noise))
    return bottom


def clip_terms(P: Predictor, params: dict, Ys, mask, fixed: dict, int_factors, dyn_factors,
               init_var: float):
    """The three layer terms of the clip's log-density (scalars)."""
    X, I = params["X"], params["I"]
    B = I.shape[0]
    m = mask.astype(I.dtype)
    noise = noise_variances(P)
    bottom = _bottom_term(P, X, Ys, m)
    s_int = [jnp.broadcast_to(s, (B, s.shape[0]))
             for s in styles_from(params, fixed, int_factors, P.level_vectors)]
    mu, var = predict_interaction(P, I, s_int)
    Z = jnp.concatenate([X[a] for a in range(X.shape[0])], axis=1)
    inter = jnp.sum(m * _normal(Z, mu, var + noise["X"]))
    o = P.dyn_lags.shape[0]
    lags = jnp.stack([I[o - l:B - l] for l in range(1, o + 1)])
    s_dyn = [jnp.broadcast_to(s, (B - o, s.shape[0]))
             for s in styles_from(params, fixed, dyn_factors, P.level_vectors)]
    mu, var = predict_dynamics(P, lags, s_dyn)
    dyn = jnp.sum(m[o:] * _normal(I[o:], mu, var + noise["I"])) + restart_log_prior(I[:o], init_var)
    return bottom, inter, dyn


def clip_log_density(P, params, Ys, mask, fixed, concentration, int_factors, dyn_factors,
                     init_var):
    b, i, d = clip_terms(P, params, Ys, mask, fixed, int_factors, dyn_factors, init_var)
    total = b + i + d + style_log_prior(params, concentration)
    return jnp.where(jnp.isnan(total), -jnp.inf, total)


class _Expanded(NamedTuple):
    """One layer's clip-frame predictive as a function of the free styles' coefficients c."""

    outputs: jnp.ndarray  # (B', D) what the layer predicts (X concat, or I_t)
    G: jnp.ndarray  # (P, B', D)
    H: jnp.ndarray  # (B', P, P)
    base: jnp.ndarray  # (B',) prior variance with every free style of unit norm
    noise: jnp.ndarray
    weight: jnp.ndarray  # (B',) mask


class StyleExpansion(NamedTuple):
    """Everything :func:`expanded_log_density` needs: a pytree (jit/vmap friendly)."""

    const: jnp.ndarray  # bottom term + the dynamics prior of the first frames
    inter: _Expanded
    dyn: _Expanded
    vectors: dict  # free factor -> (K_f, K_f) level vectors


def _combos(factors, free: dict):
    """One-hot style combinations of the free factors among ``factors`` (itertools order)."""
    names = [f for f in factors if f in free]
    return names, list(itertools.product(*[range(free[f]) for f in names]))


def _expand(kernel_at, fit: LayerFit, factors, free: dict, fixed: dict, n: int, vectors: dict):
    """Cross-covariances at every combination of the free factors' level vectors: the clip's
    style vector w @ V is linear in its coordinates w, so its kernel rows are sums over these."""
    names, combos = _combos(factors, free)
    kx = []
    for combo in combos:
        styles = [vectors[f][combo[names.index(f)]] if f in free else jnp.asarray(fixed[f])
                  for f in factors]
        kx.append(kernel_at([jnp.broadcast_to(v, (n, v.shape[0])) for v in styles]))
    kx = jnp.stack(kx)  # (P, M, n)
    P, M, _ = kx.shape
    G = jnp.einsum("pmn,md->pnd", kx, fit.A)
    V = whiten(fit, jnp.moveaxis(kx, 0, 1).reshape(M, P * n))
    V = V.reshape(-1, P, n)
    return G, jnp.einsum("mpn,mqn->npq", V, V)


def style_expansion(P: Predictor, params: dict, Ys, mask, fixed: dict, free: dict,
                    int_factors, dyn_factors, init_var: float) -> StyleExpansion:
    """Precompute the clip's density as a function of its free styles, latents held fixed.

    Args:
        params: {"X", "I"} the clip's latents (padded).
        free: {factor: K_f} the styles left free (sampled).
        fixed: the other factors' style vectors.
    """
    X, I = params["X"], params["I"]
    B = I.shape[0]
    m = mask.astype(I.dtype)
    noise = noise_variances(P)
    unit = lambda factors, n: [jnp.broadcast_to(
        jnp.eye(free[f])[0] if f in free else jnp.asarray(fixed[f]),
        (n, free[f] if f in free else len(fixed[f]))) for f in factors]
    Z = jnp.concatenate([X[a] for a in range(X.shape[0])], axis=1)
    G, H = _expand(lambda S: kernels.interaction_kernel(P.I, I, list(P.int_style), S, P.beta),
                   P.inter, int_factors, free, fixed, B, P.level_vectors)
    base = jnp.ones(B)
    for s in unit(int_factors, B):
        base = base * jnp.sum(s * s, -1)
    inter = _Expanded(Z, G, H, base * P.beta[0], noise["X"], m)
    o = P.dyn_lags.shape[0]
    lags = jnp.stack([I[o - l:B - l] for l in range(1, o + 1)])
    G, H = _expand(lambda S: kernels.dynamics_kernel(list(P.dyn_lags), list(lags),
                                                     list(P.dyn_style), S, P.alpha),
                   P.dyn, dyn_factors, free, fixed, B - o, P.level_vectors)
    base = kernels.dynamics_diag(list(lags), unit(dyn_factors, B - o), P.alpha)
    dyn = _Expanded(I[o:] - ar_mean(list(lags), P.ar), G, H, base, noise["I"], m[o:])
    return StyleExpansion(_bottom_term(P, X, Ys, m) + restart_log_prior(I[:o], init_var),
                          inter, dyn,
                          {f: P.level_vectors[f] for f in free})


def _layer_term(E: _Expanded, c, norm2):
    mean = jnp.einsum("p,pnd->nd", c, E.G)
    var = jnp.maximum(E.base * norm2 - jnp.einsum("npq,p,q->n", E.H, c, c), 0.0)
    return jnp.sum(E.weight * _normal(E.outputs, mean, var + E.noise))


def expanded_log_likelihood(E: StyleExpansion, coords: dict, free: dict, int_factors,
                            dyn_factors):
    """The clip's log-likelihood (all layers, latents fixed) at the free styles' simplex
    coordinates ``coords`` (factor -> (K_f,)) from an expansion; defined on the closed simplex,
    vertices included."""

    def coeffs(factors):  # kernel rows are multilinear in the coordinates; |w V|^2 scales k(u,u)
        names, _ = _combos(factors, free)
        c, norm2 = jnp.ones(1), 1.0
        for f in names:
            c = jnp.kron(c, coords[f])
            norm2 = norm2 * jnp.sum((coords[f] @ E.vectors[f]) ** 2)
        return c, norm2

    return (E.const + _layer_term(E.inter, *coeffs(int_factors))
            + _layer_term(E.dyn, *coeffs(dyn_factors)))


def expanded_log_density(E: StyleExpansion, params: dict, concentration: dict, free: dict,
                         int_factors, dyn_factors, likelihood_power=1.0):
    """:func:`clip_log_density` at the free styles ``params["style:<f>"]`` from an expansion.

    ``likelihood_power`` eta multiplies the clip's log-likelihood, not the styles' prior: the
    tempered (generalised-Bayes) posterior p(s) p(clip | s)^eta; 1 is the plain posterior."""
    coords = {f: style_to_simplex(params[STYLE_PREFIX + f][None])[0] for f in free}
    loglik = expanded_log_likelihood(E, coords, free, int_factors, dyn_factors)
    total = likelihood_power * loglik + style_log_prior(params, concentration)
    return jnp.where(jnp.isnan(total), -jnp.inf, total)
