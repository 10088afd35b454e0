"""OpenBLAS threading: the same kernels with the default thread count and with one thread.

JAX's CPU Cholesky and triangular solves call LAPACK/BLAS from SciPy's OpenBLAS (so does
NumPy); OpenBLAS's threads busy-wait, and when the cores are oversubscribed (other processes,
XLA's own thread pool) its threaded ``potrf`` can become many times slower than one thread.
This benchmark measures, in child processes that differ only in ``OPENBLAS_NUM_THREADS``
(unset = OpenBLAS default, one per core, vs 1), alternating the two settings round by round:

* NumPy and JAX Cholesky of a 1000 x 1000 matrix;
* the GP-LVM layer value + gradient of ``gplvm_vs_gpy`` (N = 1000, D = 60, Q = 6);
* the full log-posterior value + gradient at the built-in size (24 trials x 37 frames).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SETTINGS = {"default": None, "one_thread": "1"}


def measure_here(repeats: int) -> dict:
    """The three measurements in this process (thread settings come from the environment)."""
    import jax
    import jax.numpy as jnp
    from _common import block, timeit
    from jax.flatten_util import ravel_pytree

    import bayesmotion  # noqa: F401  (float64)
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.data import fit_codecs, prepare_data
    from bayesmotion.model.fit import init_params
    from bayesmotion.model.logpost import LogPosterior
    from bayesmotion.model.spec import HGPDM

    rng = np.random.default_rng(0)
    A = rng.standard_normal((1000, 1000))
    K = A @ A.T + 1000 * np.eye(1000)
    chol = jax.jit(jnp.linalg.cholesky)
    Kj = jnp.asarray(K)
    out = {"numpy_cholesky_1000": timeit(lambda: np.linalg.cholesky(K), repeats),
           "jax_cholesky_1000": timeit(lambda: block(chol(Kj)), repeats)}
    from gplvm_vs_gpy import SIZES, bayesmotion_call, make_data

    fn, _, _ = bayesmotion_call(*make_data(**SIZES))
    out["gplvm_layer_value_grad_1000"] = timeit(fn, repeats)
    ds = load_handshakes()
    spec = HGPDM().resolved(ds)
    data = prepare_data(spec, ds, fit_codecs(spec, ds))
    logp = LogPosterior(spec, data)
    x0, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in init_params(spec, data).items()})
    vg = jax.jit(jax.value_and_grad(lambda x: -logp(unravel(x), 1e-8)))
    out["log_posterior_value_grad_builtin"] = timeit(lambda: block(vg(x0)), repeats)
    return {k: {"median_s": v["median_s"], "min_s": v["min_s"]} for k, v in out.items()}


def child(setting: str, repeats: int) -> dict:
    env = dict(os.environ)
    env.pop("OPENBLAS_NUM_THREADS", None)
    if SETTINGS[setting] is not None:
        env["OPENBLAS_NUM_THREADS"] = SETTINGS[setting]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "out.json"
        subprocess.run([sys.executable, __file__, "--out", str(path), "--repeats",
                        str(repeats)], env=env, check=True, capture_output=True, timeout=1200)
        return json.loads(path.read_text())


def run(quick: bool) -> dict:
    from _common import headline

    rounds, repeats = (1, 3) if quick else (3, 5)
    per = {s: [] for s in SETTINGS}
    for _ in range(rounds):
        for s in SETTINGS:
            per[s].append(child(s, repeats))
    summary = {s: {k: statistics.median(r[k]["median_s"] for r in runs) for k in runs[0]}
               for s, runs in per.items()}
    ratio = {k: summary["default"][k] / summary["one_thread"][k] for k in summary["default"]}
    rows = [headline(f"{k}: default threads / 1 thread", v, "x",
                     note=f"{summary['default'][k] * 1e3:.0f} ms vs "
                          f"{summary['one_thread'][k] * 1e3:.0f} ms")
            for k, v in ratio.items()]
    return {"settings": {"rounds": rounds, "repeats": repeats, "quick": quick,
                         "thread_settings": {k: v or "unset" for k, v in SETTINGS.items()}},
            "rounds": per, "median_over_rounds_s": summary,
            "slowdown_default_over_one_thread": ratio, "headline": rows}


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    from _common import write_json

    write_json(Path(a.out), measure_here(a.repeats))
