"""Shared helpers of the benchmark suite: machine info, timing, atomic JSON, synthetic data."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
BANDAI_ROOT = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "bandai-emotion"
"""Where the shared Bandai clips are beside a checkout (never copied into the repository)."""


def bandai_present(root: Path) -> bool:
    """Whether ``root`` holds the Bandai clips (its ``data/`` folder or BVH files)."""
    return (root / "data").is_dir() or any(root.glob("*.bvh"))


def cpu_model() -> str:
    """CPU model name from /proc/cpuinfo (or platform.processor() elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def versions() -> dict:
    """Python and numerical-library versions of this interpreter."""
    out = {"python": platform.python_version(), "numpy": np.__version__}
    for name in ("jax", "jaxlib", "scipy", "emcee", "numpyro", "GPy"):
        mod = sys.modules.get(name)
        if mod is not None:
            out[name] = getattr(mod, "__version__", "?")
    return out


THREAD_ENV = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "XLA_FLAGS")


def machine_info() -> dict:
    """CPU, cores, memory, load, thread settings and library versions, with the date (UTC)."""
    mem = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                mem = round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return {
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "memory_gib": mem,
        "load_average_1_5_15": [round(x, 2) for x in os.getloadavg()],
        "platform": platform.platform(),
        "date_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "thread_env": {k: os.environ.get(k) for k in THREAD_ENV},
        **versions(),
    }


def cached_fit(path: Path | None, fit: Callable[[], object], what: str = "the model"):
    """A fitted model read from ``path`` when it is there, else ``fit()`` written to it (when
    ``path`` is given; atomic, so a stopped run leaves no half-written file). MAP fits are not
    bit-reproducible (the layers' factorisations take more OpenBLAS threads when cores are
    idle), so a cached fit is what lets a benchmark resume a chain keyed on its parameters. An
    unreadable file is refitted and replaced."""
    from bayesmotion import load
    from bayesmotion.errors import ModelFileError

    if path is not None and Path(path).exists():
        try:
            return load(path)
        except ModelFileError as e:
            import warnings

            warnings.warn(f"refitting {what}: {e}", stacklevel=2)
    model = fit()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        model.save(path)
    return model


def saved_demo_model(folder: Path, fps: float, max_iter: int):
    """The demo's split of the built-in handshakes at ``fps`` (``bayesmotion.app.demo._split``:
    the training trials and one held-out trial per emotion) and ``HGPDM()`` fitted by MAP on the
    training trials for ``max_iter`` iterations, saved as ``folder/model.npz``.
    Returns (model path, train, held)."""
    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.spec import HGPDM

    train, held = _split(load_handshakes(fps=fps))
    path = Path(folder) / "model.npz"
    HGPDM().fit(train, max_iter=max_iter, progress=False).save(path)
    return path, train, held


def write_json(path: Path, obj: dict) -> None:
    """Write JSON atomically: a temp file in the same folder, then os.replace."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(to_jsonable(obj), f, indent=2, allow_nan=False)
            f.write("\n")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def to_jsonable(x):
    """NumPy scalars/arrays -> Python; non-finite floats -> None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, np.bool_ | bool):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating | float):
        return float(x) if np.isfinite(x) else None
    return x


def block(x):
    """Wait for every JAX array in a pytree (asynchronous dispatch) and return it."""
    import jax

    return jax.block_until_ready(x)


def timeit(fn: Callable[[], object], repeats: int = 5, warmup: int = 1) -> dict:
    """Median wall-clock seconds of ``fn()`` over ``repeats`` calls after ``warmup`` calls.

    ``fn`` must block until its result is ready (wrap JAX calls with :func:`block`).
    """
    for _ in range(warmup):
        fn()
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return summarise(times, cpu, warmup)


def summarise(times: list[float], cpu: list[float] | None = None, warmup: int = 1) -> dict:
    """Median/min/max of wall-clock times (and the median process CPU time, all threads)."""
    out = {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times),
           "repeats": len(times), "warmup": warmup, "times_s": times}
    if cpu:
        out["median_cpu_s"] = statistics.median(cpu)
    return out


