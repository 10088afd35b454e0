"""jax 0.9.x against jax 0.10.x on CPU: the same timings under both lines, side by side.

    python benchmarks/jax_versions.py [--quick] [--python-09 PATH] [--python-010 PATH]

Two interpreters with the package installed, one per jax line (defaults: ``.venv``, jax 0.9.x,
and ``.venv-jax010``, jax 0.10.x, at the repository root; ``pip install -e ".[dev]"
"jax==0.10.2" "jaxlib==0.10.2"`` builds the second). Each measurement runs in its own child
process of each interpreter under two sizes of XLA's CPU thread pool (``PJRT_NPROC``, read when
JAX starts its CPU backend): one thread, what bayesmotion sets on jaxlib >= 0.10 (see
``bayesmotion._config``), and one per core, XLA's own default and bayesmotion's on 0.9.x. So
the table separates the cost of the version from the cost of the workaround. Settings alternate
round by round; a child that does not finish within its timeout is recorded as hung (on jaxlib
0.10 with the per-core pool the batched Cholesky gradient deadlocks, the reason for the
workaround). The measurements:

* ``map_fit``: ``HGPDM().fit`` on the built-in handshakes at 10 fps for a fixed number of
  L-BFGS iterations (wall seconds including compilation, and seconds per iteration);
* ``gplvm_layer``: one GP-LVM layer value + gradient at ``gplvm_vs_gpy``'s size (N = 1000,
  D = 60, Q = 6);
* ``batched_solve``: ``jnp.linalg.solve`` over 86,268 float64 3 x 3 systems (the shape of
  jax-ml/jax#36927);
* ``batched_cholesky_grad``: value + gradient of a sum of four independent vmapped Cholesky
  log-determinants and solves, batch 4, N = 128 (the deadlock reproducer of
  tests/test_jax_deadlock.py);
* ``infer_emotion``: ``infer_emotion`` (default settings) of the four held-out clips of the
  demo's split, from a model fitted for a few iterations: the first call (compilation) apart,
  the median of the other three.

A measurement that hung under a setting is not run again under it in later rounds.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import headline, standalone_main  # noqa: E402

NAME = "jax_versions"
PYTHONS = {"jax09": REPO / ".venv" / "bin" / "python",
           "jax010": REPO / ".venv-jax010" / "bin" / "python"}
POOLS = ("one_thread", "per_core")
MEASUREMENTS = ("map_fit", "gplvm_layer", "batched_solve", "batched_cholesky_grad",
                "infer_emotion")
FULL = {"rounds": 2, "repeats": 5, "fit_iter": 50, "infer_fit_iter": 30}
QUICK = {"rounds": 1, "repeats": 3, "fit_iter": 20, "infer_fit_iter": 10}
# seconds before a child is called hung: several times what it takes on the 2-core target
# (a child that returns: map_fit 10-20 s, infer_emotion 45-80 s, the others 3-5 s)
TIMEOUT_S = {"map_fit": 100, "gplvm_layer": 60, "batched_solve": 60,
             "batched_cholesky_grad": 60, "infer_emotion": 200}


# --------------------------------------------------------------------------- in the child
def _map_fit(cfg):
    import bayesmotion
    from bayesmotion.datasets import load_handshakes

    ds = load_handshakes(fps=10.0)
    t = time.perf_counter()
    model = bayesmotion.HGPDM().fit(ds, max_iter=cfg["fit_iter"], progress=False)
    wall = time.perf_counter() - t
    d = model.diagnostics
    return {"wall_s": wall, "iterations": d["iterations"], "evaluations": d["evaluations"],
            "seconds_per_iteration": d["seconds"] / max(d["iterations"], 1),
            "objective": d["objective"]}


def _gplvm_layer(cfg):
    from _common import timeit
    from gplvm_vs_gpy import SIZES, bayesmotion_call, make_data

    fn, _, _ = bayesmotion_call(*make_data(**SIZES))
    return timeit(fn, cfg["repeats"])


def _batched_solve(cfg):
    import jax
    import jax.numpy as jnp
    from _common import block, timeit

    batch = 182 * 474
    kA, kb = jax.random.split(jax.random.PRNGKey(0))
    A = jax.random.normal(kA, (batch, 3, 3))
    A = A @ jnp.swapaxes(A, -1, -2) + 1e-2 * jnp.eye(3)
    b = jax.random.normal(kb, (batch, 3, 1))
    solve = jax.jit(jnp.linalg.solve)
    return timeit(lambda: block(solve(A, b)), cfg["repeats"])


def _batched_cholesky_grad(cfg):
    import jax
    import jax.numpy as jnp
    from _common import block, timeit
    from jax.scipy.linalg import solve_triangular

    def branch(A, y):
        L = jnp.linalg.cholesky(A @ jnp.swapaxes(A, -1, -2) + 128 * jnp.eye(128))
        z = solve_triangular(L, y, lower=True)
        return jnp.sum(z**2) + 2 * jnp.sum(jnp.log(jnp.diagonal(L, axis1=-2, axis2=-1)))

    vg = jax.jit(jax.value_and_grad(lambda As, ys: sum(map(branch, As, ys))))
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    As = [jax.random.normal(k, (4, 128, 128)) for k in keys]
    ys = [jax.random.normal(k, (4, 128, 3)) for k in keys]
    return timeit(lambda: block(vg(As, ys)), cfg["repeats"])


def _infer_emotion(cfg):
    import bayesmotion
    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes

    train, held = _split(load_handshakes(fps=10.0))
    model = bayesmotion.HGPDM().fit(train, max_iter=cfg["infer_fit_iter"], progress=False)
    times = []
    for trial in held:
        t = time.perf_counter()
        bayesmotion.infer_emotion(model, trial, couple=trial.labels["couple"], seed=0)
        times.append(time.perf_counter() - t)
    return {"first_call_s": times[0], "times_s": times[1:],
            "median_s": statistics.median(times[1:])}


def measure_here(name: str, cfg: dict) -> dict:
    """One measurement in this process, with the jax versions and the pool setting."""
    import jax
    import jaxlib

    import bayesmotion  # noqa: F401  (float64; the XLA pool policy, before JAX starts)

    res = globals()[f"_{name}"](cfg)
    return {**res, "jax": jax.__version__, "jaxlib": jaxlib.__version__,
            "PJRT_NPROC": os.environ.get("PJRT_NPROC"),
            "XLA_FLAGS": os.environ.get("XLA_FLAGS"),
            "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")}


# --------------------------------------------------------------------------- in the parent
def _env(pool: str) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PJRT_NPROC", "NPROC", "OPENBLAS_NUM_THREADS")
           and not k.startswith("BAYESMOTION_SET_")}
    env["PJRT_NPROC"] = "1" if pool == "one_thread" else str(len(os.sched_getaffinity(0)))
    env.setdefault("TQDM_DISABLE", "1")
    return env


def child(python: Path, name: str, pool: str, cfg: dict) -> dict:
    """Run one measurement in a child of ``python``; {"status": "hung"} after the timeout."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "out.json"
        cmd = [str(python), __file__, "--worker", name, "--out", str(path),
               "--cfg", json.dumps(cfg)]
        t, timeout = time.perf_counter(), TIMEOUT_S[name]
        try:
            r = subprocess.run(cmd, env=_env(pool), capture_output=True, text=True,
                               timeout=timeout, cwd=REPO)
        except subprocess.TimeoutExpired:
            return {"status": "hung", "timeout_s": timeout}
        if r.returncode or not path.exists():
            return {"status": "error", "error": r.stderr.strip().splitlines()[-3:]}
        return {"status": "ok", "child_wall_s": time.perf_counter() - t,
                **json.loads(path.read_text())}


