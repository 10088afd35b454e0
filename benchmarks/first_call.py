"""The first ``infer_emotion`` call of a fresh process, this version against an earlier one.

    python benchmarks/first_call.py [--quick] [--baseline REV]

Most of a first call is JAX compiling its programs (the compilation cache off, as a script that
does not turn it on). The model is compile_cache's: ``HGPDM()`` fitted by MAP on the built-in
handshakes at 10 fps without the four held-out trials, saved to a model file. Each row is a
fresh Python process that loads the model and calls ``infer_emotion`` (defaults, couple given,
seed 0) on a held-out trial, then on another: the first call's seconds include compiling every
program it runs (their number and compile seconds, from JAX's compile events), the second's
are the arithmetic alone. The two versions run alternately, ``repeats`` processes each, on the
same model file: this checkout's ``src`` and ``--baseline`` (a git revision, checked out into a
temporary worktree). Both must give the same labels; the largest difference of their label
probabilities is reported (a different compiled program may round differently and move an
L-BFGS path by a few iterations).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import (  # noqa: E402
    RESULTS,
    headline,
    machine_info,
    saved_demo_model,
    show_headlines,
    write_json,
)

NAME = "first_call"
ROOT = HERE.parent
BASELINE = "2d0cf2d"  # the revision the stored result compares against
FULL = {"fps": 10.0, "max_iter": 150, "repeats": 3}
QUICK = {"fps": 10.0, "max_iter": 20, "repeats": 1}

# one process: load the model, infer two held-out trials, print the timings as JSON
CHILD = r"""
import json, sys, time
import jax.monitoring
from jax._src.dispatch import BACKEND_COMPILE_EVENT
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, secs, **kw: compiles.append(secs) if event == BACKEND_COMPILE_EVENT else None)
import bayesmotion
from bayesmotion.app.demo import _split
from bayesmotion.datasets import load_handshakes
model = bayesmotion.load(sys.argv[1])
held = _split(load_handshakes(fps=float(sys.argv[2])))[1]
out = {"module": bayesmotion.__file__}
for key, trial in (("first", held[0]), ("second", held[1])):
    n0 = len(compiles)
    t = time.perf_counter()
    ep = bayesmotion.infer_emotion(model, trial, couple=trial.labels["couple"], seed=0)
    out[key + "_call_seconds"] = time.perf_counter() - t
    out[key + "_compile_seconds"] = sum(compiles[n0:])
    out[key + "_programs"] = len(compiles) - n0
    out[key + "_label"] = ep.label
    out[key + "_probabilities"] = [float(p) for p in ep.probabilities]
print(json.dumps(out))
"""


def _child(src: Path, model: Path, fps: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), BAYESMOTION_COMPILE_CACHE="off")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", CHILD, str(model), str(fps)], env=env,
                       capture_output=True, text=True, check=True, cwd=src.parent)
    out = {**json.loads(r.stdout.strip().splitlines()[-1]),
           "process_seconds": time.perf_counter() - t}
    if not Path(out["module"]).resolve().is_relative_to(src.resolve()):
        raise RuntimeError(f"the process imported {out['module']}, not the version in {src}")
    return out


def _summary(rows: list[dict]) -> dict:
    keys = ("first_call_seconds", "first_compile_seconds", "first_programs",
            "second_call_seconds", "process_seconds")
    return {k: float(np.median([r[k] for r in rows])) for k in keys}


def run(quick: bool, baseline: str = BASELINE) -> dict:
    cfg = QUICK if quick else FULL
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        model, _, _ = saved_demo_model(tmp, cfg["fps"], cfg["max_iter"])
        base = tmp / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base),
                        baseline], check=True, capture_output=True)
        try:
            sha = subprocess.run(["git", "-C", str(base), "rev-parse", "HEAD"], check=True,
                                 capture_output=True, text=True).stdout.strip()
            runs = {"this": [], "baseline": []}
            for _ in range(cfg["repeats"]):  # alternately, so drift hits both alike
                runs["this"].append(_child(ROOT / "src", model, cfg["fps"]))
                runs["baseline"].append(_child(base / "src", model, cfg["fps"]))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)],
                           check=False, capture_output=True)
    this, old = _summary(runs["this"]), _summary(runs["baseline"])
    same = all(a[k] == b[k] for a in runs["this"] for b in runs["baseline"]
               for k in ("first_label", "second_label"))
    diff = max(float(np.max(np.abs(np.subtract(a[k], b[k]))))
               for a in runs["this"] for b in runs["baseline"]
               for k in ("first_probabilities", "second_probabilities"))
    rows = [
        headline("infer_emotion first call, fresh process, no compilation cache",
                 this["first_call_seconds"], "s",
                 note=f"baseline {baseline}: {old['first_call_seconds']:.1f} s; medians of "
                      f"{cfg['repeats']} processes each"),
        headline("  of which compiling", this["first_compile_seconds"], "s",
                 note=f"{this['first_programs']:.0f} programs; baseline "
                      f"{old['first_compile_seconds']:.1f} s, {old['first_programs']:.0f} "
                      "programs"),
        headline("infer_emotion second call", this["second_call_seconds"], "s",
                 note=f"baseline {old['second_call_seconds']:.2f} s"),
        headline("same labels as the baseline", same, "", "True", same,
                 note=f"largest difference of a label probability {diff:.2g}"),
    ]
    return {"settings": {**cfg, "baseline": baseline, "baseline_sha": sha},
            "summary": {"this": this, "baseline": old}, "runs": runs, "headline": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="one process per version, a barely fitted model")
    ap.add_argument("--baseline", default=BASELINE, metavar="REV",
                    help=f"the git revision to compare with (default {BASELINE})")
    a = ap.parse_args(argv)
    res = run(a.quick, a.baseline)
    write_json(RESULTS / f"{NAME}.json", {"name": NAME, "mode": "quick" if a.quick else "full",
                                          **res, "status": "ok", "machine": machine_info()})
    print(show_headlines(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
