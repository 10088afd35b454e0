"""Cost of one log-posterior value + gradient (eq. 12) against the number of frames N.

Synthetic two-actor data (D = 96 per actor like the built-in set) in 8 emotion x couple cells
(trials of ~31 frames), one-hot styles, the default HGPDM spec. Both paths of
``LogPosterior(spec, data, dense=...)``: dense kernel matrices for every layer, and
block-diagonal interaction/dynamics layers (8 blocks of ~N/8 rows; the bottom layer is dense in
both). Timed: ``jit(value_and_grad)`` over one flat vector, as the MAP fit calls it. The
exponent k of time ~ N^k is a least-squares fit on log-log over the measured sizes (and over
the two largest sizes, the asymptotic slope).
"""

from __future__ import annotations

import time

import numpy as np

SIZES_FULL = (250, 500, 1000, 2000)
SIZES_QUICK = (250, 500)


def value_and_grad_fn(N: int, dense: bool):
    import jax
    import jax.numpy as jnp
    from _common import synthetic_model_data
    from jax.flatten_util import ravel_pytree

    from bayesmotion.model.fit import init_params
    from bayesmotion.model.logpost import LogPosterior
    from bayesmotion.model.spec import HGPDM

    spec = HGPDM(interaction_factors=("couple", "emotion"),
                 dynamics_factors=("couple", "emotion"), root_mode="partner")
    data = synthetic_model_data(N)
    logp = LogPosterior(spec, data, dense=dense)
    x0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in init_params(spec, data).items()})
    vg = jax.jit(jax.value_and_grad(lambda x, j: -logp(unravel(x), j)))
    return vg, x0


def loglog_slope(n, t) -> float:
    """Least-squares slope of log t on log n."""
    return float(np.polyfit(np.log(n), np.log(t), 1)[0])


def measure(N: int, dense: bool, repeats: int) -> dict:
    from _common import block, timeit

    vg, x0 = value_and_grad_fn(N, dense)
    t0 = time.perf_counter()
    v, _ = block(vg(x0, 1e-8))
    compile_s = time.perf_counter() - t0
    t = timeit(lambda: block(vg(x0, 1e-8)), repeats=repeats, warmup=1)
    return {"N": N, "dense": dense, **t, "first_call_s_incl_compile": compile_s,
            "neg_log_posterior": float(v)}


def run(quick: bool) -> dict:
    from _common import headline

    sizes = SIZES_QUICK if quick else SIZES_FULL
    rows, fits = [], {}
    for dense in (False, True):
        for N in sizes:
            rows.append(measure(N, dense, repeats=3 if (quick or N >= 2000) else 5))
        t = [r["median_s"] for r in rows if r["dense"] == dense]
        name = "dense" if dense else "block_diagonal"
        fits[name] = {"exponent_all_sizes": loglog_slope(sizes, t),
                      "exponent_two_largest": loglog_slope(sizes[-2:], t[-2:])}
    by = {(r["N"], r["dense"]): r["median_s"] for r in rows}
    nmax = sizes[-1]
    bd, de = fits["block_diagonal"], fits["dense"]
    return {
        "settings": {"sizes": list(sizes), "D_per_actor": 96, "actors": 2, "cells": 8,
                     "trial_len": 31, "Q_X": 6, "Q_I": 6, "order": 2, "jitter": 1e-8,
                     "quick": quick},
        "measurements": rows,
        "exponent": fits,
        "headline": [
            headline(f"log-posterior value+grad, N={nmax}, block-diagonal",
                     by[(nmax, False)], "s"),
            headline("  same, dense", by[(nmax, True)], "s"),
            headline("  exponent k (time ~ N^k), block-diagonal",
                     bd["exponent_all_sizes"], "",
                     note=f"two largest sizes: {bd['exponent_two_largest']:.2f}"),
            headline("  exponent k, dense", de["exponent_all_sizes"], "",
                     note=f"two largest sizes: {de['exponent_two_largest']:.2f}"),
        ],
    }
