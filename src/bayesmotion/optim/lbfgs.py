"""L-BFGS in pure JAX: the whole minimisation is one ``lax.while_loop``, so a jitted caller pays
one dispatch per run instead of one host round trip per evaluation.

Used by the projection of observed clips (bayesmotion.emotion.projection), where the density is
cheap (0.7
ms per value and gradient for a 20-frame handshake) and scipy's L-BFGS-B spent as long again in
dispatch and on the host. The algorithm is the textbook one (Nocedal & Wright 2006, Alg. 7.4 and
7.5): the two-loop recursion over the last ``memory`` curvature pairs with the initial scaling
s'y / y'y, a weak Wolfe line search by bracketing (Lewis & Overton 2013: the step doubled while
it satisfies Armijo's condition and the slope is still steep, bisected once it fails Armijo),
and a pair kept only when s'y > 0; after a failed line search the memory is dropped and the
iteration retried along steepest descent. Stopping rules follow scipy's L-BFGS-B: the largest
gradient entry below ``gtol``, or a relative reduction of the objective below ``ftol``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

# status codes
CONVERGED_GTOL, MAX_ITER, CONVERGED_FTOL, LINE_SEARCH_FAILED, NONFINITE_START = 0, 1, 2, 3, 4
MESSAGES = {CONVERGED_GTOL: "gradient below gtol", MAX_ITER: "iteration limit reached",
            CONVERGED_FTOL: "relative reduction below ftol",
            LINE_SEARCH_FAILED: "line search found no decrease along steepest descent",
            NONFINITE_START: "the objective is not finite at the start"}


class LbfgsResult(NamedTuple):
    x: jnp.ndarray
    fun: jnp.ndarray
    grad: jnp.ndarray
    nit: jnp.ndarray
    nfev: jnp.ndarray
    status: jnp.ndarray  # one of the codes above


class _State(NamedTuple):
    x: jnp.ndarray
    f: jnp.ndarray
    g: jnp.ndarray
    S: jnp.ndarray  # (memory, d) steps, a ring buffer
    Y: jnp.ndarray  # (memory, d) gradient changes
    rho: jnp.ndarray  # (memory,) 1 / s'y
    n: jnp.ndarray  # pairs stored (at most memory)
    head: jnp.ndarray  # slot the next pair goes to
    nit: jnp.ndarray
    nfev: jnp.ndarray
    status: jnp.ndarray  # -1 while running


def _direction(g, S, Y, rho, n, head):
    """-H g by the two-loop recursion over the ``n`` newest pairs of the ring buffer."""
    m = S.shape[0]

    def newest_first(i, carry):
        q, alpha = carry
        k = (head - 1 - i) % m
        a = jnp.where(i < n, rho[k] * jnp.dot(S[k], q), 0.0)
        return q - a * Y[k], alpha.at[k].set(a)

    q, alpha = jax.lax.fori_loop(0, m, newest_first, (g, jnp.zeros(m, g.dtype)))
    last = (head - 1) % m
    yy = jnp.dot(Y[last], Y[last])
    gamma = jnp.where((n > 0) & (yy > 0), jnp.dot(S[last], Y[last]) / jnp.where(yy > 0, yy, 1.0),
                      1.0)

    def oldest_first(j, r):
        i = m - 1 - j
        k = (head - 1 - i) % m
        b = rho[k] * jnp.dot(Y[k], r)
        return r + jnp.where(i < n, alpha[k] - b, 0.0) * S[k]

    return -jax.lax.fori_loop(0, m, oldest_first, gamma * q)


class _Run(NamedTuple):
    """The loop's state: the accepted point and curvature memory (:class:`_State`), and the
    line search in progress (along ``p`` with slope ``slope``, trying step ``t`` in the bracket
    ``(lo, hi)``, ``f_lo``/``g_lo`` at ``lo``, ``k`` evaluations so far); ``started`` is 0 until
    the start has been evaluated."""
    s: _State
    p: jnp.ndarray
    slope: jnp.ndarray
    t: jnp.ndarray
    lo: jnp.ndarray
    hi: jnp.ndarray
    f_lo: jnp.ndarray
    g_lo: jnp.ndarray
    k: jnp.ndarray
    started: jnp.ndarray


def minimize(fun_and_grad: Callable, x0: jnp.ndarray, max_iter, *, memory: int = 10,
             gtol: float = 1e-5, ftol: float | None = None,
             max_line_search: int = 30, c1: float = 1e-4, c2: float = 0.9) -> LbfgsResult:
    """Minimise ``f`` from ``x0`` (1-D) with ``fun_and_grad(x) -> (f, grad)``; pure JAX (call
    it under ``jit``; ``max_iter`` may be traced). A non-finite value counts as +inf: the line
    search backs away from it. When a line search fails with curvature pairs stored, they are
    dropped and the iteration retried along steepest descent (as L-BFGS-B does); the run stops
    only when that fails too. Returns the last accepted point, never one worse than ``x0``.
    ``ftol`` defaults to L-BFGS-B's 2.2e-9 (factr 1e7 in float64), at least 10 machine epsilons
    of ``x0``'s dtype (float32 on an accelerator).

    Each pass of the one ``lax.while_loop`` makes exactly one evaluation (the start's, then the
    line searches' trial steps), so ``fun_and_grad`` is traced, and compiled, once: a second
    call site would put the objective's program in twice, and compiling is most of a first
    projection's time (``benchmarks/results/first_call.json``).
    """
    if ftol is None:
        ftol = max(2.220446049250313e-09, 10.0 * float(jnp.finfo(x0.dtype).eps))
    if max_line_search < 1:
        raise ValueError(f"max_line_search must be at least 1, got {max_line_search}")
    d = x0.shape[0]
    dt = x0.dtype

    def start_search(s: _State, r: _Run) -> _Run:
        """The next line search from the accepted point: the quasi-Newton direction (steepest
        descent when it is not a descent direction) and the first trial step."""
        p = _direction(s.g, s.S, s.Y, s.rho, s.n, s.head)
        slope = jnp.dot(s.g, p)
        bad = ~(slope < 0)  # not a descent direction: restart from steepest descent
        p = jnp.where(bad, -s.g, p)
        slope = jnp.where(bad, -jnp.dot(s.g, s.g), slope)
        # no curvature known (the first iteration, or after a reset): a step of at most unit
        # length, 1 / |p| as in L-BFGS-B when the gradient is longer than 1
        t0 = jnp.where(s.n > 0, 1.0, jnp.minimum(1.0, 1.0 / jnp.linalg.norm(p)))
        return r._replace(s=s, p=p, slope=slope, t=jnp.asarray(t0, dt),
                          lo=jnp.asarray(0.0, dt), hi=jnp.asarray(jnp.inf, dt), f_lo=s.f,
                          g_lo=s.g, k=jnp.asarray(0))

    def first(s: _State, f0, g0) -> _State:
        """The state with the start's value and gradient: stopped at a non-finite start, a
        small gradient or a zero iteration limit, else running (the first line search
        follows)."""
        status = jnp.where(jnp.isfinite(f0), -1, NONFINITE_START)
        status = jnp.where((status < 0) & (jnp.max(jnp.abs(g0)) <= gtol), CONVERGED_GTOL,
                           status)
        status = jnp.where((status < 0) & (max_iter <= 0), MAX_ITER, status)
        return s._replace(f=f0, g=g0, status=status)

    def trial(r: _Run, f_t, g_t) -> tuple[_State, _Run, jnp.ndarray]:
        """One line-search trial evaluated: weak Wolfe by bracketing (Lewis & Overton 2013):
        double the step while the Armijo condition holds and the slope is still steep, bisect
        once a step fails Armijo. The search ends at a Wolfe step or after ``max_line_search``
        trials (then with the longest step found that satisfies Armijo, if any), and the
        iteration with it. Returns (the state after the iteration, the search continued, whether
        it ended)."""
        s = r.s
        t = r.t
        armijo = f_t <= s.f + c1 * t * r.slope
        steep = jnp.dot(g_t, r.p) < c2 * r.slope
        wolfe = armijo & ~steep
        hi = jnp.where(armijo, r.hi, t)
        grow = armijo & steep
        lo, f_lo = jnp.where(grow, t, r.lo), jnp.where(grow, f_t, r.f_lo)
        g_lo = jnp.where(grow, g_t, r.g_lo)
        k = r.k + 1
        searching = r._replace(t=jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), 2.0 * lo),
                               lo=lo, hi=hi, f_lo=f_lo, g_lo=g_lo, k=k)
        # the iteration's end (Nocedal & Wright Alg. 7.4's update of the memory)
        t_acc = jnp.where(wolfe, t, lo)
        f_acc, g_acc = jnp.where(wolfe, f_t, f_lo), jnp.where(wolfe, g_t, g_lo)
        accepted = t_acc > 0
        x_t = s.x + t_acc * r.p
        sv, yv = x_t - s.x, g_acc - s.g
        sy = jnp.dot(sv, yv)
        keep = accepted & (sy > 1e-10 * jnp.dot(yv, yv))
        S = s.S.at[s.head].set(jnp.where(keep, sv, s.S[s.head]))
        Y = s.Y.at[s.head].set(jnp.where(keep, yv, s.Y[s.head]))
        rho = s.rho.at[s.head].set(jnp.where(keep, 1.0 / jnp.where(keep, sy, 1.0),
                                             s.rho[s.head]))
        retry = ~accepted & (s.n > 0)  # drop the memory, try steepest descent next
        n = jnp.where(keep, jnp.minimum(s.n + 1, memory), jnp.where(retry, 0, s.n))
        head = jnp.where(keep, (s.head + 1) % memory, s.head)
        x = jnp.where(accepted, x_t, s.x)
        f = jnp.where(accepted, f_acc, s.f)
        g = jnp.where(accepted, g_acc, s.g)
        nit = s.nit + 1
        reduction = (s.f - f) / jnp.maximum(jnp.maximum(jnp.abs(s.f), jnp.abs(f)), 1.0)
        status = jnp.where(
            ~accepted & ~retry, LINE_SEARCH_FAILED,
            jnp.where(accepted & (jnp.max(jnp.abs(g)) <= gtol), CONVERGED_GTOL,
                      jnp.where(accepted & (reduction <= ftol), CONVERGED_FTOL,
                                jnp.where(nit >= max_iter, MAX_ITER, -1))))
        done = _State(x, f, g, S, Y, rho, n, head, nit, s.nfev + k, status)
        return done, searching, wolfe | (k >= max_line_search)

    def body(r: _Run) -> _Run:
        started = r.started > 0
        f, g = fun_and_grad(jnp.where(started, r.s.x + r.t * r.p, r.s.x))  # the one call
        ok = jnp.isfinite(f) & jnp.all(jnp.isfinite(g))
        f = jnp.where(ok, f, jnp.inf)
        done, searching, end = trial(r, f, g)
        s = jax.tree_util.tree_map(lambda a, b: jnp.where(started, a, b), done, first(r.s, f, g))
        # a new line search after the start and after each completed iteration (one
        # direction computed per pass)
        nxt = jax.tree_util.tree_map(lambda a, b: jnp.where(started & ~end, a, b), searching,
                                     start_search(s, r))
        return nxt._replace(started=jnp.asarray(1))

    zeros = jnp.zeros(d, dt)
    # nfev counts the start's evaluation from the outset (the first pass makes it)
    state = _State(x0, jnp.asarray(jnp.inf, dt), zeros, jnp.zeros((memory, d), dt),
                   jnp.zeros((memory, d), dt), jnp.zeros(memory, dt), jnp.asarray(0),
                   jnp.asarray(0), jnp.asarray(0), jnp.asarray(1), jnp.asarray(-1))
    run = _Run(state, zeros, jnp.asarray(0.0, dt), jnp.asarray(0.0, dt), jnp.asarray(0.0, dt),
               jnp.asarray(jnp.inf, dt), jnp.asarray(jnp.inf, dt), zeros, jnp.asarray(0),
               jnp.asarray(0))
    out = jax.lax.while_loop(lambda r: r.s.status < 0, body, run).s
    return LbfgsResult(out.x, out.f, out.g, out.nit, out.nfev, out.status)
