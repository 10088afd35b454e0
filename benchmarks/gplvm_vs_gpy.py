"""One GP-LVM layer (RBF + noise, eq. 2): bayesmotion vs GPy, value + gradient.

bayesmotion: ``jax.jit(jax.value_and_grad(...))`` of the negative log-likelihood over one flat
vector (latents X and log gamma), as ``fit_hgpdm`` does. GPy: ``GPy.models.GPLVM`` with the same
data and hyperparameters, timing ``model._objective_grads(x)`` (sets the parameters, recomputes
the likelihood and its gradients: what GPy's optimiser calls per step).

GPy lives in its own environment, ``benchmarks/.gpy-venv`` (created on first use with
``python -m venv`` + ``pip install GPy`` + this repository editable, pinned to this
interpreter's jax/numpy versions); this module then re-runs itself there in a subprocess so both
libraries are timed in one process. If GPy cannot be installed the result says why and holds
the bayesmotion timing only.

Parameterisation: GPy RBF ``variance * exp(-r^2 / (2 l^2))`` and Gaussian noise variance
``s2`` are bayesmotion's ``gamma = (variance, 1 / l^2, 1 / s2)``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
VENV = HERE / ".gpy-venv"
SIZES = {"N": 1000, "D": 60, "Q": 6}
HYPER = {"variance": 1.3, "lengthscale": 1.7, "noise_variance": 0.05}
TARGET_SPEEDUP = 2.0
RUN_LENGTH = 4  # steady-state timing: runs of 4 calls per library, the first of each dropped


def make_data(N: int, D: int, Q: int, seed: int = 0):
    """Seeded smooth data: X (N, Q) smooth latent paths, Y (N, D) a smooth map of X + noise."""
    from _common import smooth_latents, smooth_outputs

    rng = np.random.default_rng(seed)
    X = smooth_latents(N, Q, rng)
    X = X / X.std(0)
    return X, smooth_outputs(X, D, rng)


def bayesmotion_call(X, Y):
    """(call, nll, dNLL/dX): the jitted value-and-gradient over flat [X, log gamma]."""
    import jax
    import jax.numpy as jnp
    from _common import block
    from jax.flatten_util import ravel_pytree

    from bayesmotion.gp.densities import gplvm_loglik

    gamma = np.array([HYPER["variance"], HYPER["lengthscale"] ** -2, 1 / HYPER["noise_variance"]])
    x0, unravel = ravel_pytree({"X": jnp.asarray(X), "log_gamma": jnp.log(gamma)})

    def nll(x):
        p = unravel(x)
        return -gplvm_loglik(p["X"], jnp.asarray(Y), jnp.exp(p["log_gamma"]), 0.0)

    vg = jax.jit(jax.value_and_grad(nll))
    v, g = block(vg(x0))
    return (lambda: block(vg(x0))), float(v), np.asarray(unravel(g)["X"])


def generic_call(X, Y):
    """The same layer through the generic path the other layers use: autodiff of the kernel,
    with the hand-written dlogp/dK of ``gaussian_loglik``. Same value; timed beside the fused
    VJP of ``gplvm_loglik`` to show what writing out the RBF chain rule buys."""
    import jax
    import jax.numpy as jnp
    from _common import block
    from jax.flatten_util import ravel_pytree

    from bayesmotion.gp import kernels
    from bayesmotion.gp.densities import gaussian_loglik

    gamma = np.array([HYPER["variance"], HYPER["lengthscale"] ** -2, 1 / HYPER["noise_variance"]])
    x0, unravel = ravel_pytree({"X": jnp.asarray(X), "log_gamma": jnp.log(gamma)})

    def nll(x):
        p = unravel(x)
        g = jnp.exp(p["log_gamma"])
        K = kernels.bottom_kernel(p["X"], p["X"], g) + jnp.eye(X.shape[0]) / g[2]
        return -gaussian_loglik(K, jnp.asarray(Y))

    vg = jax.jit(jax.value_and_grad(nll))
    v, g = block(vg(x0))
    return (lambda: block(vg(x0))), float(v), np.asarray(unravel(g)["X"])


def gpy_call(X, Y):
    """(call, nll, dNLL/dX) of GPy's GPLVM at the same point (GPy adds 1e-8 to the noise)."""
    import GPy

    Q = X.shape[1]
    kern = GPy.kern.RBF(Q, variance=HYPER["variance"], lengthscale=HYPER["lengthscale"])
    m = GPy.models.GPLVM(Y, Q, X=X.copy(), kernel=kern)
    m.likelihood.variance = HYPER["noise_variance"]
    x = m.optimizer_array.copy()
    m._objective_grads(x)
    dX = -np.asarray(m.latent_mean.gradient)  # GPy stores d loglik / dX
    return (lambda: m._objective_grads(x)), float(m.objective_function()), dX