def _median(runs: list[dict], key: str = "median_s"):
    vals = [r[key] for r in runs if r.get("status") == "ok" and key in r]
    return statistics.median(vals) if vals else None


def run(quick: bool, pythons: dict[str, Path] = PYTHONS) -> dict:
    cfg = QUICK if quick else FULL
    present = {k: p for k, p in pythons.items() if Path(p).exists()}
    per = {f"{v}/{pool}": {m: [] for m in MEASUREMENTS} for v in present for pool in POOLS}
    for _ in range(cfg["rounds"]):
        for m in MEASUREMENTS:
            for v, py in present.items():
                for pool in POOLS:
                    runs = per[f"{v}/{pool}"][m]
                    hung_before = any(r["status"] in ("hung", "skipped") for r in runs)
                    runs.append({"status": "skipped", "reason": "hung in an earlier round"}
                                if hung_before else child(py, m, pool, cfg))
    key = {m: "seconds_per_iteration" if m == "map_fit" else "median_s" for m in MEASUREMENTS}
    table = {col: {m: _median(runs[m], key[m]) for m in MEASUREMENTS} for col, runs in per.items()}
    hung = {col: {m: sum(r.get("status") == "hung" for r in runs[m]) for m in MEASUREMENTS}
            for col, runs in per.items()}
    versions = {col: next(({"jax": r["jax"], "jaxlib": r["jaxlib"]} for rs in runs.values()
                           for r in rs if r.get("status") == "ok"), None)
                for col, runs in per.items()}
    rows = []
    default = {"jax09": "jax09/per_core", "jax010": "jax010/one_thread"}
    if set(default) <= set(present):
        for m in MEASUREMENTS:
            a, b = table[default["jax09"]][m], table[default["jax010"]][m]
            rows.append(headline(f"{m}: jax 0.10 / jax 0.9 (package defaults)",
                                 b / a if a and b else None, "x",
                                 note=f"0.10: {_ms(b)}, 0.9: {_ms(a)}"))
    if "jax010" in present:
        for m in MEASUREMENTS:
            a, b = table["jax010/per_core"][m], table["jax010/one_thread"][m]
            n = hung["jax010/per_core"][m]
            rows.append(headline(f"{m}: jax 0.10 one-thread pool / per-core pool",
                                 b / a if a and b else None, "x",
                                 note=f"one thread: {_ms(b)}, per core: {_ms(a)}"
                                 + (f"; per-core pool hung {n}/{cfg['rounds']}" if n else "")))
    return {"settings": {**cfg, "quick": quick, "measurements": list(MEASUREMENTS),
                         "pools": {"one_thread": "PJRT_NPROC=1",
                                   "per_core": "PJRT_NPROC=<cores available>"},
                         "package_default_pool": default,
                         "interpreters": {k: str(p) for k, p in pythons.items()},
                         "missing_interpreters": sorted(set(pythons) - set(present))},
            "versions": versions, "rounds": per, "median_s": table, "hung": hung,
            "headline": rows}


