"""The suite's compilation effort per test (tests/conftest.py): unmarked tests compile with
XLA's optimisations mostly off, tests marked ``optimized`` as users' programs are compiled,
in this process and in the subprocesses a test starts."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

ALL_OPTIMISED = os.environ.get("BAYESMOTION_TEST_COMPILE", "auto") == "optimized"

PROBE = "import jax; print(jax.config.values['jax_disable_most_optimizations'])"


def _subprocess_flag():
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                         check=True)
    return out.stdout.strip() == "True"


def _program(x):
    return jnp.sum(jnp.tanh(x) @ x.T) + jnp.linalg.slogdet(x @ x.T + jnp.eye(x.shape[0]))[1]


def test_unmarked_tests_compile_with_most_optimisations_off():
    want = not ALL_OPTIMISED
    assert jax.config.values["jax_disable_most_optimizations"] is want
    assert _subprocess_flag() is want


@pytest.mark.optimized
def test_marked_tests_compile_as_users_programs_are_compiled():
    assert jax.config.values["jax_disable_most_optimizations"] is False
    assert _subprocess_flag() is False


def test_both_compilations_give_the_same_answer_to_rounding():
    x = np.random.default_rng(0).standard_normal((30, 30))
    flag = jax.config.values["jax_disable_most_optimizations"]
    try:
        got = {}
        for off in (True, False):
            jax.clear_caches()
            jax.config.update("jax_disable_most_optimizations", off)
            got[off] = float(jax.jit(_program)(x))
    finally:
        jax.clear_caches()
        jax.config.update("jax_disable_most_optimizations", flag)
    np.testing.assert_allclose(got[True], got[False], rtol=1e-12)