def interleaved(calls: dict, repeats: int, run_length: int = 1) -> dict:
    """Time several calls alternately (one warm-up each), so load changes hit all alike.

    ``run_length`` 1 alternates call by call; each call then starts while the previous call's
    BLAS threads (OpenBLAS busy-waits after a call) still hold the cores, which slowed both
    libraries here (bayesmotion 30 -> 38 ms, GPy 74 -> 82 ms). With ``run_length`` k > 1 each
    library runs k times in a row and the first of each run is dropped: the steady state of a
    fit, which calls the same objective back to back, still alternating in runs over the
    measurement."""
    from _common import summarise

    for fn in calls.values():
        fn()
    times = {k: [] for k in calls}
    cpu = {k: [] for k in calls}
    for _ in range(repeats):
        for k, fn in calls.items():
            for i in range(run_length):
                t0, c0 = time.perf_counter(), time.process_time()
                fn()
                if i > 0 or run_length == 1:
                    times[k].append(time.perf_counter() - t0)
                    cpu[k].append(time.process_time() - c0)
    return {k: summarise(times[k], cpu[k]) for k in calls}


def measure(quick: bool, with_gpy: bool = True) -> dict:
    """Time both libraries on the same data in this process."""
    from _common import headline, versions

    repeats = 5 if quick else 15
    X, Y = make_data(**SIZES)
    bm_fn, bm_nll, bm_dX = bayesmotion_call(X, Y)
    cv_fn, cv_nll, cv_dX = generic_call(X, Y)
    calls = {"bayesmotion": bm_fn, "generic_layer_path": cv_fn}
    if with_gpy:
        gp_fn, gp_nll, gp_dX = gpy_call(X, Y)
        calls["gpy"] = gp_fn
    alternating = interleaved(calls, repeats)
    t = interleaved(calls, repeats, run_length=RUN_LENGTH)
    out = {"settings": {**SIZES, **HYPER, "repeats": repeats, "warmup": 1, "seed": 0,
                        "data": "smooth sinusoid latents, tanh-feature map to Y, 5% noise, "
                                "standardised columns",
                        "bayesmotion_call": "jit(value_and_grad(-gplvm_loglik)) over flat "
                                            "[X, log gamma], jitter 0",
                        "gpy_call": "GPLVM._objective_grads(optimizer_array)",
                        "timing": f"the calls alternate in runs of {RUN_LENGTH}, the first "
                                  "of each run dropped (steady state, as in a fit); "
                                  "'alternating' alternates call by call"},
           "environment": versions(),
           "bayesmotion": {**t["bayesmotion"], "nll": bm_nll},
           "generic_layer_path": {
               **t["generic_layer_path"], "nll": cv_nll,
               "grad_X_max_relative_difference_vs_bayesmotion": float(
                   np.max(np.abs(cv_dX - bm_dX)) / np.max(np.abs(bm_dX))),
               "what": " ".join(generic_call.__doc__.split())}}
    if not with_gpy:
        return out
    bm_t, gp_t = t["bayesmotion"], t["gpy"]
    ratio = gp_t["median_s"] / bm_t["median_s"]
    alt_ratio = alternating["gpy"]["median_s"] / alternating["bayesmotion"]["median_s"]
    # GPy factorises K + (noise_variance + 1e-8) I: the same value up to that shift
    rel = abs(bm_nll - gp_nll) / abs(gp_nll)
    shifted = gpy_equivalent_nll(X, Y)
    out.update(gpy={**gp_t, "nll": gp_nll}, speedup_vs_gpy=ratio,
               alternating={**alternating, "speedup_vs_gpy": alt_ratio},
               nll_relative_difference=rel,
               nll_relative_difference_with_gpy_1e8_noise_shift=abs(shifted - gp_nll)
               / abs(gp_nll),
               grad_X_max_relative_difference=float(np.max(np.abs(bm_dX - gp_dX))
                                                    / np.max(np.abs(gp_dX))))
    out["headline"] = [
        headline("GP-LVM layer value+grad, N=1000 D=60 Q=6", bm_t["median_s"] * 1e3, "ms"),
        headline("  GPy GPLVM, same", gp_t["median_s"] * 1e3, "ms"),
        headline("  speed-up over GPy", ratio, "x", f">= {TARGET_SPEEDUP:g}x",
                 ratio >= TARGET_SPEEDUP,
                 f"min-time ratio {gp_t['min_s'] / bm_t['min_s']:.2f}; alternating call by call "
                 f"{alternating['bayesmotion']['median_s'] * 1e3:.1f} vs "
                 f"{alternating['gpy']['median_s'] * 1e3:.1f} ms, {alt_ratio:.2f}x"),
        headline("  generic layer path (kernel autodiff + dlogp/dK), same layer",
                 t["generic_layer_path"]["median_s"] * 1e3, "ms",
                 note=f"{gp_t['median_s'] / t['generic_layer_path']['median_s']:.2f}x GPy"),
        headline("  |NLL difference| / |NLL|", rel, "", "< 1e-6", rel < 1e-6,
                 "GPy adds 1e-8 to the noise variance; with that shift: "
                 f"{out['nll_relative_difference_with_gpy_1e8_noise_shift']:.1e}"),
    ]
    return out


