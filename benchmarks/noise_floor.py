"""Generated motion with and without a floor on the mapping layers' noise, and after longer fits.

    python benchmarks/noise_floor.py [--quick]

The MAP fits of the H-GPDM never meet the stall test (``fit_convergence``): every layer's
noise variance keeps shrinking for as long as the fit runs. This benchmark asks what that does
to the motion the model generates, and whether a floor on the noise of the two mapping layers
(``HGPDM(mapping_noise_floor=FLOOR)``: bottom and interaction; the dynamics' noise stays free)
changes it. Each cell is one fit and its generated clips exactly as in
``benchmarks/synthesis.py`` (same groups, settings, look-ahead, judges trained on every other
real clip, naturalness ratios against the group's real clips, 1,000-frame rollouts; the walks'
transitions and mechanisms are left out), for:

* the floor 0 (the plain model, the default) and ``FLOOR``, side by side in one run;
* ``ITERATIONS`` L-BFGS iterations: the synthesis benchmark's 1,000, and 3,000 for the groups
  in ``LONG_GROUPS`` (the walks' fit takes about 5 minutes per 1,000 iterations here, so they
  are fitted for 1,000 only). How much a cell's numbers change from 1,000 to 3,000 iterations
  is how much the fits' non-convergence reaches the generated motion.
* the built-in handshakes (``HGPDM(mapping_noise_floor=...).fit(load_handshakes())``, 1,000
  iterations): the minimum right-hand distance and 1,000-frame rollouts per emotion.

Cells run two at a time in separate processes (the 2 cores). The targets are the synthesis
benchmark's naturalness and classification targets (``synthesis.TARGETS``), reported as met
or not.
``run(quick)`` writes ``results/noise_floor.json`` atomically.
"""

from __future__ import annotations

import multiprocessing
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import synthesis  # noqa: E402
from _common import (  # noqa: E402
    BANDAI_ROOT,
    RESULTS,
    bandai_present,
    bandai_skip,
    headline,
    machine_info,
    show_headlines,
    standalone_main,
    write_json,
)

NAME = "noise_floor"
FLOOR = 1e-3
FLOORS = (0.0, FLOOR)
ITERATIONS = (1000, 3000)
LONG_GROUPS = ("run", "gesture")
QUICK_ITERATIONS = (60, 120)


def bandai_cell(name: str, contents: tuple, floor: float, iterations: int, root: str,
                quick: bool) -> dict:
    """One group's fit and generated clips at one floor and iteration count."""
    import bayesmotion  # noqa: F401  (float64 on)
    from bayesmotion.features import clip_features

    cfg = replace(synthesis.QUICK if quick else synthesis.Settings(), max_iter=iterations,
                  mapping_noise_floor=floor, extras=False)
    data = synthesis.load_clips(Path(root), cfg)
    features = np.stack([clip_features(t.actors[0]) for t in data])
    labels = [t.labels["emotion"] for t in data]
    g = synthesis.judged_group(name, data, contents, features, labels,
                               synthesis.held_out_judges(features, labels), cfg)
    return {"group": name, "floor": floor, "iterations": iterations, **g}


