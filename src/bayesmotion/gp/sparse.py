"""Inducing-point (sparse) GP layers: Titsias's (2009) collapsed variational bound.

For a layer with noise-free kernel k, training inputs F (N rows), outputs Y (N, D), noise
variance s2 and M inducing inputs U, with Q = K_fu K_uu^-1 K_uf,

    F(Y) = sum_d log N(Y[:, d] | 0, Q + s2 I) - D / (2 s2) tr(K_ff - Q)

is a lower bound on the exact log-marginal likelihood sum_d log N(Y[:, d] | 0, K_ff + s2 I),
tight when the inducing inputs are the training inputs (then Q = K_ff and the trace is 0: the
bound *is* the exact value; tested). Because it is a bound, moving the inducing inputs can
only tighten it, never overfit (the DTC / projected-process likelihood, the same formula
without the trace term, has no such guarantee). Cost O(N M^2) time and O(N M) memory instead
of O(N^3) and O(N^2).

With L_u L_u^T = K_uu (plus a small relative jitter), A = L_u^-1 K_uf / s (s^2 = s2) and
B = I + A A^T = L_B L_B^T (M x M), c = L_B^-1 A Y / s:

    F = -D sum log diag L_B - N D/2 log(2 pi s2) - (|Y|^2 / s2 - |c|^2) / 2
        - D / (2 s2) (sum diag K_ff - s2 |A|^2)

Prediction at a new input x (the variational posterior of the inducing outputs, marginalised):

    mean(x) = k(U, x)^T W,       var(x) = k(x, x) - |R k(U, x)|^2

with W = L_u^-T B^-1 A Y / s (M, D) and R^T R = K_uu^-1 - (K_uu + K_uf K_fu / s2)^-1
= L_u^-T (I - B^-1) L_u^-1, taken from the eigendecomposition B = V diag(lam) V^T as
R = diag(sqrt(1 - 1/lam)) V^T L_u^-1. That is exactly the form of an exact GP's predictive
(weights K^-1 Y against the training inputs, a factor of K^-1), with the inducing inputs in
place of the training inputs; :mod:`bayesmotion.model.predict` uses it so.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular

from bayesmotion.gp.densities import LOG_2PI

#: jitter of K_uu relative to the mean of its diagonal: inducing inputs that come close make
#: K_uu singular; 1e-8 changes the bound by ~1e-8 of its prior variance per frame
INDUCING_JITTER = 1e-8


class SparseParts(NamedTuple):
    """The M x M quantities of one sparse layer at one parameter value.

    Lu_inv: (M, M) inverse of K_uu's Cholesky factor (K_uu + jitter). A: (M, N) L_u^-1 K_uf / s.
    B: (M, M) I + A A^T, LB its Cholesky factor. AY: (M, D) A Y / s. noise: s2.
    """

    Lu_inv: jnp.ndarray
    A: jnp.ndarray
    B: jnp.ndarray
    LB: jnp.ndarray
    AY: jnp.ndarray
    noise: jnp.ndarray


def sparse_parts(Kuu, Kuf, Y, noise_var, jitter_u=INDUCING_JITTER) -> SparseParts:
    """Factor one sparse layer (module docstring). Kuu (M, M), Kuf (M, N), Y (N, D)."""
    M = Kuu.shape[0]
    scale = jnp.mean(jnp.diag(Kuu))
    Lu = jnp.linalg.cholesky(Kuu + (jitter_u * scale) * jnp.eye(M, dtype=Kuu.dtype))
    s = jnp.sqrt(noise_var)
    # L_u^-1 (M x M) times K_uf rather than a triangular solve with N right-hand sides: the
    # value and gradient are then matrix products
    Lu_inv = solve_triangular(Lu, jnp.eye(M, dtype=Lu.dtype), lower=True)
    A = (Lu_inv @ Kuf) / s
    B = jnp.eye(M, dtype=A.dtype) + A @ A.T
    return SparseParts(Lu_inv, A, B, jnp.linalg.cholesky(B), (A @ Y) / s, noise_var)


def sparse_loglik(Kuu, Kuf, kff_diag, Y, noise_var, jitter_u=INDUCING_JITTER,
                  trace_term: bool = True) -> jnp.ndarray:
    """Titsias's bound (``trace_term=False``: the DTC likelihood) of sum_d log N(Y[:, d] | 0,
    K_ff + noise_var I). kff_diag: (N,) diagonal of K_ff. -inf where a factorisation failed.

    Differentiated by JAX (two M x M Cholesky factors and their solves; no N x N matrix)."""
    N, D = Y.shape
    p = sparse_parts(Kuu, Kuf, Y, noise_var, jitter_u)
    c = solve_triangular(p.LB, p.AY, lower=True)
    val = (-D * jnp.sum(jnp.log(jnp.diag(p.LB))) - 0.5 * N * D * (LOG_2PI + jnp.log(noise_var))
           - 0.5 * (jnp.sum(Y**2) / noise_var - jnp.sum(c**2)))
    if trace_term:
        val = val - 0.5 * D / noise_var * (jnp.sum(kff_diag) - noise_var * jnp.sum(p.A**2))
    ok = jnp.all(jnp.isfinite(p.Lu_inv)) & jnp.all(jnp.isfinite(p.LB)) & jnp.isfinite(val)
    return jnp.where(ok, val, -jnp.inf)


def predictive_weights(p: SparseParts) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(W, R): mean(x) = k(U, x)^T W and var(x) = k(x, x) - |R k(U, x)|^2 (module docstring).
    W (M, D); R (M, M), not triangular."""
    lam, V = jnp.linalg.eigh(p.B)
    Lu_inv = p.Lu_inv
    W = Lu_inv.T @ (V @ ((V.T @ p.AY) / lam[:, None]))  # AY holds the 1 / s
    R = jnp.sqrt(jnp.clip(1.0 - 1.0 / lam, 0.0, 1.0))[:, None] * (V.T @ Lu_inv)
    return W, R


def held_out_blocks(p: SparseParts, Y, rows):
    """For the approximate model's covariance K = Q + s2 I and the training rows ``rows`` of
    one recording: ([K^-1]_bb (n, n), [K^-1 Y]_b (n, D)), by Woodbury,
    K^-1 = (I - A^T B^-1 A) / s2 (what :mod:`bayesmotion.emotion.ood` needs, O(n M^2))."""
    Ab = solve_triangular(p.LB, p.A[:, rows], lower=True)  # L_B^-1 A_b
    c = solve_triangular(p.LB, p.AY, lower=True)  # L_B^-1 A Y / s
    n = len(rows)
    Kinv_bb = (jnp.eye(n, dtype=Ab.dtype) - Ab.T @ Ab) / p.noise
    Kinv_Y = (Y[rows] - jnp.sqrt(p.noise) * (Ab.T @ c)) / p.noise
    return Kinv_bb, Kinv_Y
