"""Where a MAP fit of the built-in handshakes is still going when it stops: the objective's
fall layer by layer, the noise variances and the latents, along one fit.

``fit_time`` finds that no fit meets the package's stall test (the objective falling by less
than 1e-5 of its magnitude over 100 iterations) within its budget. This benchmark looks at
what still moves:

1. **The default fit**, ``HGPDM().fit(load_handshakes())``'s objective and start, run for
   ``FULL["iterations"]`` L-BFGS iterations with the stall test off; every
   ``FULL["every"]`` iterations (``map_optimize``'s ``callback``) it records each layer's
   log-likelihood and the log-prior (``LogPosterior.layer_terms``), each layer's noise
   variance, signal variance and inverse squared lengthscales, and how far the latents moved
   since the last record (RMS).
2. **The same fit with the noise held**: from the iterate at ``FULL["hold_at"]``, the three
   noise precisions (gamma_3, beta_3 and the dynamics' noise) are held at their values there
   and everything else is optimised on, with the stall test on, for as many iterations as
   the default fit ran after that point. If the noise variances are what keeps the default
   fit from converging, this fit meets the stall test; if not, something else still moves.
3. **A noise floor**: the same fit from the same start with every layer's noise variance
   floored at ``FLOOR`` times the mean square of its outputs (the standardised poses; X and
   I as initialised), by parameterisation (precision p -> 1 / (1/p + floor)), for the
   default fit's iterations with the stall test on: whether a likelihood that cannot grow
   without bound through the noise converges within the same budget.

``--quick`` runs a few iterations of each (the numbers then say nothing about convergence).
"""

from __future__ import annotations

import time

import numpy as np

FULL = {"iterations": 3000, "every": 250, "hold_at": 1000}
QUICK = {"iterations": 30, "every": 10, "hold_at": 10}
# the entry of each layer's log hyperparameters that is its noise precision
NOISE_ENTRY = {"log_gamma": 2, "log_beta": 2, "log_alpha": -1}
FLOOR = 1e-4


def _hyper(params: dict) -> dict:
    """Each layer's noise variance, signal variance and inverse squared lengthscales."""
    out = {}
    for key, layer in (("log_gamma", "bottom"), ("log_beta", "interaction"),
                       ("log_alpha", "dynamics")):
        h = np.exp(np.asarray(params[key], dtype=np.float64))
        out[layer] = {"noise_variance": float(1.0 / h[NOISE_ENTRY[key]]),
                      "signal_variance": float(h[0]), "inverse_lengthscales": h[1:-1].tolist()}
    return out


def _record(terms_fn, it: int, params: dict, objective: float, last: dict | None) -> dict:
    terms = {k: float(v) for k, v in terms_fn(params).items()}
    rec = {"iteration": it, "objective": objective, "terms": terms, "hyper": _hyper(params)}
    if last is not None:
        rec["latent_rms_move"] = {k: float(np.sqrt(np.mean((params[k] - last[k]) ** 2)))
                                  for k in ("X", "I")}
    return rec


def _fall(trace: list, a: int, b: int) -> float:
    """The objective's fall from iteration a to b (1-based), relative to its magnitude at b."""
    return float((trace[a - 1] - trace[b - 1]) / max(abs(trace[b - 1]), 1.0))


def held_noise_logp(logp, held: dict):
    """``logp`` of a parameter dict whose noise entries are held at ``held`` (key -> log
    precision): the optimiser sees ``log_gamma`` etc. without their noise entry."""
    import jax.numpy as jnp

    def fn(params, jitter):
        full = dict(params)
        for key, value in held.items():
            i = NOISE_ENTRY[key]
            rest = params[key]
            full[key] = (jnp.concatenate([rest, jnp.asarray([value])]) if i == -1 else
                         jnp.concatenate([rest[:i], jnp.asarray([value]), rest[i:]]))
        return logp(full, jitter)
    return fn


def floored_noise_logp(logp, floors: dict):
    """``logp`` with each layer's noise variance floored (key -> floor): the log precision
    entry l of ``params`` stands for precision 1 / (exp(-l) + floor)."""
    import jax.numpy as jnp

    def fn(params, jitter):
        full = dict(params)
        for key, floor in floors.items():
            i = NOISE_ENTRY[key]
            full[key] = params[key].at[i].set(-jnp.log(jnp.exp(-params[key][i]) + floor))
        return logp(full, jitter)
    return fn


