"""Gaussian log-densities of GP layers: dense (with their hand-written VJPs), RBF GP-LVM
(eq. 1-3), and block-diagonal (one Cholesky per style cell).

Values are computed through a Cholesky factor and a triangular solve, never an inverse of K.
Gradients need K^-1 (d log|K| / dK = K^-1), so under differentiation K^-1 = L^-T L^-1 is
formed once, by blocks (:mod:`bayesmotion.gp.linalg`), and the value there uses it as well: the
quadratic form is sum(Y o K^-1 Y). It agrees with the solve's |L^-1 Y|^2 to ~1e-15 relative for
outputs unrelated to K, but loses more for outputs drawn from the GP (Y = L z): ~2e-11 at
condition number 2e8, ~2e-9 at 2e10, i.e. ~1e-6 in absolute log-density (tested to 1e-9 at 3e7
with both kinds of outputs). Outside the
support (a kernel matrix that is not positive definite even with jitter) they return -inf,
never NaN, with a zero gradient.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular

from bayesmotion.gp import kernels
from bayesmotion.gp.linalg import cholesky_inverse

LOG_2PI = float(np.log(2 * np.pi))


def safe_cholesky(K: jnp.ndarray, jitter: float | jnp.ndarray = 0.0):
    """Lower Cholesky factor of K + jitter * mean(diag K) * I.

    Returns (L, ok): ``ok`` is False when the factorisation failed (NaN entries); the fitting
    driver then retries with a larger jitter and reports it.
    """
    n = K.shape[0]
    scale = jnp.mean(jnp.diag(K))
    L = jnp.linalg.cholesky(K + (jitter * scale) * jnp.eye(n, dtype=K.dtype))
    ok = jnp.all(jnp.isfinite(L))
    return jnp.where(ok, L, jnp.eye(n, dtype=K.dtype)), ok


def gaussian_loglik(K: jnp.ndarray, Y: jnp.ndarray, jitter=0.0) -> jnp.ndarray:
    """sum_d log N(Y[:, d] | 0, K): D independent columns sharing one covariance (eq. 1).

    log p = -D/2 log|K| - 1/2 tr(K^-1 Y Y^T) - N D/2 log 2 pi, with log|K| = 2 sum log diag L
    and tr(K^-1 Y Y^T) = |L^-1 Y|^2. The gradient is written by hand (:func:`_loglik_bwd`), not
    traced through the Cholesky factorisation.

    Args:
        K: (N, N) covariance. Y: (N, D) outputs.
    """
    n = K.shape[0]
    scale = jnp.mean(jnp.diag(K))
    return _loglik_chol(K + (jitter * scale) * jnp.eye(n, dtype=K.dtype), Y)


def _factor(K):
    """(L, ok): a failed factorisation is NaN throughout (jax.lax.linalg.cholesky), so the
    diagonal tells."""
    L = jnp.linalg.cholesky(K)
    return L, jnp.all(jnp.isfinite(jnp.diag(L)))


def _value(quad, diag, N, D, ok):
    """The log-density from the quadratic form and the Cholesky factor's diagonal."""
    val = -0.5 * quad - D * jnp.sum(jnp.log(diag)) - 0.5 * N * D * LOG_2PI
    return jnp.where(ok & jnp.isfinite(val), val, -jnp.inf)


def _primal(L, ok, Y):
    """The value alone: one triangular solve."""
    return _value(jnp.sum(solve_triangular(L, Y, lower=True) ** 2), jnp.diag(L), *Y.shape, ok)


def _with_inverse(K, Y):
    """Under differentiation: K^-1 once (:func:`bayesmotion.gp.linalg.cholesky_inverse`); the VJP
    needs it (d log|K| / dK), and it gives alpha = K^-1 Y in one product and the quadratic form
    as sum(Y o alpha). Returns (value, K^-1, alpha, ok)."""
    diag, Kinv = cholesky_inverse(K)
    ok = jnp.all(jnp.isfinite(diag))
    alpha = Kinv @ Y
    return _value(jnp.sum(Y * alpha), diag, *Y.shape, ok), Kinv, alpha, ok


def _dlogp_dK(Kinv, alpha, ok):
    """W = d logp / dK = (alpha alpha^T - D K^-1) / 2, zero outside the support."""
    D = alpha.shape[1]
    return jnp.where(ok, 0.5 * (alpha @ alpha.T - D * Kinv), 0.0)


