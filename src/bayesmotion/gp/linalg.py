"""Dense linear algebra that jax.numpy lacks: the inverse of an SPD matrix from its Cholesky
factor (LAPACK's potri = trtri + lauum).

The layers' gradients need K^-1 (d log|K| / dK). :func:`cholesky_inverse` returns it with the
factor's diagonal (for log|K|):
- on CPU, for N >= 256, by LAPACK's potrf + potri (scipy's OpenBLAS) through a host callback,
  with OpenBLAS's threads raised to the core count for the calling thread only (XLA's pool is
  blocked on the callback meanwhile) while no other process keeps the cores busy
  (:func:`bayesmotion.gp.blas.blas_threads`), which on jaxlib < 0.10 is faster than the XLA
  path below;
- elsewhere (GPU, TPU, small blocks where a callback's overhead dominates, and on jaxlib >= 0.10,
  where a host callback inside a program run by XLA's one-thread CPU pool can wait forever on its
  own argument; see :mod:`bayesmotion._config`) by XLA: Cholesky,
  then recursive 2x2 block versions of trtri and lauum, about 2/3 N^3 multiply-adds in matrix
  products, against about 3/2 N^3 for a triangular solve with the identity and a full product.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from scipy.linalg import get_lapack_funcs

from bayesmotion._config import jaxlib_version
from bayesmotion.gp.blas import blas_threads

_BLOCK = 128  # leaf size of the recursive inverses
_LAPACK_MIN = 256  # below this a host callback costs more than it saves
#: Whether the CPU path may use the host callback: not on jaxlib >= 0.10 (module docstring).
HOST_CALLBACK = jaxlib_version() < (0, 10)


def cholesky_inverse(K: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(diag L, K^-1) of a symmetric positive-definite K = L L^T, batched over leading axes.

    Reads the lower triangle of K. Where K is not positive definite (or not finite) the diagonal
    is NaN (the callers' failure test) and K^-1 undefined. Not differentiable itself: it serves
    the hand-written gradients of :mod:`bayesmotion.model.layers`.

    Args:
        K: (..., N, N) symmetric positive-definite matrices.
    Returns:
        (..., N) diagonal of the Cholesky factor and (..., N, N) K^-1, symmetric.
    """
    if K.shape[-1] < _LAPACK_MIN or not HOST_CALLBACK:
        return _cholesky_inverse_xla(K)
    return jax.lax.platform_dependent(K, cpu=_cholesky_inverse_lapack,
                                      default=_cholesky_inverse_xla)


def _cholesky_inverse_xla(K):
    if K.ndim > 2:
        return jax.vmap(_cholesky_inverse_xla)(K)
    L = jnp.linalg.cholesky(K)
    return jnp.diag(L), lower_gram(triangular_inverse(L))


def _cholesky_inverse_lapack(K):
    shapes = (jax.ShapeDtypeStruct(K.shape[:-1], K.dtype), jax.ShapeDtypeStruct(K.shape, K.dtype))
    return jax.pure_callback(_host_cholesky_inverse, shapes, K, vmap_method="expand_dims")


def _host_cholesky_inverse(K):
    """potrf + potri on the host, matrix by matrix. A C-ordered K read as Fortran order is K^T
    (= K), so LAPACK's upper triangle there is our lower one and nothing is transposed."""
    K = np.asarray(K)
    n = K.shape[-1]
    flat = K.reshape(-1, n, n)
    potrf, potri = get_lapack_funcs(("potrf", "potri"), dtype=K.dtype)
    diag = np.empty(flat.shape[:2], K.dtype)
    inv = np.empty(flat.shape, K.dtype)
    with blas_threads():
        for b, k in enumerate(flat):
            inv[b] = k  # potrf and potri then work in place on inv[b].T (Fortran order)
            c, info = potrf(inv[b].T, lower=0, clean=0, overwrite_a=1)
            diag[b] = np.diag(c) if info == 0 else np.nan
            if info == 0:
                c, info = potri(c, lower=0, overwrite_c=1)
            if not np.shares_memory(c, inv[b]):  # a LAPACK wrapper that copied after all
                inv[b] = c.T
            _fill_upper(inv[b])  # lower triangle: K^-1; upper: what potrf/potri left there
    return diag.reshape(K.shape[:-1]), inv.reshape(K.shape)


def _fill_upper(A: np.ndarray, block: int = 64) -> None:
    """Copy the lower triangle of a square array onto its upper one, in place, by column
    blocks, without the temporary arrays of ``tril + tril.T``."""
    n = A.shape[0]
    for s in range(0, n, block):
        e = min(s + block, n)
        A[s:e, e:] = A[e:, s:e].T
        d = A[s:e, s:e]
        iu = np.triu_indices(e - s, 1)
        d[iu] = d.T[iu]


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
    M = L^-1 from :func:`triangular_inverse` this is K^-1 (LAPACK's potri); the recursion never
    multiplies M's zero blocks above the diagonal."""
    n = M.shape[0]
    if n <= block:
        return M.T @ M
    h = n // 2
    A, B, C = M[:h, :h], M[h:, :h], M[h:, h:]
    top_right = B.T @ C
    return jnp.block([[lower_gram(A, block) + B.T @ B, top_right],
                      [top_right.T, lower_gram(C, block)]])
