"""Numerical configuration applied when bayesmotion is imported.

float64: GP marginal likelihoods over hundreds of frames need it (Cholesky of kernel matrices
with condition numbers ~1e8), so bayesmotion switches JAX to 64-bit, as numpyro's ``enable_x64``
does. Code that wants float32 elsewhere can switch it back after import; bayesmotion's own
functions cast their inputs to float64 where it matters.

JAX version: jaxlib 0.10.x runs *batched* CPU LAPACK calls (vmapped Cholesky and triangular
solves, used here over walkers and style blocks) through ``ParallelBatchMap``, which can deadlock
XLA's intra-op thread pool: every worker waits in ``BlockingCounter::Wait`` and the computation
never returns. We reproduced it here (a gdb stack of the hung fit shows
``jax::TriMatrixEquationSolver`` under ``ParallelBatchMap``), so pyproject.toml excludes 0.10.*;
jaxlib 0.9.x lacks that path.

BLAS threads: JAX's CPU Cholesky and triangular solves call SciPy's OpenBLAS, whose threads
busy-wait; with the cores shared (XLA's own pool, other processes) the threaded ``potrf`` was
5-21x slower than one thread on the 2-core target machine (benchmarks/results/blas_threads.json).
bayesmotion therefore sets ``OPENBLAS_NUM_THREADS=1`` unless the caller set it. It applies when
SciPy's OpenBLAS is loaded after bayesmotion is imported (the usual case: jaxlib loads it on the
first factorisation). The exception is :func:`bayesmotion.gp.linalg.cholesky_inverse`, which
raises the count for its own calling thread (``openblas_set_num_threads_local``) while XLA's
pool is blocked on it, and only while other processes leave the cores idle. To keep every
BLAS call on one thread (e.g. when running several bayesmotion processes side by side), set
``OPENBLAS_NUM_THREADS=1`` yourself.
"""

import os

#: True when bayesmotion chose the one-thread default (the caller had not set it; a value this
#: module set in a parent process and its children inherited counts as not set, hence the
#: marker variable); then the large factorisations of
#: :func:`bayesmotion.gp.linalg.cholesky_inverse`, which run while XLA's pool waits on them, use
#: every core for their own thread only.
_MARK = "BAYESMOTION_SET_OPENBLAS_NUM_THREADS"
BLAS_THREADS_DEFAULTED = os.environ.get("OPENBLAS_NUM_THREADS") in (None, os.environ.get(_MARK))
if "OPENBLAS_NUM_THREADS" not in os.environ:
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ[_MARK] = "1"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