def gpy_equivalent_nll(X, Y) -> float:
    """bayesmotion's NLL with GPy's noise variance + 1e-8 (should equal GPy's to ~1e-12)."""
    import jax.numpy as jnp

    from bayesmotion.gp.densities import gplvm_loglik

    gamma = jnp.array([HYPER["variance"], HYPER["lengthscale"] ** -2,
                       1 / (HYPER["noise_variance"] + 1e-8)])
    return float(-gplvm_loglik(jnp.asarray(X), jnp.asarray(Y), gamma, 0.0))


# --------------------------------------------------------------------------- GPy environment
def _pins() -> list[str]:
    """Pin the GPy venv's jax/jaxlib/numpy to this interpreter's versions (same numerics)."""
    import importlib.metadata as md

    pins = []
    for name in ("jax", "jaxlib", "numpy", "scipy"):
        try:
            pins.append(f"{name}=={md.version(name)}")
        except md.PackageNotFoundError:
            pass
    return pins


def _pip(py: Path, *args: str) -> tuple[bool, str]:
    r = subprocess.run([str(py), "-m", "pip", "install", "--quiet", *args],
                       capture_output=True, text=True)
    lines = [l for l in (r.stderr + r.stdout).splitlines() if l.strip()]
    errors = [l for l in lines if "error" in l.lower()] or lines[-1:]
    return r.returncode == 0, (errors[0] if errors else "")