def run(quick: bool) -> dict:
    import jax
    from _common import headline

    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.data import fit_codecs, prepare_data
    from bayesmotion.model.fit import init_params
    from bayesmotion.model.logpost import LogPosterior
    from bayesmotion.model.spec import HGPDM
    from bayesmotion.optim.minimize import CONVERGENCE_RTOL, CONVERGENCE_WINDOW, map_optimize

    cfg = QUICK if quick else FULL
    ds = load_handshakes()
    spec = HGPDM().resolved(ds)
    data = prepare_data(spec, ds, fit_codecs(spec, ds))
    logp = LogPosterior(spec, data)
    terms_fn = jax.jit(lambda p: logp.layer_terms(p, 1e-8))
    records, kept = [], {}

    def checkpoint(it, params, objective):
        if it % cfg["every"] == 0:
            records.append(_record(terms_fn, it, params, objective,
                                   kept.get("last")))
            kept["last"] = params
        if it == cfg["hold_at"]:
            kept["hold"] = params

    t0 = time.perf_counter()
    start = init_params(spec, data, 0)
    _, diag = map_optimize(logp, start, max_iter=cfg["iterations"], rtol=0.0, progress=False,
                           callback=checkpoint, desc="default fit")
    seconds_default = time.perf_counter() - t0
    trace = diag["trace"]
    n = len(trace)
    w = min(CONVERGENCE_WINDOW, n - 1)

    hold = kept["hold"]
    held = {k: float(hold[k][i]) for k, i in NOISE_ENTRY.items()}
    free = {k: (np.delete(v, NOISE_ENTRY[k]) if k in NOISE_ENTRY else v)
            for k, v in hold.items()}
    t0 = time.perf_counter()
    _, held_diag = map_optimize(held_noise_logp(logp, held), free,
                                max_iter=n - cfg["hold_at"], progress=False,
                                window=CONVERGENCE_WINDOW if not quick else 5,
                                desc="noise held")
    seconds_held = time.perf_counter() - t0
    ht = held_diag["trace"]

    floors = {"log_gamma": FLOOR * float(np.mean([np.mean(y ** 2) for y in data.Y])),
              "log_beta": FLOOR * float(np.mean(start["X"] ** 2)),
              "log_alpha": FLOOR * float(np.mean(start["I"] ** 2))}
    t0 = time.perf_counter()
    floor_params, floor_diag = map_optimize(floored_noise_logp(logp, floors), start,
                                            max_iter=n, progress=False, desc="noise floor")
    seconds_floor = time.perf_counter() - t0
    ft = floor_diag["trace"]
    floored_var = {k: float(np.exp(-floor_params[k][i]) + floors[k])
                   for k, i in NOISE_ENTRY.items()}

    last = records[-1]
    at_hold = {r["iteration"]: r for r in records}[cfg["hold_at"]]  # a multiple of "every"
    by_layer = {k: last["terms"][k] - at_hold["terms"][k] for k in last["terms"]}
    noise_ratio = {layer: last["hyper"][layer]["noise_variance"]
                   / at_hold["hyper"][layer]["noise_variance"] for layer in last["hyper"]}
    out = {
        "settings": {**cfg, "stall_test": {"rtol": CONVERGENCE_RTOL,
                                           "window": CONVERGENCE_WINDOW},
                     "data": {"trials": len(ds), "N": int(data.lengths.sum()),
                              "D_per_actor": [int(y.shape[1]) for y in data.Y]},
                     "n_parameters": diag["n_parameters"]},
        "default": {"iterations": n, "seconds": seconds_default,
                    "objective": trace[-1], "relative_fall_last_window": _fall(trace, n - w, n),
                    "gain_after_hold_at": {"total": trace[cfg["hold_at"] - 1] - trace[-1],
                                           "log_density_by_term": by_layer},
                    "noise_variance_ratio_after_hold_at": noise_ratio,
                    "checkpoints": records},
        "noise_held": {"held_log_precisions": held, "iterations": held_diag["iterations"],
                       "seconds": seconds_held, "objective": held_diag["objective"],
                       "converged": held_diag["converged"],
                       "convergence": held_diag["convergence"], "message":
                       held_diag["message"],
                       "relative_fall_last_window": (
                           _fall(ht, len(ht) - w, len(ht)) if len(ht) > w else None),
                       "trace_every": [ht[i] for i in range(0, len(ht), cfg["every"])]},
    }
    out["noise_floor"] = {
        "floor_relative": FLOOR, "floors": floors, "noise_variances": floored_var,
        "iterations": floor_diag["iterations"], "seconds": seconds_floor,
        "objective": floor_diag["objective"], "converged": floor_diag["converged"],
        "convergence": floor_diag["convergence"], "message": floor_diag["message"],
        "relative_fall_last_window": _fall(ft, len(ft) - w, len(ft)) if len(ft) > w else None,
        "trace_every": [ft[i] for i in range(0, len(ft), cfg["every"])]}
    note = ", ".join(f"{layer} x{r:.2g}" for layer, r in noise_ratio.items())
    fall_held = out["noise_held"]["relative_fall_last_window"]
    out["headline"] = [
        headline(f"default fit, iterations {n - w}-{n}: objective's relative fall",
                 out["default"]["relative_fall_last_window"], "", f"< {CONVERGENCE_RTOL:g}",
                 out["default"]["relative_fall_last_window"] < CONVERGENCE_RTOL,
                 f"noise variances from iteration {cfg['hold_at']} to {n}: {note}"),
        headline(f"noise held from iteration {cfg['hold_at']}: iterations to the stall test",
                 held_diag["iterations"] if held_diag["converged"] else None, "",
                 f"<= {n - cfg['hold_at']}", bool(held_diag["converged"]),
                 held_diag["message"] if fall_held is None else
                 f"relative fall over its last window {fall_held:.2g}; {held_diag['message']}"),
        headline(f"noise floored at {FLOOR:g} of each layer's outputs: iterations to the stall "
                 f"test", floor_diag["iterations"] if floor_diag["converged"] else None, "",
                 f"<= {n}", bool(floor_diag["converged"]),
                 f"relative fall over its last window "
                 f"{out['noise_floor']['relative_fall_last_window']:.2g}; "
                 f"{floor_diag['message']}"),
    ]
    return out


if __name__ == "__main__":
    import sys

    from _common import show_headlines, standalone_main

    sys.exit(standalone_main("fit_convergence", run, __doc__, "a few iterations of each fit",
                             show_headlines))
