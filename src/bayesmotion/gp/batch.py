"""One point's function over a batch of points (walkers, draws): how the batch is laid out.

``jax.vmap`` turns each N x N kernel matrix and Cholesky factor of a log-density into a stack of
B of them; on a GPU that is what fills the device. On a CPU the stack of a whole half-ensemble
(27 x 340 x 340 float64: 0.9 MB per matrix, 25 MB per stack) leaves the caches, and every pass
over it reads main memory: one vmapped log-density of the demo-size posterior costs 1.6 (jax
0.10) to 1.8 (jax 0.9) times as much per point as the same function two points at a time inside
one program (``jax.lax.map``).
:func:`over_points` therefore maps over small chunks of points on a CPU and vmaps the whole
batch elsewhere; ``benchmarks/results/walker_batching.json`` has the times of each layout on the
2-core target (jax 0.9 and 0.10).
"""

from __future__ import annotations

import operator

import jax
import jax.numpy as jnp

CPU_CHUNK = 2
"""Points per vmapped chunk on a CPU. At the demo size (N = 340) chunks of 2 are the fastest or
level with the fastest on both jax lines (``benchmarks/results/walker_batching.json``); at the
built-in size (N = 816) one point at a time is 7% faster (``benchmarks/results/sampler_ess.json``,
key ``eval_costs.builtin``: 1.75 s against 1.88 s for 54 walkers), and one vmap 17% slower."""


def default_chunk() -> int | None:
    """:data:`CPU_CHUNK` when JAX's default backend is the CPU, else None (one vmap)."""
    return CPU_CHUNK if jax.default_backend() == "cpu" else None


def over_points(fn, chunk: int | None = -1):
    """``fn`` (one point -> a pytree of arrays) as a function of a batch of points (B, ...).

    Args:
        fn: a pure JAX function of one point.
        chunk: points vmapped together, the chunks run one after another under ``lax.map``;
            None vmaps the whole batch; -1 (the default) is :func:`default_chunk`, read when
            this function is called.
    Returns:
        A function of a batch, equal to ``jax.vmap(fn)`` (to rounding: the same operations
        on other array shapes); jit it, or call it inside a jitted program.
    """
    chunk = _chunk(chunk)
    batched = jax.vmap(fn)
    if chunk is None:
        return batched

    def mapped(xs):
        n = jax.tree_util.tree_leaves(xs)[0].shape[0]
        c = min(chunk, max(n, 1))
        pad, m = -n % c, -(-n // c)  # padding rows, chunks
        # the padding repeats the first point, so it is a valid input; its values are dropped
        padded = jax.tree_util.tree_map(
            lambda a: jnp.concatenate([a, jnp.repeat(a[:1], pad, axis=0)]) if pad else a, xs)
        chunks = jax.tree_util.tree_map(lambda a: a.reshape(m, c, *a.shape[1:]), padded)
        out = jax.lax.map(batched, chunks)
        return jax.tree_util.tree_map(lambda a: a.reshape(m * c, *a.shape[2:])[:n], out)

    return mapped


def _chunk(chunk) -> int | None:
    """``over_points``'s ``chunk`` resolved (-1: :func:`default_chunk`) and checked."""
    if chunk is None:
        return None
    try:
        if isinstance(chunk, bool):
            raise TypeError
        value = operator.index(chunk)
    except TypeError:
        raise ValueError(f"chunk must be a positive integer, None or -1, got {chunk!r}") from None
    if value == -1:
        return default_chunk()
    if value < 1:
        raise ValueError(f"chunk must be a positive integer, None or -1, got {chunk!r}")
    return value
