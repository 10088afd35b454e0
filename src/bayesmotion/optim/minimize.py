"""MAP optimisation at one flat-vector boundary: L-BFGS-B on a jitted value-and-gradient."""

from __future__ import annotations

import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jax.flatten_util import ravel_pytree
from tqdm.auto import tqdm

from bayesmotion.errors import BayesmotionError

JITTER_LADDER = (1e-8, 1e-6, 1e-4, 1e-2)  # relative to the mean diagonal of each kernel matrix
CONVERGENCE_WINDOW = 100
CONVERGENCE_RTOL = 1e-5


def stalled(trace, window: int = CONVERGENCE_WINDOW, rtol: float = CONVERGENCE_RTOL):
    """The convergence criterion of a MAP fit: the objective fell by less than ``rtol`` times
    its magnitude (at least 1) over the last ``window`` iterations. Returns (met, that
    relative fall, or None while fewer than ``window`` + 1 iterations exist)."""
    if len(trace) <= window:
        return False, None
    change = (trace[-window - 1] - trace[-1]) / max(abs(trace[-1]), 1.0)
    return bool(change < rtol), float(change)


def convergence_note(diagnostics: dict) -> str:
    """One sentence on a MAP fit's convergence from its ``diagnostics``: converged, and by which
    test; or not, where it stopped (iteration limit, time limit, scipy's message) and how fast
    the objective was still falling against the stall test's threshold. Diagnostics of older
    model files lack some of these entries; the sentence then says what is not recorded."""
    conv = diagnostics.get("convergence") or {}
    n = diagnostics.get("iterations")
    after = f" after {n} iterations" if n is not None else ""
    message = diagnostics.get("message")
    if diagnostics.get("converged"):
        return f"converged{after}" + (f" ({message})" if message else "")
    rtol = conv.get("rtol", CONVERGENCE_RTOL)
    window = conv.get("window", CONVERGENCE_WINDOW)
    where = ("at its time limit" if conv.get("time_limit_reached")
             else "at its iteration limit" if conv.get("max_iter_reached")
             else f"({message})" if message else "")
    head = "not converged: stopped " + where if where else "not converged"
    fall = conv.get("relative_fall_last_window")
    if rtol <= 0:
        rest = " (no stall test: rtol=0)"
    elif fall is not None:
        rest = (f"; the objective still fell by {100 * fall:.2g}% over the last {window} "
                f"iterations, where converged means below {100 * rtol:.2g}%")
    elif n is not None and n <= window:
        rest = (f"; too few iterations for the stall test (a fall below {100 * rtol:.2g}% of "
                f"the objective over {window} iterations)")
    else:
        rest = "; the stall test's result is not recorded"
    return f"{head}{after}{rest}"