@jax.custom_vjp
def _loglik_chol(K, Y):
    return _primal(*_factor(K), Y)


def _loglik_fwd(K, Y):
    val, Kinv, alpha, ok = _with_inverse(K, Y)
    return val, (Kinv, alpha, ok)


def _loglik_bwd(res, g):
    """d logp / dK = W and d logp / dY = -alpha (alpha = K^-1 Y).

    K^-1 = L^-T L^-1 by blocks (:mod:`bayesmotion.gp.linalg`). Autodiff through ``cholesky`` +
    ``cho_solve`` costs about twice as much (benchmarks/gplvm_vs_gpy.py). Outside the support
    (failed factorisation) the value is -inf and the gradient zero.
    """
    Kinv, alpha, ok = res
    g = jnp.where(ok, g, 0.0)  # a NaN/inf cotangent must not leak through the zeros below
    return g * _dlogp_dK(Kinv, alpha, ok), -g * jnp.where(ok, alpha, 0.0)


_loglik_chol.defvjp(_loglik_fwd, _loglik_bwd)


def gplvm_loglik(X, Y, gamma, jitter=0.0):
    """Bottom layer: log p(Y | X, gamma), K_Y = gamma1 exp(-gamma2/2 |x-x'|^2) + gamma3^-1 I.

    X: (N, Q) latents, Y: (N, D) poses, gamma: (3,) positive. Equal to
    ``gaussian_loglik(bottom_kernel(X, X, gamma) + I / gamma3, Y, jitter)`` (tested), with the
    gradient written out for this kernel (:func:`_rbf_gplvm_bwd`).
    """
    dtype = jnp.result_type(X, Y, gamma, float)
    return _rbf_gplvm(X, Y, gamma, jnp.asarray(jitter, dtype))


def _rbf_gplvm_kernel(X, gamma, jitter):
    """(E, K): E = exp(-gamma2/2 |x - x'|^2), the kernel without its variance gamma1 (kept
    apart so that d/dgamma1 = sum(W o E) stays finite when gamma1 underflows to 0), and
    K = gamma1 E + noise I."""
    E = kernels.rbf(X, X, 1.0, gamma[1])
    # gaussian_loglik's jitter is relative to mean(diag K) = gamma1 + 1/gamma3
    noise = 1.0 / gamma[2] + jitter * (gamma[0] + 1.0 / gamma[2])
    return E, gamma[0] * E + noise * jnp.eye(X.shape[0], dtype=E.dtype)


@jax.custom_vjp
def _rbf_gplvm(X, Y, gamma, jitter):
    return _primal(*_factor(_rbf_gplvm_kernel(X, gamma, jitter)[1]), Y)


def _rbf_gplvm_fwd(X, Y, gamma, jitter):
    E, K = _rbf_gplvm_kernel(X, gamma, jitter)
    val, Kinv, alpha, ok = _with_inverse(K, Y)
    return val, (X, gamma, jitter, E, Kinv, alpha, ok)


def _rbf_gplvm_bwd(res, g):
    """The chain rule through the RBF kernel by hand, with W = d logp / dK:

    W = (alpha alpha^T - D K^-1) / 2, G = W o E (E = K_rbf / gamma1), r = G 1,
    d/dX = -2 gamma1 gamma2 (r o X - G X), d/dgamma1 = sum(G) + jitter tr W,
    d/dgamma2 = -gamma1/2 sum(G o |x - x'|^2) = -gamma1 (r . |x|^2 - sum(X o G X)),
    d/dgamma3 = -(1 + jitter) tr W / gamma3^2, d/dY = -alpha.

    Autodiff of the same function makes about fifteen N x N passes (transposes, a scatter for
    the diagonal, copies); this makes four, which is what puts this layer ahead of GPy
    (benchmarks/gplvm_vs_gpy.py). Outside the support the gradient is zero.
    """
    X, gamma, jitter, E, Kinv, alpha, ok = res
    g = jnp.where(ok, g, 0.0)  # a NaN/inf cotangent must not leak through the zeros below
    W = _dlogp_dK(Kinv, alpha, ok)
    alpha = jnp.where(ok, alpha, 0.0)
    G = W * E
    r = jnp.sum(G, axis=1)
    GX = G @ X
    trW = jnp.trace(W)
    dX = -2.0 * gamma[0] * gamma[1] * (r[:, None] * X - GX)
    d_gamma = jnp.stack([jnp.sum(G) + jitter * trW,
                         -gamma[0] * (jnp.sum(r * jnp.sum(X**2, axis=1)) - jnp.sum(X * GX)),
                         -(1.0 + jitter) * trW / gamma[2] ** 2])
    d_jitter = trW * (gamma[0] + 1.0 / gamma[2])
    return ((g * dX).astype(X.dtype), -g * alpha, (g * d_gamma).astype(gamma.dtype),
            g * d_jitter)


