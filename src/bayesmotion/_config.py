"""Numerical configuration applied when bayesmotion is imported.

float64: GP marginal likelihoods over hundreds of frames need it (Cholesky of kernel matrices
with condition numbers ~1e8), so bayesmotion switches JAX to 64-bit, as numpyro's ``enable_x64``
does. Code that wants float32 elsewhere can switch it back after import; bayesmotion's own
functions cast their inputs to float64 where it matters.

XLA's CPU thread pool: jaxlib 0.10 runs a *batched* LAPACK call (a vmapped Cholesky or
triangular solve, as over walkers and style blocks here, and in the gradient of every Cholesky)
through ``ParallelBatchMap``: the thread running the call splits the batch into tasks on XLA's
intra-op pool and blocks until they finish. When as many such calls run at once as the pool has
threads (XLA runs independent operations of one program concurrently; 2 on the 2-core target),
every thread of the pool waits and none is left to run the tasks: the computation never returns
(a gdb stack shows each ``tf_XLAEigen`` thread in ``BlockingCounter::Wait`` under
``jax::TriMatrixEquationSolver``). On the 2-core target the MAP fit and ``infer_emotion`` hung
with the default pool (benchmarks/results/jax_versions.json), and so did the reproducer of
tests/test_jax_deadlock.py in 5 of 5 runs. With a one-thread pool ``ParallelBatchMap`` runs the
whole batch on the calling thread, so the wait cannot occur. On jaxlib >= 0.10 bayesmotion
therefore sets ``PJRT_NPROC=1`` (the pool size XLA reads when JAX starts its CPU backend) unless
the caller set ``PJRT_NPROC`` or ``NPROC``; ``XLA_FLAGS=--xla_cpu_multi_thread_eigen=false``
does not prevent this deadlock. The cost, on the 2-core target, is in
benchmarks/results/jax_versions.json. jaxlib 0.9.x runs batched LAPACK calls on one thread and
keeps XLA's default pool (one thread per core). The setting only takes effect if bayesmotion is
imported before JAX's first computation in the process; to choose the pool size yourself, set
``PJRT_NPROC`` before starting Python (on jaxlib 0.10 a number above 1 brings the deadlock
back).

Host callbacks: with the one-thread pool, a host callback inside a jitted program (a
``pure_callback``) can wait forever on its own argument: one hung in a full test run on jax
0.10.2, its thread waiting in ``np.asarray`` (tests/test_layers.py::
test_cholesky_inverse_matches_numpy). bayesmotion's only callback, the LAPACK path of
:func:`bayesmotion.gp.linalg.cholesky_inverse`, is therefore not used on jaxlib >= 0.10
(``gp.linalg.HOST_CALLBACK``): the XLA path runs there instead.

BLAS threads: JAX's CPU Cholesky and triangular solves call SciPy's OpenBLAS, whose threads
busy-wait, so with the cores shared (XLA's own pool, other processes, test workers) they take
cycles from the work beside them. One thread costs little when the cores are idle: on the
2-core target machine the default thread count takes 0.74-1.05 times the one-thread time of
a 1000 x 1000 Cholesky and of a log-posterior value and gradient
(benchmarks/results/blas_threads.json, a quick run). bayesmotion therefore sets
``OPENBLAS_NUM_THREADS=1`` unless the caller set it. It applies when
SciPy's OpenBLAS is loaded after bayesmotion is imported (the usual case: jaxlib loads it on the
first factorisation). The exception is :func:`bayesmotion.gp.linalg.cholesky_inverse`, which
raises the count for its own calling thread (``openblas_set_num_threads_local``) while XLA's
pool is blocked on it, and only while other processes leave the cores idle. To keep every
BLAS call on one thread (e.g. when running several bayesmotion processes side by side), set
``OPENBLAS_NUM_THREADS=1`` yourself.

Compiled programs: XLA's CPU backend maps memory for every program it compiles, and a loop that
compiles for each new shape can reach the kernel's limit on a process's mappings
(``vm.max_map_count``), where LLVM fails with "Cannot allocate memory" however much memory is
free. :func:`release_compiled_programs` drops JAX's compiled programs past half that limit;
``fit``, ``sample_posterior`` and ``infer_emotion`` call it before they compile, ``leave_one_out``
before each fold and ``infer_many``'s workers before each clip, so a notebook or program that
runs them in a loop stays below the limit.
"""

