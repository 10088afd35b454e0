"""Which rotated style coordinates the independence step draws: the Laplace-sd threshold.

    python benchmarks/run_all.py --only pinned_threshold

The default sampler's independence step (``bayesmotion.inference.moves.IndependenceMove``)
draws the hyperparameters, the two-level styles and those rotated style coordinates whose
Laplace sd at the conditional MAP is below ``bayesmotion.inference.proposals.PINNED_SD``; the
others are left to DE and the style rotations. This runs the whole posterior of the quick
demo's model (``load_handshakes(seed=0, fps=10)`` without its 4 held-out trials,
``HGPDM().fit(max_iter=150, seed=0)``; 26 coordinates, 54 walkers) for 600 steps (quick: 200)
at each threshold and seed, side by side in one run, and reports the slowest coordinate's
autocorrelation time, max R-hat and min bulk ESS (after the package's burn-in), the block's
size and the independence step's acceptance.

Current result (``results/pinned_threshold.json``): see ``["headline"]``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

THRESHOLDS = (0.1, 0.2)
SEEDS = (0, 1)
STEPS = {"quick": 200, "full": 600}


def run(quick: bool) -> dict:
    from _common import headline

    import bayesmotion.inference.proposals as proposals
    from bayesmotion import HGPDM, load_handshakes
    from bayesmotion.app.demo import SETTINGS, _split
    from bayesmotion.inference.diagnostics import convergence
    from bayesmotion.inference.sample import sample_posterior

    cfg = SETTINGS["quick"]
    steps = STEPS["quick" if quick else "full"]
    train, _ = _split(load_handshakes(seed=0, fps=cfg["fps"]))
    model = HGPDM().fit(train, max_iter=cfg["max_iter"], seed=0, progress=False)
    default = proposals.PINNED_SD
    rows = []
    try:
        for threshold in THRESHOLDS:
            proposals.PINNED_SD = threshold
            for seed in SEEDS:
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    post = sample_posterior(model, n_steps=steps, seed=seed, progress=False)
                tau = np.asarray(post.info["tau"])
                c = convergence(post)
                block = post.info.get("independence_block")
                rows.append({"pinned_sd": threshold, "seed": seed, "n_steps": steps,
                             "seconds": time.perf_counter() - t0,
                             "max_tau": float(tau.max()),
                             "slowest": post.target.names[int(np.argmax(tau))],
                             "tau": dict(zip(post.target.names, map(float, tau), strict=True)),
                             "max_rhat": c["max_rhat"], "min_ess_bulk": c["min_ess_bulk"],
                             "min_ess_tail": c["min_ess_tail"],
                             "independence_block": block,
                             "independence_acceptance": post.info.get("independence_acceptance")})
    finally:
        proposals.PINNED_SD = default
    out = {"settings": {"model": f"quick demo: load_handshakes(seed=0, fps={cfg['fps']}), 20 "
                                 f"training trials, HGPDM().fit(max_iter={cfg['max_iter']}, "
                                 f"seed=0)", "n_steps": steps, "seeds": list(SEEDS),
                        "thresholds": list(THRESHOLDS), "package_default": default},
           "runs": rows, "headline": []}
    for threshold in THRESHOLDS:
        mine = [r for r in rows if r["pinned_sd"] == threshold]
        out["headline"].append(headline(
            f"whole posterior, PINNED_SD = {threshold}: min bulk ESS after {steps} steps "
            f"(seeds {', '.join(map(str, SEEDS))})",
            float(np.mean([r["min_ess_bulk"] for r in mine])), "", "", None,
            "; ".join(f"seed {r['seed']}: ESS {r['min_ess_bulk']:.0f}, max tau "
                      f"{r['max_tau']:.0f} ({r['slowest']}), R-hat {r['max_rhat']:.2f}"
                      for r in mine)))
    return out
