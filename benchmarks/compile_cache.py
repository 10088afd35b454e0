"""What JAX's persistent compilation cache saves a fresh process (bayesmotion.compile_cache).

    python benchmarks/compile_cache.py [--quick]

The model is infer_speed's: ``HGPDM()`` fitted by MAP on the built-in handshakes at 10 fps
without the four held-out trials, saved to a model file. Each row is a fresh Python process,
run three ways: the cache off, the cache on in an empty folder (it compiles and writes every
program), and the cache on in that folder again (it reads them). Three kinds of process:

* ``library``: imports bayesmotion, loads the model and calls ``infer_emotion`` (defaults) on
  a held-out trial, then on another: the first call's seconds include compiling (or reading)
  every program it runs, the second's are the arithmetic alone; with the cache's hits and
  misses (``bayesmotion.compile_cache.cache_stats``).
* ``cli``: ``python -m bayesmotion infer model.npz actor0.bvh actor1.bvh --couple c1 --json``
  on a held-out trial written as BVH, timed whole (start-up, load, inference, output), as a
  user's shell sees it; its folder is a separate one, so its cold row starts empty too.
* ``generate``: ``python -m bayesmotion generate model.npz --emotion happy --frames 60
  --samples 4 --out DIR``, timed whole, with a folder of its own.

The answers of the three runs must agree: the same labels, and byte-identical BVH files from
``generate``. The cache's size on
disk is reported after the cold run.
"""

from __future__ import annotations

import hashlib
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

from _common import headline, saved_demo_model, standalone_main  # noqa: E402

NAME = "compile_cache"
FULL = {"fps": 10.0, "max_iter": 150}
QUICK = {"fps": 10.0, "max_iter": 20}
RUNS = ("off", "cold", "warm")

# one process: load the model, infer two held-out trials, print the timings as JSON
LIBRARY = r"""
import json, sys, time
t0 = time.perf_counter()
import bayesmotion
from bayesmotion.app.demo import _split
from bayesmotion.compile_cache import cache_stats, enable_compilation_cache
from bayesmotion.datasets import load_handshakes
enable_compilation_cache()
t1 = time.perf_counter()
model = bayesmotion.load(sys.argv[1])
held = _split(load_handshakes(fps=float(sys.argv[2])))[1]
out = {"import_seconds": t1 - t0}
for key, trial in (("first", held[0]), ("second", held[1])):
    t = time.perf_counter()
    ep = bayesmotion.infer_emotion(model, trial, couple=trial.labels["couple"], seed=0)
    out[key + "_call_seconds"] = time.perf_counter() - t
    out[key + "_label"] = ep.label
out.update(cache_stats())
print(json.dumps(out))
"""


def _env(cache: Path | None) -> dict:
    env = dict(os.environ)
    env["BAYESMOTION_COMPILE_CACHE"] = str(cache) if cache is not None else "off"
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


def _folder_mb(path: Path) -> tuple[int, float]:
    files = [p for p in path.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files) / 2**20


def _library(model: Path, fps: float, cache: Path | None) -> dict:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", LIBRARY, str(model), str(fps)], env=_env(cache),
                       capture_output=True, text=True, check=True)
    return {**json.loads(r.stdout.strip().splitlines()[-1]),
            "process_seconds": time.perf_counter() - t}


def _generate(model: Path, out: Path, cache: Path | None) -> dict:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "bayesmotion", "generate", str(model), "--emotion",
                    "happy", "--frames", "60", "--samples", "4", "--out", str(out)],
                   env=_env(cache), capture_output=True, text=True, check=True)
    bvh = sorted(out.glob("*.bvh"))
    return {"process_seconds": time.perf_counter() - t, "bvh_files": [p.name for p in bvh],
            "bvh_sha256": hashlib.sha256(b"".join(p.read_bytes() for p in bvh)).hexdigest()}


def _cli(model: Path, files: list[Path], couple: str, cache: Path | None) -> dict:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bayesmotion", "infer", str(model),
                        *map(str, files), "--couple", couple, "--json"], env=_env(cache),
                       capture_output=True, text=True, check=True)
    return {"process_seconds": time.perf_counter() - t,
            "label": json.loads(r.stdout)["label"]}


def _process_rows(what: str, runs: dict) -> list:
    """Headline rows of a whole-process timing: cache off, and warm with the cold run beside."""
    return [headline(f"{what}, whole process: cache off", runs["off"]["process_seconds"], "s"),
            headline(f"{what}, whole process: cache warm", runs["warm"]["process_seconds"], "s",
                     note=f"cold (empty cache, writing it) {runs['cold']['process_seconds']:.1f}"
                          f" s; cache {runs['cache_files']} files, {runs['cache_mb']:.1f} MB")]


def run(quick: bool) -> dict:
    from bayesmotion.data.bvh import write_bvh

    cfg = QUICK if quick else FULL
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        model, train, held = saved_demo_model(tmp, cfg["fps"], cfg["max_iter"])
        trial = held[0]
        files = []
        for a, motion in enumerate(trial.actors):
            files.append(tmp / f"clip_actor{a}.bvh")
            write_bvh(motion, files[-1])
        out = {"library": {}, "cli": {}, "generate": {}}
        for kind in out:
            cache = tmp / f"cache-{kind}"
            for how in RUNS:
                where = None if how == "off" else cache
                if kind == "library":
                    out[kind][how] = _library(model, cfg["fps"], where)
                elif kind == "cli":
                    out[kind][how] = _cli(model, files, trial.labels["couple"], where)
                else:
                    out[kind][how] = _generate(model, tmp / f"gen-{how}", where)
                if how == "cold":
                    n, mb = _folder_mb(cache)
                    out[kind]["cache_files"], out[kind]["cache_mb"] = n, mb
    lib, cli, gen = out["library"], out["cli"], out["generate"]
    agree = (len({lib[h]["first_label"] for h in RUNS}) == 1
             and len({cli[h]["label"] for h in RUNS}) == 1
             and len({gen[h]["bvh_sha256"] for h in RUNS}) == 1
             and bool(gen["off"]["bvh_files"]))
    rows = [
        *_process_rows("bayesmotion infer, one clip", cli),
        headline("infer_emotion first call in a fresh process: cache off",
                 lib["off"]["first_call_seconds"], "s",
                 note=f"second call {lib['off']['second_call_seconds']:.2f} s"),
        headline("infer_emotion first call in a fresh process: cache warm",
                 lib["warm"]["first_call_seconds"], "s",
                 note=f"{lib['warm']['hits']} programs read, {lib['warm']['misses']} compiled; "
                      f"second call {lib['warm']['second_call_seconds']:.2f} s"),
        *_process_rows("bayesmotion generate (60 frames, 4 samples)", gen),
        headline("same answers with and without the cache", agree, "", "True", agree),
    ]
    return {"settings": {**cfg, "n_train_trials": len(train), "n_frames": held[0].n_frames},
            "runs": out, "headline": rows}


def main() -> int:
    return standalone_main(NAME, run, __doc__, "a barely fitted model",
                           lambda r: "\n".join(map(str, r["headline"])))


if __name__ == "__main__":
    sys.exit(main())