_rbf_gplvm.defvjp(_rbf_gplvm_fwd, _rbf_gplvm_bwd)


# --------------------------------------------------------------------------- block-diagonal path
class Blocks:
    """Frames grouped by style cell, padded to one block size (static NumPy bookkeeping).

    With one-hot style vectors, prod_f (s_f^T s_f') is 1 inside a cell (same level of every
    factor) and exactly 0 across cells, so the kernel matrix is block-diagonal and its log-density
    is the sum over cells. Padding rows get unit variance and zero output, and their constant
    is removed, so the sum is exactly the dense value.

    Attributes:
        idx: (n_blocks, B) row indices into the layer's rows (padding repeats row 0).
        mask: (n_blocks, B) True for real rows.
    """

    def __init__(self, cell_of_row: np.ndarray):
        cells = np.unique(cell_of_row)
        groups = [np.flatnonzero(cell_of_row == c) for c in cells]
        B = max(g.size for g in groups)
        self.idx = np.zeros((len(groups), B), dtype=int)
        self.mask = np.zeros((len(groups), B), dtype=bool)
        for b, g in enumerate(groups):
            self.idx[b, : g.size] = g
            self.mask[b, : g.size] = True


def cell_ids(onehots) -> np.ndarray:
    """(M,) integer id of each row's combination of one-hot levels over the given factors."""
    if not onehots:
        return np.zeros(0, dtype=int)
    codes = np.stack([np.argmax(h, 1) for h in onehots], axis=1)
    _, ids = np.unique(codes, axis=0, return_inverse=True)
    return ids.ravel()


def block_matrices(K_of_rows, noise_var, blocks: Blocks, jitter=0.0) -> jnp.ndarray:
    """(n_blocks, B, B): each block's kernel + noise_var I, padded to B rows.

    Padding rows get unit variance and no coupling. The jitter is the dense path's,
    jitter * mean(diag K) over the real rows, added to the real rows only, so a blocked
    computation equals the dense one at every jitter.
    """
    idx, mask = jnp.asarray(blocks.idx), jnp.asarray(blocks.mask)

    def build(ix, m):
        mm = m[:, None] & m[None, :]
        return jnp.where(mm, K_of_rows(ix), 0.0) + jnp.diag(jnp.where(m, noise_var, 1.0))

    Ks = jax.vmap(build)(idx, mask)
    diag = jnp.diagonal(Ks, axis1=1, axis2=2)
    scale = jnp.sum(jnp.where(mask, diag, 0.0)) / jnp.sum(mask)
    return Ks + jax.vmap(jnp.diag)(jnp.where(mask, jitter * scale, 0.0))


def blocked_gaussian_loglik(K_of_rows, Y, noise_var, blocks: Blocks, jitter=0.0):
    """sum over blocks of log N(Y_b | 0, K_b + noise_var I), vectorised with vmap.

    Args:
        K_of_rows: function (B,) row indices -> (B, B) noise-free kernel of those rows.
        Y: (M, D) outputs of all rows.
        noise_var: scalar noise variance.
        blocks: the grouping.
    """
    D = Y.shape[1]
    idx, mask = jnp.asarray(blocks.idx), jnp.asarray(blocks.mask)
    # padding rows have exactly unit variance: their constant is removed below
    Ks = block_matrices(K_of_rows, noise_var, blocks, jitter)

    def one(K, ix, m):
        Yb = jnp.where(m[:, None], Y[ix], 0.0)
        return gaussian_loglik(K, Yb, 0.0) + 0.5 * jnp.sum(~m) * D * LOG_2PI

    return jnp.sum(jax.vmap(one)(Ks, idx, mask))

