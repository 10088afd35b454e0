"""Effective samples per second: vectorised emcee vs a per-walker Python loop vs NUTS.

Small model: the built-in handshakes with one repetition at 10 fps (8 trials of 17 frames,
N = 136), MAP-fitted briefly; the sampled density is ``bayesmotion.inference.target``
(hyperparameters + training style vectors, latents at the MAP). The methods (``["methods"]``):

* ``emcee_vectorised``: ``sample_posterior(method="emcee")`` defaults: one ensemble, the jitted
  log-density over the walkers (``bayesmotion.gp.batch.over_points``: chunks of walkers under
  ``lax.map`` on a CPU), DE, style rotations and an independence step on the hyperparameters;
* ``emcee_vectorised_de``: the same with ``independence=False`` (DE and the rotations only);
* ``emcee_vectorised_factorised``: ``factorise=True``: gamma in its own ensemble, stepped every
  4 steps, the other coordinates in a second ensemble that never evaluates the bottom layer;
* ``emcee_vectorised_hmc``: ``hmc=True``: the default moves, then an ensemble-preconditioned HMC
  step on the hyperparameters and two-level style vectors (fewer steps: each costs ~10x a DE step);
* ``emcee_loop``: ``emcee_vectorised_de``'s walkers, steps, moves, seed, start, burn-in and
  thinning, but ``vectorize=False``: the un-vmapped jitted ``Target.logp`` once per walker;
* ``nuts``: ``sample_posterior(method="nuts")`` (numpyro, 2 sequential chains).

ESS per second: min over coordinates of arviz's bulk ESS (each walker / chain a chain) over the
sampler's wall time (JIT compilation and NUTS warm-up included). For the full built-in model
(24 trials, N = 816) the script times one ensemble step (joint and factorised), one HMC move and
one gradient, and projects the time to 1,000 ESS assuming the small model's ESS per step (emcee)
and per gradient (NUTS) carry over: a rough, optimistic extrapolation, labelled as such.

Current result (``results/sampler_ess.json``): ``["methods"][m]["min_ess_bulk_per_s"]`` is 45
default, 13 factorised, 7.0 DE only, 5.8 HMC, 5.8 loop, 2.6 NUTS (NUTS max R-hat 1.008, the
default emcee chain 1.016, the others 1.04-1.17); the best projection
(``["projected_s_to_1000_ess_builtin"]``), the default, is 1,743 s against the 120 s target.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
TARGET_ESS = 1000
TARGET_SECONDS = 120.0
NUTS_TIMEOUT_S = {"quick": 300, "full": 900}
GAMMA_EVERY = 4  # sample_posterior's default


def fit(n_repetitions: int, fps: float, max_iter: int):
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.spec import HGPDM

    ds = load_handshakes(fps=fps, n_repetitions=n_repetitions)
    return HGPDM().fit(ds, max_iter=max_iter, progress=False)


def _ess(chains: np.ndarray, acceptance) -> dict:
    from types import SimpleNamespace

    from bayesmotion.inference.diagnostics import convergence

    return convergence(SimpleNamespace(chains=chains, acceptance=np.asarray(acceptance)))


def _record(method, seconds, chains, acceptance, extra) -> dict:
    conv = _ess(chains, acceptance)
    ess = conv["min_ess_bulk"]
    return {"method": method, "seconds": seconds, **conv,
            "min_ess_bulk_per_s": ess / seconds,
            "projected_s_to_1000_ess": seconds * TARGET_ESS / ess,
            "draws_kept": int(chains.shape[0] * chains.shape[1]), **extra}


def run_vectorised(fitted, n_steps: int, factorise: bool = False, hmc: bool = False,
                   independence: bool | None = None) -> tuple[dict, object]:
    from bayesmotion.inference.sample import sample_posterior

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        post = sample_posterior(fitted, n_steps=n_steps, method="emcee", progress=False, seed=0,
                                factorise=factorise, hmc=hmc, independence=independence)
    info = post.info
    name = ("emcee_vectorised" + ("_factorised" if factorise else "")
            + ("_hmc" if hmc else "") + ("_de" if independence is False else ""))
    rec = _record(name, info["seconds"], post.chains, post.acceptance,
                  {"n_walkers": info["n_walkers"], "n_steps": n_steps, "burn": info["burn"],
                   "thin": info["thin"], "max_tau": float(np.max(info["tau"])),
                   "hmc_acceptance": info.get("hmc_acceptance"),
                   "independence_acceptance": info.get("independence_acceptance"),
                   "warnings": [str(x.message) for x in w]})
    return rec, post


def run_loop(post, n_steps: int) -> dict:
    """emcee with vectorize=False and the un-vmapped jitted logp, same start, moves and
    settings as the (joint, ``independence=False``) vectorised run ``post``."""
    import emcee
    import jax.numpy as jnp

    target = post.target
    W, ndim = post.info["n_walkers"], target.ndim
    centre, _ = target.conditional_map(progress=False)
    from bayesmotion.inference.proposals import default_moves
    from bayesmotion.inference.target import start_points

    p0 = start_points(target, centre, W, "laplace", 1e-3, np.random.default_rng(0))

    def log_prob(x):
        return float(target.logp(jnp.asarray(x)))

    moves = default_moves(target)  # DE followed by the style rotations, as in ``post``
    sampler = emcee.EnsembleSampler(W, ndim, log_prob, vectorize=False, moves=moves)
    state = emcee.State(p0, random_state=np.random.RandomState(0).get_state())
    t0 = time.perf_counter()
    sampler.run_mcmc(state, n_steps, progress=False)
    seconds = time.perf_counter() - t0
    chain = sampler.get_chain()[post.info["burn"]::post.info["thin"]]
    return _record("emcee_loop", seconds, np.swapaxes(chain, 0, 1),
                   sampler.acceptance_fraction,
                   {"n_walkers": W, "n_steps": n_steps, "burn": post.info["burn"],
                    "thin": post.info["thin"]})


def run_nuts_child(fitted, n_steps: int, timeout: float) -> dict:
    """NUTS in a child process (the fitted model passed as a model file), with a timeout."""
    with tempfile.TemporaryDirectory() as tmp:
        model, out = Path(tmp) / "model", Path(tmp) / "nuts.json"
        fitted.save(model)
        cmd = [sys.executable, __file__, "--nuts", str(model), "--steps", str(n_steps),
               "--out", str(out)]
        t0 = time.perf_counter()
        try:
            subprocess.run(cmd, check=True, capture_output=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"method": "nuts", "timed_out": True, "timeout_s": timeout,
                    "wall_s": time.perf_counter() - t0, "min_ess_bulk_per_s": None,
                    "projected_s_to_1000_ess": None, "n_warmup": n_steps,
                    "n_samples": n_steps, "n_chains": 2}
        return {"timed_out": False, **json.loads(out.read_text())}


def run_nuts(fitted, n_steps: int) -> dict:
    from bayesmotion.inference.sample import sample_posterior

    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        post = sample_posterior(fitted, n_steps=n_steps, method="nuts", progress=False, seed=0,
                                n_chains=2)
    return _record("nuts", post.info["seconds"], post.chains, post.acceptance,
                   {"n_chains": 2, "n_warmup": n_steps, "n_samples": n_steps,
                    "warnings": [str(x.message) for x in w]})


def eval_costs(fitted, repeats: int) -> dict:
    """Seconds of one vectorised ensemble step (all walkers) and one gradient of the target."""
    from types import SimpleNamespace

    import emcee
    import jax
    import jax.numpy as jnp
    from _common import block, timeit

    from bayesmotion.gp.batch import over_points
    from bayesmotion.inference.moves import EnsembleHMC
    from bayesmotion.inference.proposals import default_moves
    from bayesmotion.inference.target import Target

    def step_s(t, W):
        xs = jnp.asarray(t.x0 + 1e-3 * rng.standard_normal((W, t.ndim)))
        return timeit(lambda: block(t.logp_batch(xs)), repeats, warmup=1)["median_s"]

    rng = np.random.default_rng(0)
    target = Target(fitted)
    W = 2 * target.ndim + 2
    up = Target(fitted, block="upper")
    W_up = W  # the factorised sampler's default: 2 ndim + 2 walkers in both blocks (the
    # projection uses the ratio of the two sizes' step costs)
    factorised = (step_s(up, W_up)
                  + step_s(Target(fitted, block="bottom"), W_up) / GAMMA_EVERY)
    xs = jnp.asarray(target.x0 + 1e-3 * rng.standard_normal((W, target.ndim)))
    grad = jax.jit(jax.grad(target._logp))
    x0 = jnp.asarray(target.x0)
    # the other layouts: walkers one after another inside one jitted call, and one vmap
    mapped = jax.jit(lambda xs: jax.lax.map(target._logp, xs))
    vmapped = jax.jit(over_points(target._logp, None))
    # hmc=True adds one EnsembleHMC step (mean 3 leapfrog steps) on the non-rotated block
    hmc = next(m for m in default_moves(target, hmc=True).moves if isinstance(m, EnsembleHMC))
    hmc.n_leapfrog = (3, 3)
    fake = SimpleNamespace(random=np.random.RandomState(0))
    state = emcee.State(np.asarray(xs), log_prob=np.asarray(target.logp_batch(xs)))
    return {"ndim": target.ndim, "n_walkers": W, "N": int(fitted.data.lengths.sum()),
            "ensemble_step_s": timeit(lambda: block(target.logp_batch(xs)), repeats,
                                      warmup=1)["median_s"],
            "factorised_step_s": factorised, "factorised_n_walkers": W_up,
            "ensemble_step_lax_map_s": timeit(lambda: block(mapped(xs)), repeats,
                                              warmup=1)["median_s"],
            "ensemble_step_vmap_s": timeit(lambda: block(vmapped(xs)), repeats,
                                           warmup=1)["median_s"],
            "gradient_s": timeit(lambda: block(grad(x0)), repeats, warmup=1)["median_s"],
            "hmc_move_s": timeit(lambda: hmc.propose(fake, state), repeats,
                                 warmup=1)["median_s"],
            "single_logp_s": timeit(lambda: block(target.logp(x0)), repeats,
                                    warmup=1)["median_s"]}


def run(quick: bool) -> dict:
    from _common import headline

    steps = 100 if quick else 1000
    hmc_steps = 30 if quick else 300  # a step costs ~10x a DE step and mixes much faster
    nuts_steps = 100 if quick else 500
    fit_iter = 20 if quick else 200
    small = fit(1, 10.0, fit_iter)
    vec, _ = run_vectorised(small, steps)
    de, post_de = run_vectorised(small, steps, independence=False)
    fact, _ = run_vectorised(small, steps, factorise=True)
    with_hmc, _ = run_vectorised(small, hmc_steps, hmc=True)
    loop = run_loop(post_de, steps)
    nuts = run_nuts_child(small, nuts_steps, NUTS_TIMEOUT_S["quick" if quick else "full"])
    methods = {"emcee_vectorised": vec, "emcee_vectorised_de": de,
               "emcee_vectorised_factorised": fact,
               "emcee_vectorised_hmc": with_hmc, "emcee_loop": loop, "nuts": nuts}
    # projection to the full built-in model
    big = fit(3, 20.0, 3)
    c_small, c_big = eval_costs(small, 5), eval_costs(big, 2 if quick else 3)
    # a default step evaluates the density twice per walker (DE, independence step), as does
    # the hmc=True step before its HMC trajectories: the ratio of the two sizes' costs is that
    # of one evaluation
    proj = {"emcee_vectorised": vec["projected_s_to_1000_ess"] * c_big["ensemble_step_s"]
            / c_small["ensemble_step_s"],
            "emcee_vectorised_de": de["projected_s_to_1000_ess"] * c_big["ensemble_step_s"]
            / c_small["ensemble_step_s"],
            "emcee_vectorised_factorised": fact["projected_s_to_1000_ess"]
            * c_big["factorised_step_s"] / c_small["factorised_step_s"],
            "emcee_vectorised_hmc": with_hmc["projected_s_to_1000_ess"]
            * (c_big["ensemble_step_s"] + c_big["hmc_move_s"])
            / (c_small["ensemble_step_s"] + c_small["hmc_move_s"])}
    if not nuts["timed_out"]:
        proj["nuts"] = (nuts["projected_s_to_1000_ess"] * c_big["gradient_s"]
                        / c_small["gradient_s"])
    rows = []
    for name, r in methods.items():
        note = (f"not finished after {r['timeout_s']:.0f} s ({r['n_warmup']} warm-up + "
                f"{r['n_samples']} samples x {r['n_chains']} chains), stopped"
                if r.get("timed_out") else
                f"{r['seconds']:.1f} s, min ESS {r['min_ess_bulk']:.0f}, "
                f"R-hat {r['max_rhat']:.3f}")
        rows.append(headline(f"{name}: min bulk ESS / s (small model, N={c_small['N']})",
                             r["min_ess_bulk_per_s"], "1/s", note=note))
    best = min(proj, key=proj.get)
    rows.append(headline("  vectorised / loop emcee speed-up (DE and rotations)",
                         loop["seconds"] / de["seconds"], "x",
                         note=f"built-in model, one ensemble step: default "
                              f"{c_big['ensemble_step_s']:.2f} s, one vmap "
                              f"{c_big['ensemble_step_vmap_s']:.2f} s, lax.map "
                              f"{c_big['ensemble_step_lax_map_s']:.2f} s, loop "
                              f"{c_big['single_logp_s'] * c_big['n_walkers']:.2f} s; "
                              f"factorised {c_big['factorised_step_s']:.2f} s"))
    rows.append(headline(f"projected time to 1000 ESS, built-in model (N={c_big['N']}, "
                         f"{c_big['ndim']} dims), best = {best}", proj[best], "s",
                         f"< {TARGET_SECONDS:g} s", proj[best] < TARGET_SECONDS,
                         "extrapolated from the small model's ESS per step/gradient"))
    return {
        "settings": {"small_model": "load_handshakes(fps=10, n_repetitions=1): 8 trials",
                     "fit_max_iter_small": fit_iter,
                     "emcee_steps": steps, "emcee_hmc_steps": hmc_steps,
                     "nuts_warmup_and_samples": nuts_steps,
                     "nuts_chains": 2, "seed": 0, "quick": quick,
                     "builtin_model": "load_handshakes(): 24 trials, fitted 3 iterations "
                                      "(cost measurement only)"},
        "methods": methods,
        "eval_costs": {"small": c_small, "builtin": c_big},
        "projected_s_to_1000_ess_builtin": proj,
        "projection_assumptions": "ESS per ensemble step (emcee) and per gradient (NUTS) of "
                                  "the small model carried over to the built-in model; real "
                                  "autocorrelation times grow with the dimension, so these "
                                  "are lower bounds",
        "headline": rows,
    }


if __name__ == "__main__":
    sys.path.insert(0, str(HERE))
    ap = argparse.ArgumentParser()
    ap.add_argument("--nuts", required=True, help="model file to sample")
    ap.add_argument("--steps", type=int, required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    from _common import write_json

    from bayesmotion.model.io import load

    write_json(Path(a.out), run_nuts(load(a.nuts), a.steps))
