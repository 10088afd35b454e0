"""Batched LAPACK calls on jaxlib 0.10 return instead of deadlocking XLA's CPU thread pool.

The reproducer is the value and gradient of a sum of eight independent vmapped Cholesky
log-determinants and triangular solves (batch 4, N = 128), called three times: jaxlib 0.10 splits
each batched triangular solve of the Cholesky gradient over XLA's intra-op pool and blocks on
it, and with several of them running at once every pool thread waits (see
``bayesmotion._config``). It runs in a child process that imports bayesmotion first, so
bayesmotion's one-thread pool (``PJRT_NPROC=1``) applies, pinned to two cores: XLA sizes its
pool by the cores a process may use, so the child has the pool of the 2-core target on any
machine.

How it was verified to hang without the workaround: the same child with ``PJRT_NPROC=2`` in its
environment (a caller's setting, which bayesmotion keeps: the opt-out) hung past a 30 s timeout
in 5 of 5 runs on jax 0.10.2 (2 cores), and returned in 5 of 5 runs (3-4 s each) with
bayesmotion's setting. On jaxlib 0.9.x the batched calls run on one thread and the child
returns whatever the pool size: the test then checks the value only.
"""

import json
import os
import subprocess
import sys

import pytest

from bayesmotion import _config

TIMEOUT_S = 120  # the child takes 3-6 s (import and compilation included); a hang never returns

CHILD = """
import json
import os
os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2])  # XLA's pool: 2 threads
import bayesmotion  # before JAX starts its CPU backend: the pool setting must precede it
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular

N = 128

def branch(A, y):
    L = jnp.linalg.cholesky(A @ jnp.swapaxes(A, -1, -2) + N * jnp.eye(N))
    z = solve_triangular(L, y, lower=True)
    return jnp.sum(z**2) + 2 * jnp.sum(jnp.log(jnp.diagonal(L, axis1=-2, axis2=-1)))

vg = jax.jit(jax.value_and_grad(lambda As, ys: sum(map(branch, As, ys))))
keys = jax.random.split(jax.random.PRNGKey(0), 8)
As = [jax.random.normal(k, (4, N, N)) for k in keys]
ys = [jax.random.normal(k, (4, N, 3)) for k in keys]
for _ in range(3):  # each call is another chance for the pool to deadlock
    value, grads = jax.block_until_ready(vg(As, ys))
# reference: y^T K^-1 y + log|K| per matrix, by NumPy
ref = 0.0
for A, y in zip(map(np.asarray, As), map(np.asarray, ys)):
    for a, b in zip(A, y):
        K = a @ a.T + N * np.eye(N)
        ref += np.sum(b * np.linalg.solve(K, b)) + np.linalg.slogdet(K)[1]
print(json.dumps({"value": float(value), "reference": ref,
                  "grad_finite": bool(all(np.isfinite(g).all() for g in grads))}))
"""


def _child_env() -> dict:
    """This environment without pool settings, so the child applies bayesmotion's default."""
    drop = {"PJRT_NPROC", "NPROC", "BAYESMOTION_SET_PJRT_NPROC"}
    return {k: v for k, v in os.environ.items() if k not in drop}


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs Linux CPU affinity")
def test_batched_cholesky_gradient_returns():
    try:
        r = subprocess.run([sys.executable, "-c", CHILD], env=_child_env(), capture_output=True,
                           text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"batched Cholesky gradient did not return in {TIMEOUT_S} s: XLA's CPU pool "
                    "deadlocked (see bayesmotion._config)")
    assert r.returncode == 0, r.stderr[-2000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["value"] == pytest.approx(out["reference"], rel=1e-9)
    assert out["grad_finite"]


@pytest.mark.parametrize(("env", "version", "expected"), [
    ({}, (0, 10), "1"),
    ({}, (0, 11), "1"),
    ({}, (0, 9), None),
    ({"PJRT_NPROC": "4"}, (0, 10), "4"),  # the caller's choice is kept
    ({"NPROC": "4"}, (0, 10), None),  # XLA reads NPROC when PJRT_NPROC is unset
    # set by bayesmotion in a parent process: a child with jaxlib 0.9 drops it
    ({"PJRT_NPROC": "1", "BAYESMOTION_SET_PJRT_NPROC": "1"}, (0, 9), None),
    ({"PJRT_NPROC": "1", "BAYESMOTION_SET_PJRT_NPROC": "1"}, (0, 10), "1"),
])
def test_pool_policy(env, version, expected):
    env = dict(env)
    set_here = _config.apply_xla_pool_policy(env, version)
    assert env.get("PJRT_NPROC") == expected
    assert set_here == (expected == "1" and version >= (0, 10))


def test_jaxlib_version_matches_jax():
    import jaxlib

    major, minor = (int(p) for p in jaxlib.__version__.split(".")[:2])
    assert _config.jaxlib_version() == (major, minor)
    assert _config.XLA_POOL_DEFAULTED == (
        (major, minor) >= (0, 10) and os.environ.get("BAYESMOTION_SET_PJRT_NPROC") == "1")
