"""The quick demo's posterior: the hyperparameters with the style vectors held at the MAP
(``sample_posterior(fix_styles=True)``, what ``bayesmotion demo --quick`` samples) side by side
with the whole posterior (style vectors sampled too), same model, same run: for the demo's
steps and for twice as many (``WHOLE_STEPS``), each a run of its own (a run's adaptation and
burn-in scale with its length).

The model is the quick demo's: ``load_handshakes(seed=0, fps=10)`` without its 4 held-out
trials (20 trials, N = 340 frames per actor), ``HGPDM().fit(max_iter=150, seed=0)``. Each
posterior is sampled with ``sample_posterior``'s defaults (DE, style rotations where styles are
sampled, the independence step) for the demo's 200 steps (quick: 100), and the whole posterior
also for 400 (``WHOLE_STEPS``), seed 0; R-hat and ESS
are ``bayesmotion.inference.diagnostics.convergence`` of the chain after the package's burn-in.
Target (issue: the posterior in minutes): the quick demo reports max R-hat <= 1.05 and min bulk
ESS >= 400.

The full demo's chain (the whole posterior of ``HGPDM().fit(max_iter=1000, seed=0)`` on the same
20 trials, ``SETTINGS["full"]["n_steps"]`` steps, seed 0) is the one ``posterior_convergence``
follows: its checkpoint at that step count is what the full demo reports.

Current result (``results/demo_posterior.json``): see ``["headline"]`` and
``docs/results.md``.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

STEPS = {"quick": 100, "full": 200}
WHOLE_STEPS = {"quick": (100,), "full": (200, 400)}
TARGET_RHAT, TARGET_ESS = 1.05, 400


def run(quick: bool) -> dict:
    from _common import headline

    from bayesmotion import HGPDM, load_handshakes
    from bayesmotion.app.demo import SETTINGS, _split
    from bayesmotion.inference.diagnostics import convergence
    from bayesmotion.inference.sample import sample_posterior

    cfg = SETTINGS["quick"]
    steps = STEPS["quick" if quick else "full"]
    train, _ = _split(load_handshakes(seed=0, fps=cfg["fps"]))
    t0 = time.perf_counter()
    model = HGPDM().fit(train, max_iter=cfg["max_iter"], seed=0, progress=False)
    fit_s = time.perf_counter() - t0
    rows = {}
    runs = [("styles_held_at_map", True, steps)] + [
        ("whole_posterior" if n == steps else f"whole_posterior_{n}", False, n)
        for n in WHOLE_STEPS["quick" if quick else "full"]]
    for name, fix, n_steps in runs:
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            post = sample_posterior(model, n_steps=n_steps, seed=0, fix_styles=fix,
                                    progress=False)
        c = convergence(post)
        rows[name] = {"fix_styles": fix, "ndim": post.target.ndim,
                      "n_walkers": post.info["n_walkers"], "n_steps": n_steps,
                      "seconds": time.perf_counter() - t0,
                      "seconds_per_step": post.info["pace"]["seconds_per_step"],
                      "burn": post.info["burn"], "max_tau": float(np.max(post.info["tau"])),
                      "max_rhat": c["max_rhat"], "min_ess_bulk": c["min_ess_bulk"],
                      "min_ess_tail": c["min_ess_tail"],
                      "chain_too_short_warning": any("autocorrelation" in str(w.message)
                                                     for w in caught)}
    held, whole = rows["styles_held_at_map"], rows["whole_posterior"]
    met = held["max_rhat"] <= TARGET_RHAT and held["min_ess_bulk"] >= TARGET_ESS
    out = {"settings": {"model": f"quick demo: load_handshakes(seed=0, fps={cfg['fps']}), 20 "
                                 f"training trials, HGPDM().fit(max_iter={cfg['max_iter']}, "
                                 f"seed=0)", "n_steps": steps,
                        "whole_posterior_steps": list(WHOLE_STEPS["quick" if quick else "full"]),
                        "seed": 0,
                        "targets": {"max_rhat": TARGET_RHAT, "min_ess_bulk": TARGET_ESS}},
           "fit_seconds": fit_s, "samplers": rows}
    out["headline"] = [
        headline(f"quick demo posterior, styles held at the MAP ({held['ndim']} dims): max "
                 f"R-hat after {steps} steps", held["max_rhat"], "", f"<= {TARGET_RHAT}", met,
                 f"min bulk ESS {held['min_ess_bulk']:.0f} (target >= {TARGET_ESS}), tail "
                 f"{held['min_ess_tail']:.0f}; max tau {held['max_tau']:.1f} steps; "
                 f"{held['seconds']:.0f} s"),
        headline(f"  whole posterior ({whole['ndim']} dims), same model and steps",
                 whole["max_rhat"], "", f"<= {TARGET_RHAT}",
                 whole["max_rhat"] <= TARGET_RHAT and whole["min_ess_bulk"] >= TARGET_ESS,
                 f"min bulk ESS {whole['min_ess_bulk']:.0f}; max tau {whole['max_tau']:.0f} "
                 f"steps; {whole['seconds']:.0f} s"),
    ]
    for name, r in rows.items():
        if name.startswith("whole_posterior_"):
            short = r["chain_too_short_warning"]
            out["headline"].append(headline(
                f"  whole posterior, same model, {r['n_steps']} steps", r["max_rhat"], "",
                f"<= {TARGET_RHAT}",
                r["max_rhat"] <= TARGET_RHAT and r["min_ess_bulk"] >= TARGET_ESS,
                f"min bulk ESS {r['min_ess_bulk']:.0f}, tail {r['min_ess_tail']:.0f}; max tau "
                f"{r['max_tau']:.0f} steps; {r['seconds']:.0f} s"
                + ("; the package warned the chain is shorter than 50 autocorrelation times"
                   if short else "")))
    return out
