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
    """
    if ftol is None:
        ftol = max(2.220446049250313e-09, 10.0 * float(jnp.finfo(x0.dtype).eps))

    def evaluate(x):
        f, g = fun_and_grad(x)
        ok = jnp.isfinite(f) & jnp.all(jnp.isfinite(g))
        return jnp.where(ok, f, jnp.inf), g

    f0, g0 = evaluate(x0)
    d = x0.shape[0]
    dt = x0.dtype
    state = _State(x0, f0, g0, jnp.zeros((memory, d), dt), jnp.zeros((memory, d), dt),
                   jnp.zeros(memory, dt), jnp.asarray(0), jnp.asarray(0), jnp.asarray(0),
                   jnp.asarray(1), jnp.where(jnp.isfinite(f0), -1, NONFINITE_START))
    state = state._replace(status=jnp.where(
        (state.status < 0) & (jnp.max(jnp.abs(g0)) <= gtol), CONVERGED_GTOL, state.status))

    def line_search(s: _State, p, slope):
        """Weak Wolfe step by bracketing (Lewis & Overton 2013): double the step while the
        Armijo condition holds and the slope is still steep, bisect once a step fails Armijo.
        Returns (t, f, g, evaluations, accepted); without a Wolfe step within the budget, the
        longest step found that satisfies Armijo (if any)."""
        def cond(c):
            return (c[-1] == 0) & (c[5] < max_line_search)

        def body(c):
            t, lo, hi, f_lo, g_lo, k, _ = c
            f_t, g_t = evaluate(s.x + t * p)
            armijo = f_t <= s.f + c1 * t * slope
            steep = jnp.dot(g_t, p) < c2 * slope
            wolfe = armijo & ~steep
            hi = jnp.where(armijo, hi, t)
            grow = armijo & steep
            lo, f_lo = jnp.where(grow, t, lo), jnp.where(grow, f_t, f_lo)
            g_lo = jnp.where(grow, g_t, g_lo)
            nxt = jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), 2.0 * lo)
            # done: 1 a Wolfe step at t; the others keep searching
            return (jnp.where(wolfe, t, nxt), lo, hi, jnp.where(wolfe, f_t, f_lo),
                    jnp.where(wolfe, g_t, g_lo), k + 1, wolfe.astype(jnp.int32))

        # no curvature known (the first iteration, or after a reset): a step of at most unit
        # length, 1 / |p| as in L-BFGS-B when the gradient is longer than 1
        t0 = jnp.where(s.n > 0, 1.0, jnp.minimum(1.0, 1.0 / jnp.linalg.norm(p)))
        c = jax.lax.while_loop(cond, body, (jnp.asarray(t0, dt), jnp.asarray(0.0, dt),
                                            jnp.asarray(jnp.inf, dt), s.f, s.g,
                                            jnp.asarray(0), jnp.asarray(0, jnp.int32)))
        t, lo, _, f_acc, g_acc, k, wolfe = c
        t_acc = jnp.where(wolfe == 1, t, lo)
        return t_acc, f_acc, g_acc, k, t_acc > 0

    def step(s: _State) -> _State:
        p = _direction(s.g, s.S, s.Y, s.rho, s.n, s.head)
        slope = jnp.dot(s.g, p)
        bad = ~(slope < 0)  # not a descent direction: restart from steepest descent
        p = jnp.where(bad, -s.g, p)
        slope = jnp.where(bad, -jnp.dot(s.g, s.g), slope)
        t, f_t, g_t, k, accepted = line_search(s, p, slope)
        x_t = s.x + t * p
        sv, yv = x_t - s.x, g_t - s.g
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
        f = jnp.where(accepted, f_t, s.f)
        g = jnp.where(accepted, g_t, s.g)
        nit = s.nit + 1
        reduction = (s.f - f) / jnp.maximum(jnp.maximum(jnp.abs(s.f), jnp.abs(f)), 1.0)
        status = jnp.where(
            ~accepted & ~retry, LINE_SEARCH_FAILED,
            jnp.where(accepted & (jnp.max(jnp.abs(g)) <= gtol), CONVERGED_GTOL,
                      jnp.where(accepted & (reduction <= ftol), CONVERGED_FTOL,
                                jnp.where(nit >= max_iter, MAX_ITER, -1))))
        return _State(x, f, g, S, Y, rho, n, head, nit, s.nfev + k, status)

    state = state._replace(status=jnp.where((state.status < 0) & (max_iter <= 0), MAX_ITER,
                                            state.status))
    out = jax.lax.while_loop(lambda s: s.status < 0, step, state)
    return LbfgsResult(out.x, out.f, out.g, out.nit, out.nfev, out.status)