def headline(metric: str, value, unit: str, target: str = "", met: bool | None = None,
             note: str = "") -> dict:
    """One row of the README table."""
    return {"metric": metric, "value": value, "unit": unit, "target": target, "met": met,
            "note": note}


# --------------------------------------------------------------------------- synthetic data
def smooth_latents(n_frames: int, q: int, rng: np.random.Generator, n_terms: int = 3):
    """(n_frames, q) smooth trajectories: sums of random sinusoids of the frame index."""
    t = np.linspace(0.0, 1.0, n_frames)[:, None, None]
    freq = rng.uniform(0.3, 2.0, (1, n_terms, q))
    phase = rng.uniform(0, 2 * np.pi, (1, n_terms, q))
    amp = rng.normal(0, 1, (1, n_terms, q))
    return (amp * np.sin(2 * np.pi * freq * t + phase)).sum(1)


def smooth_outputs(X: np.ndarray, d: int, rng: np.random.Generator, noise: float = 0.05):
    """(N, d) outputs: random smooth (tanh-feature) map of X plus Gaussian noise, standardised."""
    W = rng.normal(0, 1, (X.shape[1], 4 * d)) / np.sqrt(X.shape[1])
    F = np.tanh(X @ W + rng.uniform(-1, 1, 4 * d))
    Y = F @ rng.normal(0, 1, (4 * d, d)) / np.sqrt(4 * d)
    Y = Y + noise * rng.standard_normal(Y.shape)
    return (Y - Y.mean(0)) / Y.std(0)


def synthetic_model_data(n_frames: int, d: int = 96, seed: int = 0, trial_len: int = 31):
    """A two-actor ModelData of ``n_frames`` frames in emotion (4) x couple (2) cells.

    Trials of about ``trial_len`` frames, labels cycling over the 8 cells, so the block-diagonal
    path has 8 blocks of about n_frames / 8 rows, like the built-in set.
    """
    from bayesmotion.model.data import ModelData

    rng = np.random.default_rng(seed)
    n_trials = max(8, round(n_frames / trial_len) // 8 * 8)
    lengths = np.full(n_trials, n_frames // n_trials)
    lengths[: n_frames - lengths.sum()] += 1
    cells = np.arange(n_trials) % 8
    onehot = {"couple": np.eye(2)[cells // 4], "emotion": np.eye(4)[cells % 4]}
    Ys = []
    for _ in range(2):
        X = np.concatenate([smooth_latents(n, 6, rng) for n in lengths])
        Ys.append(smooth_outputs(X, d, rng))
    tof = np.repeat(np.arange(n_trials), lengths)
    return ModelData(tuple(Ys), onehot, tof, lengths)


def bandai_skip(base: dict, root: Path, out: Path) -> dict:
    """The record of a Bandai benchmark run without its data: written to ``out``, returned."""
    result = {**base, "skipped": f"Bandai data not found at {root}", "headline": []}
    write_json(out, result)
    return result


def show_headlines(result: dict) -> str:
    """A result's headline rows, one per line, or why it was skipped (``standalone_main``'s
    ``show`` for benchmarks that write their own JSON)."""
    return "\n".join(map(str, result.get("headline", []))) + result.get("skipped", "")


def standalone_main(name: str, run: Callable[[bool], dict], doc: str, quick_help: str,
                    show: Callable[[dict], str]) -> int:
    """Command line of a benchmark module: ``--quick``, run, JSON to ``results/<name>.json``
    (atomic), print ``show(result)``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help=quick_help)
    a = ap.parse_args()
    import bayesmotion  # noqa: F401  (float64 on)

    res = run(a.quick)
    write_json(RESULTS / f"{name}.json", {"name": name, "mode": "quick" if a.quick else "full",
                                          **res, "status": "ok", "machine": machine_info()})
    print(show(res))
    return 0
