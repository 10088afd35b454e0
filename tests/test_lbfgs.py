"""The pure-JAX L-BFGS (bayesmotion.optim.lbfgs) against known minima and scipy's L-BFGS-B."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from bayesmotion.optim import lbfgs


def rosenbrock(x):
    return jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)


@jax.jit
def run(x0, max_iter):
    return lbfgs.minimize(jax.value_and_grad(rosenbrock), x0, max_iter)


@pytest.mark.parametrize("d", [2, 10, 50])
def test_rosenbrock_reaches_the_minimum_in_as_few_evaluations_as_scipy(d):
    x0 = jnp.full(d, -1.2)
    r = run(x0, 2000)
    assert int(r.status) in (lbfgs.CONVERGED_GTOL, lbfgs.CONVERGED_FTOL)
    np.testing.assert_allclose(np.asarray(r.x), np.ones(d), atol=2e-5)
    assert float(r.fun) < 1e-8  # scipy: 2.5e-16, 5.6e-10, 2.2e-9
    ref = scipy.optimize.minimize(
        lambda x: (float(rosenbrock(x)), np.asarray(jax.grad(rosenbrock)(x), np.float64)),
        np.asarray(x0), jac=True, method="L-BFGS-B", options={"maxiter": 2000})
    assert int(r.nfev) <= 1.5 * ref.nfev  # d = 2: 33 vs 35; 10: 89 vs 79; 50: 299 vs 316


def test_ill_conditioned_quadratic_matches_the_solution():
    A = np.diag(np.logspace(0, 4, 100))
    b = np.linspace(-1.0, 2.0, 100)
    f = lambda x: 0.5 * x @ (jnp.asarray(A) @ x) - jnp.asarray(b) @ x
    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(f), x0, 5000))(jnp.zeros(100))
    exact = -0.5 * b @ np.linalg.solve(A, b)
    assert abs(float(r.fun) - exact) < 1e-6 * abs(exact)


def test_iteration_limit_is_honoured_and_traced():
    calls = []
    f = lambda x0, n: (calls.append(1), lbfgs.minimize(jax.value_and_grad(rosenbrock), x0, n))[1]
    g = jax.jit(f)
    for n in (1, 5, 17):
        r = g(jnp.full(10, -1.2), n)
        assert int(r.nit) == n and int(r.status) == lbfgs.MAX_ITER
    assert len(calls) == 1  # the limit is a traced argument: one compilation
    r = g(jnp.full(10, -1.2), 0)
    assert int(r.nit) == 0 and int(r.status) == lbfgs.MAX_ITER
    np.testing.assert_array_equal(np.asarray(r.x), np.full(10, -1.2))


def test_start_at_the_minimum_stops_at_once():
    r = run(jnp.ones(4), 100)
    assert int(r.nit) == 0 and int(r.status) == lbfgs.CONVERGED_GTOL


def test_non_finite_values_are_backed_away_from():
    """Values are +inf beyond x0 = 0.5 (a failed Cholesky, say): the run never returns a
    non-finite point or one worse than its start, and gets to the boundary's neighbourhood."""
    f = lambda x: jnp.where(x[0] > 0.5, jnp.nan, (x[0] - 1.0) ** 2 + x[1] ** 2)
    x0 = jnp.asarray([0.0, 1.0])
    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(f), x0, 100))(x0)
    assert np.all(np.isfinite(np.asarray(r.x))) and np.isfinite(float(r.fun))
    assert float(r.fun) <= float(f(x0))
    assert float(r.x[0]) <= 0.5 and float(r.fun) < 0.6
    # a start where the value is not finite: returned unchanged, flagged
    bad = jnp.asarray([1.0, 0.0])
    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(f), x0, 100))(bad)
    assert int(r.status) == lbfgs.NONFINITE_START and int(r.nit) == 0
    np.testing.assert_array_equal(np.asarray(r.x), np.asarray(bad))


def test_stops_when_even_steepest_descent_finds_no_decrease():
    """Against a wall (+inf beyond x0 = 1) every descent direction leaves the finite region:
    the quasi-Newton step fails, the retry along steepest descent fails too, and the run stops
    there, at the wall, with the best point found."""
    f = lambda x: jnp.where(x[0] > 1.0, jnp.inf, -x[0] + (x[1] - 0.5) ** 2)
    x0 = jnp.asarray([0.0, 2.0])
    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(f), x0, 500))(x0)
    assert int(r.status) == lbfgs.LINE_SEARCH_FAILED and int(r.nit) < 500
    assert float(r.x[0]) == pytest.approx(1.0, abs=1e-6) and float(r.fun) < -0.99
    assert int(r.nfev) > int(r.nit)  # every failed search spent its evaluations