def map_optimize(logp: Callable, params0: dict, *, max_iter: int = 1000, gtol: float = 1e-5,
                 ftol: float = 1e-10, rtol: float = CONVERGENCE_RTOL,
                 window: int = CONVERGENCE_WINDOW, max_seconds: float | None = None,
                 progress: bool = True,
                 desc: str = "MAP", value_and_grad: Callable | None = None,
                 callback: Callable[[int, dict, float], None] | None = None
                 ) -> tuple[dict, dict]:
    """Maximise ``logp(params, jitter)`` over a parameter dict.

    The dict is flattened once with ``ravel_pytree``; scipy's L-BFGS-B gets a jitted
    ``value_and_grad`` of the negative log-density. When the objective is not finite (a
    Cholesky failed) the jitter added to every kernel diagonal climbs ``JITTER_LADDER`` and the
    step is retried; each escalation is recorded in the diagnostics. The jitter is an argument
    of the jitted function, so escalation does not recompile. ``value_and_grad``: an already
    jitted ``(flat x, jitter) -> (-logp, gradient)`` over the same flattening, to share one
    compilation with other users of the density.

    Stops at scipy's own tests (``gtol`` on the projected gradient, ``ftol`` on one step's
    relative decrease), at ``max_iter``, or when the objective has fallen by less than
    ``rtol`` of its magnitude over the last ``window`` iterations (:func:`stalled`; ``rtol=0``
    turns that test off), or after the iteration that passes ``max_seconds`` of optimisation
    (compilation excluded). A fit is ``converged`` when it stopped at one of the convergence
    tests rather than at ``max_iter`` or ``max_seconds``. On the 10,000-parameter latent
    models scipy's gradient test is not met (the gradient norm stays in the thousands), so the
    stall test is the one that can end them.

    Returns:
        (params at the optimum as NumPy arrays, diagnostics dict with iterations, evaluations,
        objective, gradient norm, stop reason, converged flag, jitter events, seconds, trace).
    """
    x0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in params0.items()})
    vg = (jax.jit(jax.value_and_grad(lambda x, j: -logp(unravel(x), j)))
          if value_and_grad is None else value_and_grad)
    state = {"level": 0, "events": [], "nfev": 0, "best": (np.inf, None)}

    def fun(x):
        state["nfev"] += 1
        while True:
            j = JITTER_LADDER[state["level"]]
            v, g = vg(jnp.asarray(x), j)
            v, g = float(v), np.asarray(g, dtype=np.float64)
            if np.isfinite(v) and np.all(np.isfinite(g)):
                if v < state["best"][0]:
                    state["best"] = (v, np.array(x))
                return v, g
            if state["level"] + 1 < len(JITTER_LADDER):
                state["level"] += 1
                state["events"].append({"evaluation": state["nfev"],
                                        "jitter": JITTER_LADDER[state["level"]]})
                continue
            # Still failing at the largest jitter: report a large value so the line search
            # backs off; never hand NaN to the optimiser.
            return 1e300, np.zeros_like(x)

    trace = []
    bar = tqdm(total=max_iter, desc=desc, disable=not progress, leave=False)

    def on_iteration(intermediate_result):
        trace.append(float(intermediate_result.fun))
        if callback is not None:
            callback(len(trace), {k: np.asarray(v) for k, v in
                                  unravel(jnp.asarray(intermediate_result.x)).items()},
                     trace[-1])
        bar.update(1)
        bar.set_postfix(objective=f"{intermediate_result.fun:.4g}")
        if rtol > 0 and stalled(trace, window, rtol)[0]:
            raise StopIteration  # scipy ends the run and reports it
        if max_seconds is not None and time.perf_counter() - state["t_opt"] > max_seconds:
            state["out_of_time"] = True
            raise StopIteration

    t0 = time.perf_counter()
    initial = float(vg(x0, JITTER_LADDER[0])[0])  # compiles the objective once, then reused
    state["t_opt"] = time.perf_counter()
    res = scipy.optimize.minimize(fun, np.asarray(x0, dtype=np.float64), jac=True,
                                  method="L-BFGS-B", callback=on_iteration,
                                  options={"maxiter": max_iter, "gtol": gtol, "ftol": ftol,
                                           "maxcor": 20})
    bar.close()
    seconds = time.perf_counter() - t0
    if state["best"][1] is None:
        raise BayesmotionError(
            f"{desc}: the log-density is not finite at any point the optimiser tried, even with "
            f"jitter {JITTER_LADDER[-1]:g} on every kernel diagonal (initial objective "
            f"{initial:g}); check the priors (e.g. init_var > 0) and that the data are finite")
    x = res.x if res.fun <= state["best"][0] else state["best"][1]
    v, g = fun(x)
    met, change = stalled(trace, window, rtol) if rtol > 0 else (False, None)
    converged = bool(res.success) or met
    diagnostics = {
        "initial_objective": initial,
        "iterations": int(res.nit),
        "evaluations": int(state["nfev"]),
        "objective": float(v),
        "grad_norm": float(np.linalg.norm(g)),
        "grad_max": float(np.max(np.abs(g))) if g.size else 0.0,
        "message": (f"CONVERGED: OBJECTIVE FELL BY LESS THAN {rtol:g} (RELATIVE) OVER "
                    f"{window} ITERATIONS" if met
                    else f"STOP: TIME LIMIT OF {max_seconds:g} S REACHED"
                    if state.get("out_of_time") else str(res.message)),
        "converged": converged,
        "convergence": {"criterion": f"scipy's gtol={gtol:g} / ftol={ftol:g}, or a relative "
                                     f"fall of the objective < {rtol:g} over {window} "
                                     f"iterations",
                        "met": converged, "rtol": rtol, "window": window,
                        "relative_fall_last_window": change,
                        "max_iter_reached": int(res.nit) >= max_iter and not converged,
                        "time_limit_reached": bool(state.get("out_of_time")) and not converged},
        "jitter": JITTER_LADDER[state["level"]],
        "jitter_events": state["events"],
        "seconds": seconds,
        "n_parameters": int(x.size),
        "trace": trace,
    }
    params = {k: np.asarray(v) for k, v in unravel(jnp.asarray(x)).items()}
    return params, diagnostics