def handshake_cell(floor: float, iterations: int) -> dict:
    import bayesmotion  # noqa: F401  (float64 on)

    cfg = replace(synthesis.Settings(), handshake_iter=iterations, mapping_noise_floor=floor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        hs = synthesis.handshakes(cfg)
    return {"group": "handshakes", "floor": floor, "iterations": iterations, **hs}


def _f(x, spec: str = ".2f") -> str:
    return "n/a" if x is None else format(x, spec)


def _summary(c: dict) -> dict:
    """The numbers a headline compares, of one Bandai cell."""
    n = c.get("naturalness") or {}
    return {"rate_mean": c["synthesized_rate"]["mean"],
            "rate_sampled": c["synthesized_rate"]["sampled"],
            "natural_rate": c["natural_rate"]["rate"],
            "jerk_ratio": n.get("jerk_ratio"), "foot_sliding_ratio": n.get("foot_sliding_ratio"),
            "joint_limit_violations": n.get("joint_limit_violations"),
            "limb_motion_last_over_first": c["long_worst"]["limb_motion_last_over_first"],
            "latent_range": c["long_worst"]["latent_range"],
            "relative_fall_last_window": c["fit"]["convergence"]["relative_fall_last_window"]}


def run(quick: bool, root: str | Path | None = None, out: str | Path | None = None) -> dict:
    base_cfg = synthesis.QUICK if quick else synthesis.Settings()
    iterations = QUICK_ITERATIONS if quick else ITERATIONS
    root = Path(root) if root is not None else BANDAI_ROOT
    out = Path(out) if out is not None else RESULTS / f"{NAME}.json"
    base = {"name": NAME, "mode": "quick" if quick else "full",
            "settings": {"floors": list(FLOORS), "iterations": list(iterations),
                         "long_groups": list(LONG_GROUPS),
                         "groups": {k: list(v) for k, v in base_cfg.groups.items()},
                         "fps": base_cfg.fps, "n_samples": base_cfg.n_samples,
                         "periodic": list(base_cfg.periodic), "lookahead": base_cfg.lookahead,
                         "handshake_iter": iterations[0] if quick else 1000},
            "targets": synthesis.TARGETS}
    if not bandai_present(root):
        return bandai_skip(base, root, out)
    t0 = time.perf_counter()
    jobs = []
    for name, cs in base_cfg.groups.items():
        its = iterations if (quick or name in LONG_GROUPS) else iterations[:1]
        jobs += [("bandai", (name, tuple(cs), f, n, str(root), quick))
                 for n in its for f in FLOORS]
    jobs += [("handshakes", (f, base["settings"]["handshake_iter"])) for f in FLOORS]
    jobs.sort(key=lambda j: j[0] == "bandai" and j[1][0] == "walks", reverse=True)  # longest
    cells = []
    with ProcessPoolExecutor(max_workers=2,
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(bandai_cell if kind == "bandai" else handshake_cell, *args)
                   for kind, args in jobs]
        for fut in futures:
            cells.append(fut.result())
            c = cells[-1]
            print(f"[{NAME}] {c['group']} floor {c['floor']:g}, {c['iterations']} iterations: "
                  "done", file=sys.stderr, flush=True)
    rows = []
    bandai = {(c["group"], c["floor"], c["iterations"]): c for c in cells
              if c["group"] != "handshakes"}
    for (name, floor, n), c in sorted(bandai.items(), key=lambda kv: (kv[0][0], kv[0][2],
                                                                     kv[0][1])):
        s = _summary(c)
        c["summary"] = s
        rows.append(headline(
            f"{name}, floor {floor:g}, {n} iterations: jerk ratio of generated clips",
            s["jerk_ratio"], "", f"<= {synthesis.TARGETS['jerk_ratio_max']}",
            c["targets_met"]["jerk"],
            f"judge's rate mean {_f(s['rate_mean'])} / sampled {_f(s['rate_sampled'])} "
            f"(natural {_f(s['natural_rate'])}); foot sliding {_f(s['foot_sliding_ratio'])}; "
            f"limb motion last/first 200 of 1000 frames >= "
            f"{_f(s['limb_motion_last_over_first'])}; objective's fall over the last 100 "
            f"iterations {_f(s['relative_fall_last_window'], '.2g')}"))
    for c in (c for c in cells if c["group"] == "handshakes"):
        ok = [r for r in c["emotions"].values() if "error" not in r]
        worst = max((r["min_hand_distance"] for r in ok), default=None)
        rows.append(headline(
            f"built-in handshakes, floor {c['floor']:g}: largest per-emotion minimum "
            "right-hand distance", worst, "", f"< 1.5 x real {c['real_min_hand_distance']:.2f}",
            worst is not None and len(ok) == len(c["emotions"])
            and worst < 1.5 * c["real_min_hand_distance"],
            f"1000-frame rollouts: latent range <= "
            f"{_f(max((r['latent_range'] for r in ok), default=None))}x; fit "
            f"{c['fit']['iterations']} iterations, {c['fit']['seconds']:.0f} s"))
    result = {**base, "cells": cells, "headline": rows, "status": "ok",
              "timing_s": {"total": time.perf_counter() - t0}, "machine": machine_info()}
    write_json(out, result)
    return result


def main() -> int:
    return standalone_main(NAME, run, __doc__, "one group of two walk contents, few iterations",
                           show_headlines)


if __name__ == "__main__":
    sys.exit(main())
