"""Run the bayesmotion benchmark suite and write benchmarks/results/.

    python benchmarks/run_all.py [--quick] [--only NAME ...] [--blas-threads N|inherit]

Every benchmark is a module ``benchmarks/<name>.py`` with ``run(quick: bool) -> dict``. Each one
runs in its own child process (fresh JAX caches, no interference between benchmarks, a hang or
crash in one does not stop the others) and its result is written atomically to
``results/<name>.json`` together with the machine info (CPU model, cores, versions, date, load)
and the settings. The environment is left alone by default (``--blas-threads``), so bayesmotion
applies its own OpenBLAS thread policy, as for a user (the
``blas_threads`` benchmark measures the default-thread case). ``results/README.md`` is then
rebuilt from every result file present: a markdown table of the headline numbers and targets.
The same table, and the interpolation study's table, are written into the documentation page
``docs/results.md`` between its markers (``--docs``, alias ``--readme``, does only that).

Adding a benchmark (e.g. emotion inference seconds per clip, the interpolation study): write
``benchmarks/<name>.py`` with ``run(quick) -> dict`` -- put the settings under ``"settings"``
and the README rows under ``"headline"`` (``_common.headline(metric, value, unit, target,
met, note)``) -- and append ``<name>`` to ``BENCHMARKS`` below.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import RESULTS, machine_info, write_json, write_text  # noqa: E402

# The suite, in run order. Hook: append the module name of a new benchmark here.
BENCHMARKS = [
    "gplvm_vs_gpy",
    "fit_time",
    "fit_convergence",
    "eval_scaling",
    "generation_fps",
    "sampler_ess",
    "blas_threads",
    "study_interpolation",
    "synthesis",
    "foot_contacts",
    "noise_floor",
    "transition_lengths",
    "sample_paths",
    "bandai_inference",
    "infer_speed",
    "batch_inference",
    "handshake_inference",
    "calibration_consistency",
    "posterior_convergence",
    "demo_posterior",
    "demo_quick",
    "pinned_threshold",
    "jax_versions",
    "sparse_scaling",
    "projection_starts",
    "projection_budget",
    "sparse_inference",
    "compile_cache",
    "first_call",
    "online_padding",
    "style_shear",
    "independence_refit",
    "walker_batching",
    "builtin_mixing",
    "chain_file",
]
TIMEOUT_S = {"quick": 20 * 60, "full": 90 * 60}


def run_one(name: str, quick: bool) -> dict:
    """Import and run one benchmark in this process; the result with machine info."""
    import bayesmotion  # noqa: F401  (float64 on, as in the package)

    start = machine_info()
    t0 = time.perf_counter()
    try:
        result = importlib.import_module(name).run(quick)
        status = "ok"
    except Exception as e:  # a failing benchmark is recorded, not fatal to the suite
        result = {"error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()}
        status = "error"
    machine = machine_info()
    machine["load_average_at_start"] = start["load_average_1_5_15"]
    return {"name": name, "mode": "quick" if quick else "full", "status": status,
            "wall_s": time.perf_counter() - t0, "machine": machine, **result}


def run_child(name: str, quick: bool, blas_threads: str = "inherit") -> dict:
    """Run one benchmark in a child process with a timeout; return what it wrote."""
    mode = "quick" if quick else "full"
    cmd = [sys.executable, __file__, "--worker", name] + (["--quick"] if quick else [])
    env = dict(os.environ)
    if blas_threads != "inherit":
        env["OPENBLAS_NUM_THREADS"] = blas_threads
    path = RESULTS / f"{name}.json"
    t0, started = time.perf_counter(), time.time()
    try:
        r = subprocess.run(cmd, timeout=TIMEOUT_S[mode], capture_output=True, text=True,
                           env=env)
        err = r.stderr.strip().splitlines()[-5:] if r.returncode else None
    except subprocess.TimeoutExpired:
        err = [f"timed out after {TIMEOUT_S[mode]} s"]
    if err is None and path.exists() and path.stat().st_mtime >= started:
        return json.loads(path.read_text())
    res = {"name": name, "mode": mode, "status": "error",
           "error": " | ".join(err or ["the worker wrote no result"]),
           "wall_s": time.perf_counter() - t0, "machine": machine_info()}
    write_json(path, res)
    return res


# --------------------------------------------------------------------------- README and docs
def _fmt(v) -> str:
    if v is None:
        return "--"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int | float):
        a = abs(v)
        if a == 0 or 1e-3 <= a < 1e6:
            return f"{v:,.3g}" if a < 1000 else f"{v:,.0f}"
        return f"{v:.2e}"
    return str(v)


def jax_versions(results: dict[str, dict]) -> str:
    """The jax version the results were measured with: the most common one, then each other
    version with the results it measured (e.g. "jax 0.9.2 (jax 0.10.2: study_interpolation)")."""
    by_version: dict[str, list[str]] = {}
    for name, r in results.items():
        by_version.setdefault(str(r.get("machine", {}).get("jax", "?")), []).append(name)
    if not by_version:
        return "jax ?"
    order = sorted(by_version, key=lambda v: -len(by_version[v]))
    rest = "; ".join(f"jax {v}: {', '.join(by_version[v])}" for v in order[1:])
    return f"jax {order[0]}" + (f" ({rest})" if rest else "")


def readme(results: dict[str, dict]) -> str:
    lines = ["# Benchmark results", "",
             "Written by `python benchmarks/run_all.py` (do not edit by hand). One JSON file per "
             "benchmark beside this file holds every measurement, the settings and the machine.",
             ""]
    machines = {(r["machine"]["cpu_model"], r["machine"]["cores"]) for r in results.values()
                if "machine" in r}
    for cpu, cores in sorted(machines):
        lines.append(f"Machine: {cpu}, {cores} cores.")
    any_r = next(iter(results.values()), {})
    m = any_r.get("machine", {})
    blas = sorted({str(r.get("machine", {}).get("thread_env", {}).get("OPENBLAS_NUM_THREADS"))
                   for r in results.values()})
    lines += [f"Python {m.get('python', '?')}, {jax_versions(results)}, numpy "
              f"{m.get('numpy', '?')}; float64 on CPU; OPENBLAS_NUM_THREADS={'/'.join(blas)} "
              "(None = OpenBLAS default; blas_threads compares both). Timings are wall-clock "
              "medians after warm-up; other processes may share the cores (each JSON records "
              "the load average at start and end).", "",
              "| benchmark | mode | metric | value | unit | target | met | note |",
              "|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        mode = r.get("mode", "?")
        date = r.get("machine", {}).get("date_utc", "")[:10]
        # records written by a benchmark's own command line (not run_all) carry no status
        ok = r.get("status", "error" if "error" in r else "ok") == "ok"
        if not ok:
            lines.append(f"| {name} | {mode} | **failed** | | | | | {r.get('error', '')} |")
            continue
        for i, h in enumerate(r.get("headline", [])):
            met = {True: "met", False: "**not met**", None: ""}[h.get("met")]
            label = f"{name} ({date})" if i == 0 else ""
            note = str(h.get("note", "")).replace("|", "/")
            metric = h["metric"].strip().replace("|", "\\|")
            lines.append(f"| {label} | {mode} | {metric} | {_fmt(h['value'])} | "
                         f"{h.get('unit', '')} | {h.get('target', '')} | {met} | {note} |")
    loads = [f"{n} {r['machine'].get('load_average_at_start', ['?'])[0]}"
             for n, r in results.items() if "machine" in r]
    lines += ["", "1-minute load average at each benchmark's start (2 cores): "
              + ", ".join(loads) + "."]
    quick = [n for n, r in results.items() if r.get("mode") == "quick"]
    if quick:
        lines += ["", f"**Quick mode** ({', '.join(quick)}): small sizes and capped iterations "
                      "(see each JSON's settings); targets that need the full run are not "
                      "judged there."]
    return "\n".join(lines) + "\n"


DOCS_RESULTS = HERE.parent / "docs" / "results.md"
START, END = "<!-- benchmarks:start -->", "<!-- benchmarks:end -->"
STUDY_START, STUDY_END = "<!-- study:start -->", "<!-- study:end -->"


def embed(text: str, table: str, start: str = START, end: str = END) -> str:
    """``text`` with what lies between the markers ``start`` and ``end`` replaced by ``table``
    (unchanged when the markers are missing)."""
    if start not in text or end not in text:
        return text
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{table}{end}{tail}"


def headline_table(results: dict[str, dict]) -> str:
    """The headline table of ``readme`` from "Machine:" on (no title, no file note)."""
    return readme(results).split("\n\n", 2)[2]


def study_table() -> str | None:
    """The interpolation study's table and conclusion, rendered from its committed JSON by
    ``study_interpolation.markdown_table``; None when there is no result file."""
    path = RESULTS / "study_interpolation.json"
    if not path.exists():
        return None
    import study_interpolation  # imports bayesmotion: only when the page is rendered

    return study_interpolation.markdown_table(json.loads(path.read_text())) + "\n"


def render_docs(page: str, results: dict[str, dict]) -> str:
    """The documentation page ``page`` with both generated blocks brought up to date."""
    page = embed(page, headline_table(results))
    study = study_table()
    return page if study is None else embed(page, study, STUDY_START, STUDY_END)


# result files written besides the suite's own runs, listed after the benchmark named: the 40
# clips of ``bandai_inference.py --all-contents``, the walks from jittered level starts and from
# three starts per level, the baselines alone on both sets of folds (``--baselines-only``)
# (``--start-jitter 0.02``), the sparse model with capped projections, plain and relative to each
# clip's content (``--inducing 100 --projection-iter 400 [--relative-to content]``), the relative
# model on the 40 clips with 50 inducing points and with longer fits (``--all-contents
# --projection-iter 400 --relative-to content`` with ``--inducing 50``, or with ``--inducing 100
# --fit-iter 1500 --refit-iter 300``), and
# ``device_timings.py --merge`` of a lent
# GPU's part with this CPU's (run by hand: the suite has no GPU), and this CPU's part alone
# (``device_timings.py``, with the newer infer_emotion variants)
EXTRA_RESULTS = {"bandai_inference": ("bandai_inference_all", "bandai_inference_jittered",
                                      "bandai_inference_starts3", "bandai_baselines",
                                      "bandai_inference_sparse100",
                                      "bandai_inference_sparse100_iter400",
                                      "bandai_inference_sparse100_iter400_starts3",
                                      "bandai_inference_all_sparse100_iter400",
                                      "bandai_inference_sparse100_iter400_relative",
                                      "bandai_inference_all_sparse100_iter400_relative",
                                      "bandai_inference_all_sparse100_iter400_starts3_relative",
                                      "bandai_inference_all_relative",
                                      "bandai_inference_all_sparse100_iter400_content_factor",
                                      "bandai_inference_all_sparse50_iter400_relative",
                                      "bandai_inference_all_sparse100_iter400_relative_fit1500_300",
                                      "bandai_inference_all_sparse100_iter400_relative_frameswhole"),
                 "infer_speed": ("device_timings", "device_timings_cpu"),
                 "synthesis": ("synthesis_by_kind", "synthesis_by_kind_seed1")}


def load_results() -> dict:
    results = {}
    for name in [n for b in BENCHMARKS for n in (b, *EXTRA_RESULTS.get(b, ()))]:
        p = RESULTS / f"{name}.json"
        if p.exists():
            results[name] = json.loads(p.read_text())
    return results


def write_readme() -> None:
    """results/README.md from every result file, and the generated blocks of docs/results.md."""
    results = load_results()
    write_text(RESULTS / "README.md", readme(results))
    if DOCS_RESULTS.exists():
        old = DOCS_RESULTS.read_text()
        new = render_docs(old, results)
        if new != old:
            write_text(DOCS_RESULTS, new)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, a few minutes in all")
    ap.add_argument("--only", nargs="+", choices=BENCHMARKS, metavar="NAME",
                    help=f"run only these ({', '.join(BENCHMARKS)})")
    ap.add_argument("--blas-threads", default="inherit", metavar="N",
                    help="OPENBLAS_NUM_THREADS for the benchmarks (default 'inherit': leave the "
                         "environment alone, so bayesmotion applies its own policy as for a "
                         "user: one OpenBLAS thread, except inside its large factorisations, "
                         "see bayesmotion._config; a number sets it for every library); "
                         "recorded in each JSON's machine.thread_env")
    ap.add_argument("--docs", "--readme", dest="docs", action="store_true",
                    help="only rebuild results/README.md and the tables of docs/results.md "
                         "from the JSON files (--readme: the same)")
    ap.add_argument("--worker", choices=BENCHMARKS, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    if a.worker:
        os.environ.setdefault("TQDM_DISABLE", "1")
        res = run_one(a.worker, a.quick)
        write_json(RESULTS / f"{a.worker}.json", res)  # an error is recorded in the JSON
        return 0
    if a.docs:
        write_readme()
        return 0
    failed = []
    for name in a.only or BENCHMARKS:
        print(f"[{time.strftime('%H:%M:%S')}] {name} ...", flush=True)
        res = run_child(name, a.quick, a.blas_threads)
        print(f"    {res['status']} in {res['wall_s']:.0f} s", flush=True)
        for h in res.get("headline", []):
            print(f"    {h['metric']}: {_fmt(h['value'])} {h.get('unit', '')}", flush=True)
        if res["status"] != "ok":
            failed.append(name)
            print(f"    {res.get('error')}", flush=True)
        write_readme()  # after each benchmark, so a stopped run still leaves a consistent table
    print(f"wrote {RESULTS}/README.md and {DOCS_RESULTS}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
