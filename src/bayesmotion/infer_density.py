"""Predictive log-density of an observed clip under a conditioned model (pure JAX).

For a clip with poses Y*_a (per actor), latents X*_a, I* and style vectors s* (one per factor):

    log p(Y*, X*, I* | s*, training data)
      = sum_a sum_t log N(Y*_a,t | mu_Y(X*_a,t), (sigma_Y^2 + 1/gamma3) I)        bottom
      + sum_t log N([X*_1,t X*_2,t] | mu_X(I*_t, s*), (sigma_X^2 + 1/beta3) I)  interaction
      + sum_{t>o} log N(I*_t | mu_I(I*_{t-1..t-o}, s*), (sigma_I^2 + 1/alpha_noise) I)
      + sum_{t<=o} log N(I*_t | 0, v0 I)                                          dynamics

with every mu / sigma^2 the GP predictive of the fitted layer (bayesmotion.predict). Arrays are
padded to a frame bucket; ``mask`` marks real frames (padding contributes exactly 0), so clips of
many lengths share one compiled function.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .params import style_log_jacobian, style_to_simplex
from .predict import (
    Predictor,
    noise_variances,
    predict_bottom,
    predict_dynamics,
    predict_interaction,
)

LOG_2PI = float(np.log(2 * np.pi))


def _normal(x, mean, var):
    """Sum over the last axis of log N(x | mean, var) with var broadcast per row. -> (B,)"""
    D = x.shape[-1]
    return -0.5 * (jnp.sum((x - mean) ** 2, -1) / var + D * (LOG_2PI + jnp.log(var)))


def styles_from(params: dict, fixed: dict, factors) -> list[jnp.ndarray]:
    """Per factor (K_f,) style: free ones from params["u:<f>"], else the fixed vector."""
    return [style_to_simplex(params["u:" + f][None])[0] if ("u:" + f) in params
            else jnp.asarray(fixed[f]) for f in factors]


def clip_terms(P: Predictor, params: dict, Ys, mask, fixed: dict, int_factors, dyn_factors,
               init_var: float):
    """The three layer terms of the clip's log-density (scalars)."""
    X, I = params["X"], params["I"]
    B = I.shape[0]
    m = mask.astype(I.dtype)
    noise = noise_variances(P)
    bottom = 0.0
    for a, Y in enumerate(Ys):
        mu, var = predict_bottom(P, a, X[a])
        bottom = bottom + jnp.sum(m * _normal(Y, mu, var + noise["Y"]))
    s_int = [jnp.broadcast_to(s, (B, s.shape[0])) for s in styles_from(params, fixed, int_factors)]
    mu, var = predict_interaction(P, I, s_int)
    Z = jnp.concatenate([X[a] for a in range(X.shape[0])], axis=1)
    inter = jnp.sum(m * _normal(Z, mu, var + noise["X"]))
    o = P.dyn_lags.shape[0]
    lags = jnp.stack([I[o - l:B - l] for l in range(1, o + 1)])
    s_dyn = [jnp.broadcast_to(s, (B - o, s.shape[0]))
             for s in styles_from(params, fixed, dyn_factors)]
    mu, var = predict_dynamics(P, lags, s_dyn)
    dyn = jnp.sum(m[o:] * _normal(I[o:], mu, var + noise["I"]))
    first = I[:o]
    dyn = dyn - 0.5 * jnp.sum(first**2) / init_var - 0.5 * first.size * (
        LOG_2PI + jnp.log(init_var))
    return bottom, inter, dyn


def style_log_prior(params: dict, concentration: dict) -> jnp.ndarray:
    """Dirichlet log-density of each free style plus the stick-breaking log-Jacobian."""
    import numpyro.distributions as dist

    lp = 0.0
    for key, u in params.items():
        if key.startswith("u:"):
            s = jnp.clip(style_to_simplex(u[None])[0], 1e-300, 1.0)
            lp = lp + dist.Dirichlet(jnp.asarray(concentration[key[2:]])).log_prob(s)
            lp = lp + style_log_jacobian(u[None])
    return lp


def clip_log_density(P, params, Ys, mask, fixed, concentration, int_factors, dyn_factors,
                     init_var):
    b, i, d = clip_terms(P, params, Ys, mask, fixed, int_factors, dyn_factors, init_var)
    total = b + i + d + style_log_prior(params, concentration)
    return jnp.where(jnp.isnan(total), -jnp.inf, total)