def test_float32_converges_by_its_own_tolerance():
    """On an accelerator the latents may be float32: the default ftol follows the dtype (at
    least 10 epsilons), so the run stops by convergence, not at the limit."""
    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(rosenbrock), x0, 2000))(
        jnp.full(10, -1.2, jnp.float32))
    assert r.x.dtype == jnp.float32
    assert int(r.status) in (lbfgs.CONVERGED_GTOL, lbfgs.CONVERGED_FTOL)
    assert int(r.nit) < 2000 and np.abs(np.asarray(r.x) - 1.0).max() < 1e-2


def test_vmapped_runs_equal_single_runs():
    x0 = jnp.asarray([[-1.2, 1.0, 0.5], [0.3, -0.7, 2.0], [1.5, 1.5, 1.5]])
    batched = jax.jit(jax.vmap(lambda x: lbfgs.minimize(jax.value_and_grad(rosenbrock), x,
                                                        200)))(x0)
    for i in range(3):
        single = run(x0[i], 200)
        np.testing.assert_allclose(np.asarray(batched.x[i]), np.asarray(single.x), rtol=1e-9)
        assert int(batched.nit[i]) == int(single.nit)


def test_the_stall_criterion_is_relative_to_the_objective_over_a_window():
    from bayesmotion.optim.minimize import stalled

    assert stalled([5.0, 4.0], window=3) == (False, None)
    met, change = stalled([1000.0, 999.0, 998.0, 997.99], window=2)
    assert change == pytest.approx((999.0 - 997.99) / 997.99)
    assert not met
    met, change = stalled([1000.0, 999.0, 998.0, 997.99], window=2, rtol=2e-3)
    assert met
    # the magnitude is at least 1, so an objective near 0 does not inflate the change
    assert stalled([1e-9, 0.0], window=1, rtol=2.0)[0]


def test_map_optimize_stops_at_the_stall_test_and_says_so():
    from bayesmotion.optim.minimize import convergence_note, map_optimize, stalled

    def logp(p, jitter):  # 20-D Rosenbrock: many iterations from (-1.2, 1, ...)
        x = p["x"]
        return -jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)

    x0 = {"x": jnp.tile(jnp.array([-1.2, 1.0]), 10)}
    _, full = map_optimize(logp, x0, max_iter=2000, rtol=0.0, progress=False)
    _, early = map_optimize(logp, x0, max_iter=2000, rtol=0.5, window=5, progress=False)
    assert full["iterations"] > 30 and full["converged"]
    assert 6 <= early["iterations"] < full["iterations"]  # 6: the first with a window of 5
    trace = early["trace"]  # it stopped at the first iteration that met the test
    assert not any(stalled(trace[:k], 5, 0.5)[0] for k in range(len(trace)))
    assert stalled(trace, 5, 0.5)[0]
    assert early["converged"] and early["convergence"]["met"]
    assert early["message"].startswith("CONVERGED: OBJECTIVE FELL BY LESS THAN 0.5")
    assert early["convergence"]["relative_fall_last_window"] < 0.5
    _, capped = map_optimize(logp, x0, max_iter=10, rtol=0.0, progress=False)
    assert not capped["converged"] and capped["convergence"]["max_iter_reached"]
    # what the demo report and `bayesmotion fit` say about it
    assert convergence_note(full) == (
        f"converged after {full['iterations']} iterations ({full['message']})")
    assert convergence_note(early) == (
        f"converged after {early['iterations']} iterations ({early['message']})")
    assert convergence_note(capped) == (
        "not converged: stopped at its iteration limit after 10 iterations (no stall test: "
        "rtol=0)")
    _, short = map_optimize(logp, x0, max_iter=10, progress=False)
    assert convergence_note(short) == (
        "not converged: stopped at its iteration limit after 10 iterations; too few iterations "
        "for the stall test (a fall below 0.001% of the objective over 100 iterations)")
    _, long = map_optimize(logp, x0, max_iter=40, rtol=1e-9, window=20, progress=False)
    fall = long["convergence"]["relative_fall_last_window"]
    assert not long["converged"] and fall > 1e-9
    assert convergence_note(long) == (
        f"not converged: stopped at its iteration limit after 40 iterations; the objective "
        f"still fell by {100 * fall:.2g}% over the last 20 iterations, where converged means "
        f"below 1e-07%")


