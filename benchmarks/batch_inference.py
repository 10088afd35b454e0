"""Batch emotion inference: one process clip after clip against ``infer_many`` on a local Dask
cluster of 2 worker processes, the same clips and settings, side by side in one run.

    python benchmarks/batch_inference.py [--quick]

The model is the demo's (``HGPDM()`` on the built-in handshakes at 10 fps without the four
held-out trials, 150 fit iterations); the clips are the 24 built-in trials written as BVH pairs
(``--quick``: 6). One process: ``infer_emotion`` on each clip in a fresh Python process (its
first call compiles). Two workers: ``bayesmotion.infer_many(model_file, folder, table,
workers=2)`` from a fresh process (each worker compiles on its first clip). Reported: wall
seconds of each, clips per second over the whole run, and clips per second once warm (from the
moment every process has finished its first clip to the last clip, from the clips' finishing
times); the target is 2 workers >= 1.8x one process on this 2-core machine.

A third run, the same serial process pinned to one core (``os.sched_setaffinity``), says what
one process already takes from the second core: 2 workers can be at most (1-core rate x 2) /
(2-core rate) times one unpinned process, whatever the scheduler.
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

from _common import headline  # noqa: E402

NAME = "batch_inference"
TARGET = 1.8
FULL = {"fps": 10.0, "max_iter": 150, "n_clips": 24, "seed": 0}
QUICK = {"fps": 10.0, "max_iter": 20, "n_clips": 6, "seed": 0}

SERIAL = """
import json, sys, time, warnings
import bayesmotion as bm
from bayesmotion.emotion.ood import OutOfDistributionWarning
model = bm.load(sys.argv[1])
clips = json.loads(sys.argv[2])
t0 = time.time()
out = []
for name, files in clips:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfDistributionWarning)
        ep = bm.infer_emotion(model, files, seed=int(sys.argv[3]))
    out.append({"clip": name, "label": ep.label, "finished": time.time(), "worker": "serial"})
print(json.dumps({"start": t0, "rows": out}))
"""

PARALLEL = """
import json, sys, time
import bayesmotion as bm
t0 = time.time()
rows = bm.infer_many(sys.argv[1], sys.argv[2], sys.argv[3], workers=2, progress=False,
                     seed=int(sys.argv[4]))
print(json.dumps({"start": t0, "rows": [{k: r[k] for k in ("clip", "label", "finished",
                                                         "worker", "error")} for r in rows]}))
"""


def _rates(res: dict) -> dict:
    rows = res["rows"]
    ends = sorted(float(r["finished"]) for r in rows)
    wall = ends[-1] - res["start"]
    firsts = {}
    for r in sorted(rows, key=lambda r: float(r["finished"])):
        firsts.setdefault(r["worker"], float(r["finished"]))
    warm_from = max(firsts.values())
    warm = [e for e in ends if e > warm_from]
    return {"wall_s": wall, "clips_per_s": len(rows) / wall,
            "warm_clips": len(warm), "warm_s": ends[-1] - warm_from,
            "warm_clips_per_s": len(warm) / (ends[-1] - warm_from) if warm else None,
            "processes": len(firsts)}


def run(quick: bool) -> dict:
    import bayesmotion as bm
    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes

    cfg = QUICK if quick else FULL
    ds = load_handshakes(fps=cfg["fps"])
    train, _ = _split(ds)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        model_path = d / "model.npz"
        bm.HGPDM().fit(train, max_iter=cfg["max_iter"], progress=False).save(model_path)
        folder = d / "clips"
        folder.mkdir()
        clips = []
        for i, t in enumerate(list(ds)[:cfg["n_clips"]]):
            files = [str(bm.write_bvh(m, folder / f"clip{i:02d}_actor{a}.bvh"))
                     for a, m in enumerate(t.actors)]
            clips.append((f"clip{i:02d}", files))
        py = sys.executable

        def child(code, *args, cores=None):
            t = time.perf_counter()
            pin = None if cores is None else (lambda: os.sched_setaffinity(0, cores))
            r = subprocess.run([py, "-c", code, *map(str, args)], capture_output=True,
                               text=True, timeout=3600, preexec_fn=pin)
            if r.returncode:
                raise RuntimeError(r.stderr[-3000:])
            out = json.loads(r.stdout.strip().splitlines()[-1])
            out["process_wall_s"] = time.perf_counter() - t
            return out

        serial = child(SERIAL, model_path, json.dumps(clips), cfg["seed"])
        one_core = (child(SERIAL, model_path, json.dumps(clips), cfg["seed"], cores={0})
                    if hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) > 1
                    else None)
        parallel = child(PARALLEL, model_path, folder, d / "table.csv", cfg["seed"])
    s, p = _rates(serial), _rates(parallel)
    same = ({r["clip"]: r["label"] for r in serial["rows"]}
            == {r["clip"]: r["label"] for r in parallel["rows"]})
    total, warm = p["clips_per_s"] / s["clips_per_s"], None
    if s["warm_clips_per_s"] and p["warm_clips_per_s"]:
        warm = p["warm_clips_per_s"] / s["warm_clips_per_s"]
    rows = [
        headline(f"throughput, 2 workers / 1 process, whole run ({cfg['n_clips']} clips)",
                 round(total, 2), "x", f">= {TARGET}", total >= TARGET,
                 f"{s['wall_s']:.0f} s vs {p['wall_s']:.0f} s, compilation included"),
        headline("throughput, 2 workers / 1 process, once warm", None if warm is None
                 else round(warm, 2), "x", f">= {TARGET}",
                 None if warm is None else warm >= TARGET,
                 f"{p['warm_clips']} and {s['warm_clips']} clips after every process's first"),
        headline("same labels from both", same, "", "True", same),
    ]
    one = None
    if one_core is not None:
        one = _rates(one_core)
        if one["warm_clips_per_s"] and s["warm_clips_per_s"] and p["warm_clips_per_s"]:
            gain = s["warm_clips_per_s"] / one["warm_clips_per_s"]
            rows.append(headline(
                "  one process on 2 cores / on 1 core, once warm", round(gain, 2), "x", "", None,
                f"so 2 workers can reach at most {2 / gain:.2f}x one process here; they reach "
                f"{p['warm_clips_per_s'] / one['warm_clips_per_s']:.2f}x the 1-core process"))
    return {"settings": cfg, "serial": {**s, "rows": serial["rows"]},
            "serial_one_core": None if one is None else {**one, "rows": one_core["rows"]},
            "parallel": {**p, "rows": parallel["rows"]}, "ratio_whole_run": total,
            "ratio_warm": warm, "same_labels": same, "headline": rows}


def show(res: dict) -> str:
    return "\n".join(f"{h['metric']}: {h['value']} {h['unit']} ({h['note']})"
                     for h in res["headline"])


if __name__ == "__main__":
    from _common import standalone_main

    raise SystemExit(standalone_main(NAME, run, __doc__, "6 clips, a 20-iteration fit", show))