def _ms(v) -> str:
    return "--" if v is None else f"{v * 1e3:.0f} ms"


def _show(res: dict) -> str:
    lines = []
    for col, row in res["median_s"].items():
        cells = ", ".join(f"{m} {_ms(v)}" for m, v in row.items())
        lines.append(f"{col} ({res['versions'][col]}): {cells}; hung {res['hung'][col]}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", choices=MEASUREMENTS, help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    ap.add_argument("--cfg", help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="one round, fewer iterations")
    ap.add_argument("--python-09", default=str(PYTHONS["jax09"]),
                    help="interpreter with jax 0.9.x and bayesmotion (default .venv)")
    ap.add_argument("--python-010", default=str(PYTHONS["jax010"]),
                    help="interpreter with jax 0.10.x and bayesmotion (default .venv-jax010)")
    a = ap.parse_args(argv)
    if a.worker:
        from _common import write_json

        write_json(Path(a.out), measure_here(a.worker, json.loads(a.cfg)))
        return 0
    pythons = {"jax09": Path(a.python_09), "jax010": Path(a.python_010)}
    sys.argv = [sys.argv[0]] + (["--quick"] if a.quick else [])
    return standalone_main(NAME, lambda q: run(q, pythons), __doc__,
                           "one round, fewer iterations", _show)


if __name__ == "__main__":
    sys.exit(main())
