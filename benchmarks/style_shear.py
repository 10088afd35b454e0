"""Mixing per step of the default emcee sampler with and without the style shear
(``bayesmotion.inference.moves.shear``), same model, same seeds, same run.

The model is the full demo's (``load_handshakes(seed=0, fps=10)`` without its 4 held-out trials,
20 trials, ``HGPDM().fit(max_iter=1000, seed=0)``, read from ``posterior_convergence``'s cache
when it is there): the demo-size posterior, 26 coordinates, 54 walkers. Each sampler runs
``sample_posterior``'s defaults for ``steps`` steps per seed:

* ``sheared`` (the default): differential evolution and the independence step propose in
  coordinates where the output scales' logs carry the log mean style diagonal;
* ``previous``: the same moves in the sampled coordinates (``StyleShear.for_target`` patched to
  find no shear), i.e. the sampler before the shear.

The diagnostics are read from the raw chain with the same burn-in for both (the independence
step's adaptation, 150 steps): per-coordinate integrated autocorrelation time (emcee), max
R-hat and min bulk ESS over the 26 sampled coordinates (arviz, each walker a chain). Mixing is
measured as the slowest coordinate's bulk ESS per step, against a target of 4 times the
unsheared sampler's.

Current result (``results/style_shear.json``): see ``["headline"]`` and ``docs/results.md``.
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

SETTINGS = {"full": {"steps": 800, "seeds": (0, 1)}, "quick": {"steps": 200, "seeds": (0,)}}
BURN = 150


def chain_stats(chain: np.ndarray, names: list[str]) -> dict:
    """Diagnostics of a raw (steps, walkers, dim) chain after ``BURN`` steps."""
    import arviz as az
    import emcee

    from bayesmotion.inference.diagnostics import arviz_without_numba

    kept = chain[BURN:]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = emcee.autocorr.integrated_time(kept, quiet=True)
    x = np.swapaxes(kept, 0, 1)  # (walkers, steps, dim): each walker a chain
    with arviz_without_numba():
        ess = np.array([float(az.ess(x[..., i], method="bulk")) for i in range(x.shape[-1])])
        rhat = np.array([float(az.rhat(x[..., i])) for i in range(x.shape[-1])])
    slow = int(np.argmin(ess))
    return {"kept_steps": int(kept.shape[0]), "max_tau": float(tau.max()),
            "mean_tau": float(tau.mean()), "slowest_tau_coordinate": names[int(tau.argmax())],
            "min_ess_bulk": float(ess.min()), "min_ess_coordinate": names[slow],
            "min_ess_bulk_per_step": float(ess.min() / kept.shape[0]),
            "max_rhat": float(rhat.max()), "tau": tau.tolist()}


def sample(model, steps: int, seed: int, sheared: bool) -> dict:
    import emcee

    from bayesmotion.inference.moves import shear as shear_mod
    from bayesmotion.inference.sample import sample_posterior

    found = shear_mod.StyleShear.for_target
    if not sheared:
        shear_mod.StyleShear.for_target = classmethod(lambda cls, target: None)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            path = str(Path(tmp) / "chain.h5")
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = sample_posterior(model, n_steps=steps, seed=seed, backend=path,
                                        progress=False)
            seconds = time.perf_counter() - t0
            chain = emcee.backends.HDFBackend(path, read_only=True, name="mcmc").get_chain()
    finally:
        shear_mod.StyleShear.for_target = found
    return {"seed": seed, "steps": steps, "seconds": seconds,
            "seconds_per_step": post.info["pace"]["seconds_per_step"],
            "independence_acceptance": post.info.get("independence_acceptance"),
            **chain_stats(chain, post.target.names)}


def run(quick: bool) -> dict:
    from _common import headline
    from posterior_convergence import demo_model, model_path

    cfg = SETTINGS["quick" if quick else "full"]
    t0 = time.perf_counter()
    model = demo_model(1000, None if quick else model_path(1000))
    fit_s = time.perf_counter() - t0
    rows = {"previous": [], "sheared": []}
    for seed in cfg["seeds"]:  # alternate, so load drifts hit both alike
        for name in ("previous", "sheared"):
            rows[name].append(sample(model, cfg["steps"], seed, name == "sheared"))

    def mean(name, key):
        return float(np.mean([r[key] for r in rows[name]]))

    ratio = mean("sheared", "min_ess_bulk_per_step") / mean("previous", "min_ess_bulk_per_step")
    tau_ratio = mean("previous", "max_tau") / mean("sheared", "max_tau")
    out = {"settings": {"model": "full demo: load_handshakes(seed=0, fps=10), 20 training "
                                 "trials, HGPDM().fit(max_iter=1000, seed=0)",
                        "steps": cfg["steps"], "seeds": list(cfg["seeds"]), "burn": BURN,
                        "n_walkers": 54, "ndim": 26},
           "fit_or_load_seconds": fit_s, "samplers": rows,
           "min_ess_per_step_ratio": ratio, "max_tau_ratio": tau_ratio}
    note = lambda name: (  # noqa: E731
        f"max tau {mean(name, 'max_tau'):.1f} (mean {mean(name, 'mean_tau'):.1f}), max R-hat "
        f"{mean(name, 'max_rhat'):.3f}, {mean(name, 'seconds_per_step'):.2f} s per step; "
        f"mean of seeds {list(cfg['seeds'])}, {cfg['steps']} steps, burn {BURN}")
    out["headline"] = [
        headline("demo-size posterior: min bulk ESS per step, default sampler (style shear)",
                 mean("sheared", "min_ess_bulk_per_step"), "1/step", "", None,
                 note("sheared")),
        headline("  the same without the shear (previous default)",
                 mean("previous", "min_ess_bulk_per_step"), "1/step", "", None,
                 note("previous")),
        headline("  ratio, sheared / previous", ratio, "x", ">= 4", ratio >= 4,
                 f"max tau {tau_ratio:.2f}x shorter"),
    ]
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(run("--quick" in sys.argv)["headline"], indent=1))