def ensure_venv() -> tuple[Path | None, str]:
    """The GPy venv's python (creating it if needed), or (None, the pip error line)."""
    py = VENV / "bin" / "python"
    check = [str(py), "-c", "import GPy, bayesmotion"]
    if py.exists() and subprocess.run(check, capture_output=True).returncode == 0:
        return py, ""
    if not py.exists():
        r = subprocess.run([sys.executable, "-m", "venv", str(VENV)], capture_output=True,
                           text=True)
        if r.returncode:
            return None, f"python -m venv failed: {r.stderr.strip().splitlines()[-1:]}"
    pins = _pins()
    ok, err = _pip(py, "GPy", *pins)
    if not ok:  # GPy releases before numpy 2 support: try an older numpy
        pins = [p for p in pins if not p.startswith("numpy")]
        ok, err2 = _pip(py, "GPy", "numpy<2", *pins)
        if not ok:
            return None, f"{err} | with numpy<2: {err2}"
    ok, err = _pip(py, "-e", str(REPO), *pins)
    return (py, "") if ok else (None, f"installing bayesmotion into the GPy venv: {err}")


def gpy_only(quick: bool) -> dict:
    """GPy alone, in a process where bayesmotion was never imported (so OpenBLAS keeps its own
    default thread count instead of bayesmotion's one thread)."""
    from _common import summarise

    X, Y = make_data(**SIZES)
    fn, _, _ = gpy_call(X, Y)
    fn()
    times = []
    for _ in range(5 if quick else 15):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return summarise(times)


def _add_gpy_default_threads(res: dict, py: Path, quick: bool, tmp: Path) -> None:
    """Time GPy once more with OpenBLAS's default threads: the same-process comparison runs it
    with bayesmotion's OPENBLAS_NUM_THREADS=1, which a GPy user would not have set."""
    import os

    out = tmp / "gpy_default.json"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    cmd = [str(py), __file__, "--out", str(out), "--gpy-only"] + (["--quick"] if quick else [])
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    except subprocess.TimeoutExpired:
        res["gpy_default_blas_threads"] = {"failed": "timed out after 600 s"}
        return
    if r.returncode:
        res["gpy_default_blas_threads"] = {"failed": (r.stderr.strip().splitlines() or ["?"])[-1]}
        return
    t = json.loads(out.read_text())
    ratio = t["median_s"] / res["bayesmotion"]["median_s"]
    res["gpy_default_blas_threads"] = {**t, "speedup_vs_gpy": ratio,
                                       "note": "separate process, same data, run after the "
                                               "same-process comparison"}
    for h in res.get("headline", []):
        if h["metric"].strip() == "speed-up over GPy":
            h["note"] += f"; vs GPy with OpenBLAS's default threads (own process) {ratio:.2f}x"


def run(quick: bool) -> dict:
    from _common import headline

    try:
        import GPy  # noqa: F401

        return measure(quick)
    except ImportError:
        pass
    py, reason = ensure_venv()
    if py is not None:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out.json"
            cmd = [str(py), __file__, "--out", str(out)] + (["--quick"] if quick else [])
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode == 0:
                res = json.loads(out.read_text())
                res["ran_in"] = str(VENV.relative_to(REPO))
                _add_gpy_default_threads(res, py, quick, Path(tmp))
                return res
            reason = f"GPy run failed: {(r.stderr.strip().splitlines() or ['?'])[-1]}"
    res = measure(quick, with_gpy=False)
    res.update(gpy=None, skipped_reason=reason)
    res["headline"] = [
        headline("GP-LVM layer value+grad, N=1000 D=60 Q=6",
                 res["bayesmotion"]["median_s"] * 1e3, "ms"),
        headline("  speed-up over GPy", None, "x", f">= {TARGET_SPEEDUP:g}x", None,
                 f"GPy skipped: {reason}"),
    ]
    return res


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", required=True)
    ap.add_argument("--gpy-only", action="store_true")
    a = ap.parse_args()
    from _common import write_json

    write_json(Path(a.out), gpy_only(a.quick) if a.gpy_only else measure(a.quick))
