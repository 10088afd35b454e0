"""Kernels of the hierarchical GPDM as pure JAX functions (Taubert et al. 2012).

Gram-matrix functions of two input sets; the white-noise term is added by the layer that owns
the training inputs (it exists only on the diagonal of a training Gram matrix).

Notation (code name <- paper):
    gamma = (gamma1, gamma2, gamma3)  bottom layer, eq. 2
    beta  = (beta1, beta2, beta3)     interaction layer
    alpha = (alpha_rbf, alpha_ls[lag 1..o], alpha_lin[lag 1..o], alpha_noise)  dynamics, eq. 10
            (order o = 2: alpha1, alpha2, alpha3, alpha4, alpha5, alpha6 of the paper), or
            (alpha_rbf, alpha_ls[lag 1..o], alpha_noise) without the linear term, when the
            dynamics' linear part is an explicit stable autoregression instead
            (:func:`bayesmotion.model.layers.ar_coefficients`); the noise precision is last
            either way (:func:`dynamics_noise_precision`)
    S     = per-frame style vectors, one (N, K_f) matrix per style factor (couple c, emotion e)
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp


def sqdist(A: jnp.ndarray, B: jnp.ndarray) -> jnp.ndarray:
    """Squared Euclidean distances. A: (N, Q), B: (M, Q) -> (N, M), clipped at 0.

    Uses |a|^2 + |b|^2 - 2 a.b (one matmul); no square root, so gradients are finite at 0.
    The clip changes the value only (straight through): derivatives of every order are those
    of the polynomial. A plain ``maximum`` zeroes the second derivative wherever rounding makes
    d slightly negative -- at a point equal to a training input, where the projection of a clip
    starts -- and gave Hessians of the clip density wrong by a factor of 4 on the diagonal.
    """
    d = jnp.sum(A**2, -1)[:, None] + jnp.sum(B**2, -1)[None, :] - 2.0 * A @ B.T
    return d + jax.lax.stop_gradient(jnp.maximum(d, 0.0) - d)


def rbf(A, B, variance, inv_lengthscale):
    """variance * exp(-inv_lengthscale / 2 * |a - b|^2). A: (N, Q), B: (M, Q) -> (N, M)."""
    return variance * jnp.exp(-0.5 * inv_lengthscale * sqdist(A, B))


def style_gram(Sa: Sequence[jnp.ndarray], Sb: Sequence[jnp.ndarray]) -> jnp.ndarray | float:
    """Product over style factors of inner products, prod_f (s_f^T s_f').

    Sa, Sb: per factor, (N, K_f) and (M, K_f) per-frame style vectors. With one-hot vectors this
    is 1 between frames of the same style and exactly 0 otherwise (Wang et al. 2007).
    Returns 1.0 when there are no factors.
    """
    G = 1.0
    for a, b in zip(Sa, Sb, strict=True):
        G = G * (a @ b.T)
    return G


def style_gram_diag(S: Sequence[jnp.ndarray], n: int) -> jnp.ndarray:
    """Diagonal of style_gram(S, S), prod_f |s_f|^2, (n,) (ones without factors)."""
    d = jnp.ones(n)
    for s in S:
        d = d * jnp.sum(s * s, -1)
    return d


def bottom_kernel(A, B, gamma):
    """Bottom layer X -> Y, eq. 2 without noise: gamma1 exp(-gamma2/2 |x - x'|^2)."""
    return rbf(A, B, gamma[0], gamma[1])


def interaction_kernel(A, B, Sa, Sb, beta):
    """Interaction layer I -> [X1, X2]: (c^T c')(e^T e') beta1 exp(-beta2/2 |i - i'|^2)."""
    return style_gram(Sa, Sb) * rbf(A, B, beta[0], beta[1])


def has_linear_term(alpha, order: int) -> bool:
    """Whether ``alpha`` carries the linear kernel's weights (2 + 2 o entries) or not (2 + o)."""
    n = alpha.shape[0]
    if n not in (2 + order, 2 + 2 * order):
        raise ValueError(f"alpha has {n} entries; order {order} needs {2 + order} or "
                         f"{2 + 2 * order}")
    return n == 2 + 2 * order


def dynamics_noise_precision(alpha):
    """alpha_noise, the dynamics' white-noise precision: the last entry of ``alpha``."""
    return alpha[-1]


def dynamics_kernel(lags_a: Sequence[jnp.ndarray], lags_b: Sequence[jnp.ndarray], Sa, Sb, alpha):
    """Dynamics layer, eq. 10 without noise, for a GPDM of order o = len(lags_a).

    k = prod_f (s_f^T s_f') * [alpha_rbf exp(-sum_l alpha_ls[l]/2 |i_{t-l} - i'_{t-l}|^2)
                               + sum_l alpha_lin[l] i_{t-l}^T i'_{t-l}]

    (the linear sum only when ``alpha`` carries its weights, :func:`has_linear_term`).

    Style is constant within a trial, so both lags of one input share one style vector; the
    factor therefore appears once (the paper's "style of both lags").

    Args:
        lags_a: o arrays (N, Q): I_{t-1}, ..., I_{t-o} for each output frame t.
        lags_b: o arrays (M, Q).
        alpha: (2 + 2 o,) or (2 + o,) positive parameters.
    """
    o = len(lags_a)
    linear = has_linear_term(alpha, o)
    log_rbf = 0.0
    lin = 0.0
    for l in range(o):
        log_rbf = log_rbf - 0.5 * alpha[1 + l] * sqdist(lags_a[l], lags_b[l])
        if linear:
            lin = lin + alpha[1 + o + l] * (lags_a[l] @ lags_b[l].T)
    return style_gram(Sa, Sb) * (alpha[0] * jnp.exp(log_rbf) + lin)


def dynamics_diag(lags: Sequence[jnp.ndarray], S, alpha):
    """Diagonal of dynamics_kernel(lags, lags, S, S) without forming the matrix. -> (N,)."""
    o = len(lags)
    style = 1.0
    for s in S:
        style = style * jnp.sum(s * s, -1)
    if not has_linear_term(alpha, o):
        return style * alpha[0] * jnp.ones(lags[0].shape[0])
    lin = sum(alpha[1 + o + l] * jnp.sum(lags[l] ** 2, -1) for l in range(o))
    return style * (alpha[0] + lin)
