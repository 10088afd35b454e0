"""Dense linear algebra in JAX that jax.numpy lacks: LAPACK's trtri/lauum/potri, blocked.

The layers' gradients need K^-1 (d log|K| / dK). A triangular solve with the identity followed
by a full product spends about 3/2 N^3 multiply-adds on it; these recursive 2x2 block versions
spend about 2/3 N^3 in matrix products, which XLA runs on every core (CPU) or on the GPU
unchanged.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.scipy.linalg import solve_triangular

_BLOCK = 128  # leaf size of the recursive inverses; 64-256 time alike at N = 1000 on 2 cores


def triangular_inverse(L: jnp.ndarray, block: int = _BLOCK) -> jnp.ndarray:
    """L^-1 of a lower-triangular L by recursive 2x2 blocking (LAPACK's trtri, in JAX).

    [[A, 0], [B, C]]^-1 = [[A^-1, 0], [-C^-1 B A^-1, C^-1]]: about N^3/3 multiply-adds in
    matrix products, against N^3/2 for a triangular solve with the identity as right-hand side.
    (Products that skip the zero halves of A and C timed the same at N = 1000.)
    """
    n = L.shape[0]
    if n <= block:
        return solve_triangular(L, jnp.eye(n, dtype=L.dtype), lower=True)
    h = n // 2
    A = triangular_inverse(L[:h, :h], block)
    C = triangular_inverse(L[h:, h:], block)
    B = -C @ (L[h:, :h] @ A)
    return jnp.block([[A, jnp.zeros((h, n - h), L.dtype)], [B, C]])


def lower_gram(M: jnp.ndarray, block: int = _BLOCK) -> jnp.ndarray:
    """M^T M for a lower-triangular M, recursing on the blocks (LAPACK's lauum). With
    M = L^-1 from :func:`triangular_inverse` this is K^-1 (LAPACK's potri): 26-30 ms (best of
    15) at N = 1000 on the 2-core target, against 75 ms for a triangular solve with the
    identity followed by a full product, and 69 ms for ``cho_solve(L, I)``."""
    n = M.shape[0]
    if n <= block:
        return M.T @ M
    h = n // 2
    A, B, C = M[:h, :h], M[h:, :h], M[h:, h:]
    top_right = B.T @ C
    return jnp.block([[lower_gram(A, block) + B.T @ B, top_right],
                      [top_right.T, lower_gram(C, block)]])
