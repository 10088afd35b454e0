"""The main job as a new user runs it: ``bayesmotion demo --quick``, timed as a whole command.

    python benchmarks/demo_quick.py [--quick]

Each run is a fresh process of the command line (``python -m bayesmotion demo --quick``) with
its own output folder and a compilation cache folder of its own
(``BAYESMOTION_COMPILE_CACHE``): the first run finds it empty, as a new user's first run does,
and compiles every program; the second reads the programs the first wrote, as every later run
on the machine does. ``--quick`` runs the first only. Recorded per run: the command's wall
seconds, the demo's own seconds per stage and in total (``summary.json``, keys
``stage_seconds`` and ``seconds_total``), and the posterior's diagnostics the report shows
(max R-hat, min bulk ESS; the quick demo samples the hyperparameters with the style vectors
held at the MAP, and says so). Targets: the demo's own budget, 3 minutes on a 2-core CPU, and
the quick demo's posterior at max R-hat <= 1.05 with min bulk ESS >= 400.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import headline, show_headlines, standalone_main  # noqa: E402

NAME = "demo_quick"
ROOT = HERE.parent
BUDGET_S = 180.0  # the quick demo's time budget on a 2-core CPU (bayesmotion.app.demo)
TARGETS = {"max_rhat": 1.05, "min_ess_bulk": 400.0}


def run_demo(out: Path, cache: Path) -> dict:
    """One ``bayesmotion demo --quick`` process writing to ``out`` with the compilation cache
    folder ``cache``: its wall seconds and what its summary says."""
    env = dict(os.environ, BAYESMOTION_COMPILE_CACHE=str(cache),
               PYTHONPATH=str(ROOT / "src"))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bayesmotion", "demo", "--quick", "--out",
                        str(out)], env=env, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise RuntimeError(f"bayesmotion demo --quick failed ({r.returncode}): "
                           f"{r.stderr[-2000:]}")
    s = json.loads((out / "summary.json").read_text())
    p = s["posterior"]
    return {"wall_seconds": wall, "seconds_total": s["seconds_total"],
            "stage_seconds": s["stage_seconds"],
            "cache_files": sum(1 for f in cache.rglob("*") if f.is_file()),
            "posterior": {k: p.get(k) for k in ("max_rhat", "min_ess_bulk", "min_ess_tail",
                                                "max_tau", "n_steps", "n_walkers",
                                                "n_coordinates", "style_vectors", "seconds")}}


def run(quick: bool) -> dict:
    runs = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cache = tmp / "cache"
        cache.mkdir()
        for name in ("empty_cache",) if quick else ("empty_cache", "filled_cache"):
            runs[name] = run_demo(tmp / name, cache)
    first = runs["empty_cache"]
    p = first["posterior"]
    ok = p["max_rhat"] <= TARGETS["max_rhat"] and p["min_ess_bulk"] >= TARGETS["min_ess_bulk"]
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in first["stage_seconds"].items())
    rows = [headline("bayesmotion demo --quick, fresh process, empty compilation cache",
                     first["wall_seconds"], "s", f"<= {BUDGET_S:.0f} s",
                     first["wall_seconds"] <= BUDGET_S,
                     note=f"the demo's own count {first['seconds_total']:.0f} s: {stages}")]
    if "filled_cache" in runs:
        second = runs["filled_cache"]
        rows.append(headline("  again, reading the programs the first run compiled",
                             second["wall_seconds"], "s", f"<= {BUDGET_S:.0f} s",
                             second["wall_seconds"] <= BUDGET_S,
                             note=f"the demo's own count {second['seconds_total']:.0f} s"))
    rows.append(headline("quick demo posterior (style vectors held at the MAP): max R-hat",
                         p["max_rhat"], "", f"<= {TARGETS['max_rhat']}",
                         p["max_rhat"] <= TARGETS["max_rhat"],
                         note=f"min bulk ESS {p['min_ess_bulk']:.0f} (target >= "
                              f"{TARGETS['min_ess_bulk']:.0f}), {p['n_steps']} steps of "
                              f"{p['n_walkers']} walkers over {p['n_coordinates']} "
                              f"coordinates, {p['seconds']:.0f} s; both met: {ok}"))
    return {"settings": {"command": "python -m bayesmotion demo --quick --out DIR",
                         "runs": list(runs), "budget_s": BUDGET_S, "targets": TARGETS,
                         "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")},
            "runs": runs, "headline": rows}


if __name__ == "__main__":
    sys.exit(standalone_main(NAME, run, __doc__, "the first run only (empty cache)",
                             show_headlines))