import os
from collections.abc import MutableMapping
from importlib import metadata

#: True when bayesmotion chose the one-thread default (the caller had not set it; a value this
#: module set in a parent process and its children inherited counts as not set, hence the
#: marker variable); then the large factorisations of
#: :func:`bayesmotion.gp.linalg.cholesky_inverse`, which run while XLA's pool waits on them, use
#: every core for their own thread only.
_MARK = "BAYESMOTION_SET_OPENBLAS_NUM_THREADS"
BLAS_THREADS_DEFAULTED = os.environ.get("OPENBLAS_NUM_THREADS") in (None, os.environ.get(_MARK))
if "OPENBLAS_NUM_THREADS" not in os.environ:
    os.environ["OPENBLAS_NUM_THREADS"] = os.environ[_MARK] = "1"

_POOL_MARK = "BAYESMOTION_SET_PJRT_NPROC"


def jaxlib_version() -> tuple[int, int]:
    """(major, minor) of the installed jaxlib, read without importing it; (0, 0) if unknown."""
    try:
        major, minor = metadata.version("jaxlib").split(".")[:2]
        return int(major), int("".join(c for c in minor if c.isdigit()) or 0)
    except (metadata.PackageNotFoundError, ValueError):
        return 0, 0


def apply_xla_pool_policy(env: MutableMapping[str, str], version: tuple[int, int]) -> bool:
    """Set ``PJRT_NPROC=1`` in ``env`` for jaxlib ``version`` >= 0.10 unless the caller set
    ``PJRT_NPROC`` or ``NPROC``; True when it did. A value this function set in a parent
    process (marked by ``BAYESMOTION_SET_PJRT_NPROC``) counts as not set, so a child process
    with another jaxlib gets its own default."""
    if env.get(_POOL_MARK) is not None and env.get(_POOL_MARK) == env.get("PJRT_NPROC"):
        del env["PJRT_NPROC"], env[_POOL_MARK]
    if version < (0, 10) or {"PJRT_NPROC", "NPROC"} & env.keys():
        return False
    env["PJRT_NPROC"] = env[_POOL_MARK] = "1"
    return True


#: True when bayesmotion sized XLA's CPU pool to one thread (see the module docstring).
XLA_POOL_DEFAULTED = apply_xla_pool_policy(os.environ, jaxlib_version())

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)


# --------------------------------------------------------------------------- compiled programs
#: the share of the kernel's limit on a process's memory mappings at which
#: :func:`release_compiled_programs` drops JAX's compiled programs
MAPS_FRACTION = 0.5


def memory_maps() -> tuple[int, int] | None:
    """(memory mappings of this process, the kernel's limit ``vm.max_map_count``), or None
    where the system does not say (not Linux)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            used = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            limit = int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return used, limit


def release_compiled_programs(fraction: float = MAPS_FRACTION, maps=memory_maps) -> bool:
    """Drop JAX's caches of compiled programs (``jax.clear_caches()``) when this process's
    memory mappings exceed ``fraction`` of the kernel's limit; True when it did.

    XLA's CPU backend maps memory for every compiled program. A long loop that compiles anew
    for each new shape (leave-one-out folds of other sizes, clips of many lengths) grows the
    count until mapping fails at the limit (65,530 by default): LLVM then reports "Cannot
    allocate memory" with gigabytes free, and the process crashes. Called between such units
    of work, this keeps the count bounded at the cost of compiling again what is used next.
    """
    now = maps()
    if now is None or now[0] <= fraction * now[1]:
        return False
    import jax

    jax.clear_caches()
    return True