def test_map_optimize_stops_at_its_time_budget_and_does_not_call_that_converged():
    import time

    from bayesmotion.optim.minimize import convergence_note, map_optimize

    def logp(p, jitter):
        x = p["x"]
        return -jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)

    x0 = {"x": jnp.tile(jnp.array([-1.2, 1.0]), 10)}
    t0 = time.perf_counter()
    _, d = map_optimize(logp, x0, max_iter=100000, rtol=0.0, gtol=0.0, ftol=0.0,
                        max_seconds=0.0, progress=False)
    assert d["iterations"] == 1  # the first iteration is past a zero budget
    assert not d["converged"] and d["convergence"]["time_limit_reached"]
    assert d["message"] == "STOP: TIME LIMIT OF 0 S REACHED"
    assert convergence_note(d).startswith("not converged: stopped at its time limit after 1 "
                                          "iterations")
    assert time.perf_counter() - t0 < 60


def test_convergence_note_reads_older_and_abnormal_diagnostics():
    """Diagnostics without the stall test's entries (older model files), a scipy stop other
    than the limits, and an empty record each get a sentence that claims nothing unrecorded."""
    from bayesmotion.optim.minimize import convergence_note

    old = {"iterations": 1000, "converged": False, "message": "STOP: TOTAL NO. OF ITERATIONS "
           "REACHED LIMIT"}
    assert convergence_note(old) == (
        "not converged: stopped (STOP: TOTAL NO. OF ITERATIONS REACHED LIMIT) after 1000 "
        "iterations; the stall test's result is not recorded")
    search = {"iterations": 37, "converged": False, "message": "ABNORMAL_TERMINATION_IN_LNSRCH",
              "convergence": {"met": False, "relative_fall_last_window": None,
                              "max_iter_reached": False, "time_limit_reached": False}}
    assert convergence_note(search) == (
        "not converged: stopped (ABNORMAL_TERMINATION_IN_LNSRCH) after 37 iterations; too few "
        "iterations for the stall test (a fall below 0.001% of the objective over 100 "
        "iterations)")
    assert convergence_note({}) == "not converged; the stall test's result is not recorded"
    assert convergence_note({"converged": True}) == "converged"


def test_map_optimize_hands_every_iterate_to_the_callback_without_changing_the_run():
    from bayesmotion.optim.minimize import map_optimize

    def logp(p, jitter):  # 6-D Rosenbrock in two named blocks
        x = jnp.concatenate([p["a"], p["b"]])
        return -jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)

    x0 = {"a": jnp.array([-1.2, 1.0, -1.2]), "b": jnp.array([1.0, -1.2, 1.0])}
    seen = []
    keep = lambda it, params, objective: seen.append((it, params, objective))  # noqa: E731
    with_cb, d_cb = map_optimize(logp, x0, max_iter=60, rtol=0.0, progress=False,
                                 callback=keep)
    plain, d = map_optimize(logp, x0, max_iter=60, rtol=0.0, progress=False)
    assert [s[0] for s in seen] == list(range(1, d_cb["iterations"] + 1))
    assert [s[2] for s in seen] == d_cb["trace"] == d["trace"]
    for k in ("a", "b"):
        np.testing.assert_array_equal(with_cb[k], plain[k])
    # each iterate is the dict the objective was evaluated at: its value is the traced one
    for _, params, objective in seen[::7]:
        assert set(params) == {"a", "b"} and params["a"].shape == (3,)
        assert -float(logp(params, 0.0)) == pytest.approx(objective, rel=1e-12)
    # the final iterate is the returned optimum
    np.testing.assert_array_equal(seen[-1][1]["b"], with_cb["b"])


def test_the_objective_is_traced_once_per_compilation():
    """One evaluation per pass of the loop: the start's and every line-search trial's go
    through one call site, so a compiled run holds the objective once. nfev counts them all:
    on Rosenbrock (d = 2) the run makes 33 evaluations in 27 iterations, as the two-loop
    implementation with the start evaluated outside the loop did."""
    traces = []

    def f(x):
        traces.append(1)
        return rosenbrock(x)

    r = jax.jit(lambda x0: lbfgs.minimize(jax.value_and_grad(f), x0, 2000))(jnp.full(2, -1.2))
    assert len(traces) == 1
    assert int(r.nit) == 27 and int(r.nfev) == 33
