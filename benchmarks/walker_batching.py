"""How to lay out a batch of walkers for the sampled log-density on a CPU: one ``jax.vmap`` over
the half-ensemble (the previous layout) against ``jax.lax.map`` over chunks of c walkers, each
chunk vmapped (``bayesmotion.gp.batch.over_points``), under each installed jax line.

The density is ``Target(model).logp`` of the demo-size posterior (``posterior_convergence``'s
model: 20 trials, N = 340 frames per actor, 26 sampled coordinates), evaluated at 27 points (half
of the default 54 walkers: what emcee asks for per half-step) scattered around the start. Each
layout is compiled once, then timed ``repeats`` times over ``calls`` calls, layouts alternating;
the median per call is reported, with the largest difference from the vmapped values. Each jax
line runs in a child process of its own interpreter (``.venv-jax010`` and ``.venv-jax09`` at
the repository root, where present; otherwise the current one).

Current result (``results/walker_batching.json``): see ``["headline"]`` and ``docs/results.md``.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

SETTINGS = {"full": {"max_iter": 1000, "batch": 27, "chunks": [None, 1, 2, 3, 4, 9],
                     "repeats": 5, "calls": 10},
            "quick": {"max_iter": 150, "batch": 27, "chunks": [None, 1, 2], "repeats": 2,
                      "calls": 3}}
PYTHONS = {"jax010": REPO / ".venv-jax010" / "bin" / "python",
           "jax09": REPO / ".venv-jax09" / "bin" / "python"}


def measure(settings: dict) -> dict:
    """Times of each layout in this process (its jax)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    import posterior_convergence as pc

    from bayesmotion.gp.batch import over_points
    from bayesmotion.inference.target import Target

    model = pc.demo_model(settings["max_iter"], pc.model_path(settings["max_iter"]))
    target = Target(model)
    rng = np.random.default_rng(0)
    xs = jnp.asarray(target.x0 + 1e-3 * rng.standard_normal((settings["batch"], target.ndim)))
    fns = {str(c): jax.jit(over_points(target._logp, c)) for c in settings["chunks"]}
    ref = np.asarray(fns["None"](xs))
    # the points are near the start, where the density is finite
    diff = {k: float(np.max(np.abs(np.asarray(f(xs)) - ref))) for k, f in fns.items()}
    times = {k: [] for k in fns}
    for _ in range(settings["repeats"]):
        for k, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(settings["calls"]):
                f(xs).block_until_ready()
            times[k].append((time.perf_counter() - t0) / settings["calls"])
    rows = [{"chunk": None if k == "None" else int(k), "median_ms": 1e3 * statistics.median(t),
             "min_ms": 1e3 * min(t), "max_abs_diff_from_vmap": diff[k]} for k, t in times.items()]
    return {"jax": jax.__version__, "n_frames": int(model.log_posterior_fn.data.Y[0].shape[0]),
            "ndim": int(target.ndim), "rows": rows}


def run(quick: bool) -> dict:
    from _common import headline

    from bayesmotion.gp.batch import CPU_CHUNK

    settings = SETTINGS["quick" if quick else "full"]
    found = {k: p for k, p in PYTHONS.items() if p.exists()} or {"current": Path(sys.executable)}
    lines = {}
    for name, python in found.items():
        out = subprocess.run([str(python), str(Path(__file__)), "--child", json.dumps(settings)],
                             capture_output=True, text=True, cwd=str(REPO))
        if out.returncode:
            raise RuntimeError(f"the {name} child ({python}) failed:\n{out.stderr[-3000:]}")
        lines[name] = json.loads(out.stdout.strip().splitlines()[-1])
        for r in lines[name]["rows"]:
            print(f"  {name} chunk {r['chunk']}: {r['median_ms']:.1f} ms", flush=True)
    heads = []
    for res in lines.values():
        by = {r["chunk"]: r for r in res["rows"]}
        chosen = by.get(CPU_CHUNK)
        if chosen is None:
            continue
        ratio = by[None]["median_ms"] / chosen["median_ms"]
        heads.append(headline(
            f"sampled log-density at {settings['batch']} walkers, jax {res['jax']}: chunks of "
            f"{CPU_CHUNK} under "
            f"lax.map", chosen["median_ms"], "ms", f"< one vmap ({by[None]['median_ms']:.0f} ms)",
            ratio > 1.0, f"{ratio:.2f}x faster; N = {res['n_frames']}, {res['ndim']} coordinates"))
    return {"settings": settings, "lines": lines, "headline": heads}


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:  # a child of run(): one jax line's measurements as JSON
        import bayesmotion  # noqa: F401  (float64, the package's thread settings)

        print(json.dumps(measure(json.loads(sys.argv[2]))))
    else:
        sys.exit("run it with: python benchmarks/run_all.py --only walker_batching [--quick]")
