"""Posterior convergence at the demo size: how many emcee steps give max R-hat <= 1.01 and min
bulk ESS >= 400 over every sampled coordinate and the style vectors' Gram entries (the
demo-size target of the Bayesian layer).

The demo's model: ``load_handshakes(fps=10)`` without the 4 held-out trials (20 trials, N = 340
frames per actor), ``HGPDM().fit(max_iter=1000, seed=0)``; then ``sample_posterior`` with its
defaults (one ensemble of 2 ndim + 2 walkers started from the Laplace approximation; DE moves
in the shear's and the canonical style coordinates, followed by style rotations, then an
independence move whose proposal has one component per idle-factor mode,
``bayesmotion.inference.proposals.idle_factor_modes``, and which after its adaptation draws the
emotion styles' Gram factor with the hyperparameters; ``SAMPLER_VERSION``) for ``steps`` steps
into an emcee HDF5 backend. R-hat (rank-normalised, split, arviz) and
bulk/tail ESS are computed on the chain's first n steps for each n in ``checkpoints``, after
the package's own burn-in rule (2 max tau, at most half the chain, at least the independence
move's adaptation), with the walkers as arviz chains.

The fit is not bit-reproducible (the layers' factorisations take more OpenBLAS threads when
cores are idle, ``bayesmotion.gp.blas``), so the fitted model is cached in ``benchmarks/.cache``
(``posterior_convergence_model_<max_iter>_<version>.npz``) and the chain beside it under a hash
of the fitted parameters and ``SAMPLER_VERSION``: a run stopped by the suite's timeout, or one
with ``steps`` raised (checkpoints past it are skipped), resumes from the file.

Current result (``results/posterior_convergence.json``, full settings, 54 walkers, 26 dims,
Gram entries counted): both targets are met from 800 steps (``["checkpoints"][4]``: max R-hat
1.0099, min bulk ESS 4,637; 303 s from scratch; at 1,000 steps 1.0077 and 6,613, 379 s), the
bulk-ESS target alone from 300 steps; at 2,000 steps max R-hat 1.0030, min bulk ESS 15,779.
Worst coordinates (``["worst_coordinate_names"]``): the couple's style coordinates, the neutral
emotion's Gram entry and ``log_gamma[2]``. ``["seconds_per_step"]`` 0.38, over the steps
sampled after ``["resumed_from_step"]``. The
full demo samples this chain for ``bayesmotion.app.demo.SETTINGS["full"]["n_steps"]`` steps.
"""

from __future__ import annotations

import hashlib
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / ".cache"
SETTINGS = {"full": {"max_iter": 1000, "steps": 2000,
                     "checkpoints": [300, 400, 500, 600, 800, 1000, 1200, 1600, 2000, 3000,
                                     4000, 6000, 8000]},
            "quick": {"max_iter": 150, "steps": 300, "checkpoints": [100, 200, 300]}}
TARGET_RHAT, TARGET_ESS = 1.01, 400


def model_path(max_iter: int) -> Path:
    """The cached demo model of this package version and fit length."""
    from bayesmotion import __version__

    return CACHE / f"posterior_convergence_model_{max_iter}_{__version__}.npz"


def demo_model(max_iter: int, cache: Path | None = None):
    """The demo's MAP fit; with ``cache`` (a file, :func:`model_path`), read from it or written
    to it (``_common.cached_fit``), so the chain keyed on its parameters can be resumed."""
    from _common import cached_fit

    from bayesmotion import HGPDM, load_handshakes
    from bayesmotion.app.demo import _split

    def fit():
        train, _ = _split(load_handshakes(seed=0, fps=10.0))
        return HGPDM().fit(train, max_iter=max_iter, seed=0, progress=False)

    return cached_fit(cache, fit, "the demo model")


# part of the cache key, so a chain run with other default moves or coordinates is not resumed:
# edit it whenever sample_posterior's default moves or sampled coordinates change
SAMPLER_VERSION = ("DE move (in the style shear's coordinates, the rotated style vectors through "
                   "their Gram's LQ factor, each walker keeping its rotation from the aligned "
                   "one) followed by StyleRotations with reflections, then an IndependenceMove "
                   "on the hyperparameters (Laplace proposal in the shear's coordinates for the "
                   "150-step adaptation; a mixture with one component per idle-factor mode), "
                   "after it on the hyperparameters and the Gram factors (canonical "
                   "coordinates, a t after sinh-arcsinh maps of each coordinate, fitted to the "
                   "adaptation and refitted at steps 250, 500 and 1000 to every state since it)")


def _key(model, extra: str = "") -> str:
    """A hash of :data:`SAMPLER_VERSION` (then ``extra``) and the fitted parameters: the name of
    a chain file that is resumed only by the same sampler on the same fit."""
    h = hashlib.sha1((SAMPLER_VERSION + extra).encode())
    for k in sorted(model.params):
        h.update(k.encode())
        h.update(np.ascontiguousarray(model.params[k], dtype=np.float64).tobytes())
    return h.hexdigest()[:12]


def checkpoint(chain: np.ndarray, n: int, adapt: int = 0, target=None) -> dict:
    """Diagnostics of the first ``n`` steps of an emcee chain (steps, walkers, ndim); the
    burn-in covers the ``adapt`` steps of the independence move's adaptation. With the chain's
    ``target``, the style vectors' Gram entries (what the likelihood identifies of them,
    ``bayesmotion.inference.target.gram_entries``) count beside the sampled coordinates, as in
    ``sample_posterior``'s own diagnostics; their columns follow the coordinates'."""
    import arviz as az
    import emcee

    from bayesmotion.inference.posterior import burn_thin
    from bayesmotion.inference.target import chain_gram

    head = chain[:n]
    if target is not None:
        head = np.concatenate([head, chain_gram(target, head)[1]], -1)
    with warnings.catch_warnings():  # short heads are expected; steps_over_max_tau says so
        warnings.simplefilter("ignore")
        tau = emcee.autocorr.integrated_time(head, quiet=True)
        info = burn_thin(tau, n, None, 1, min_burn=min(adapt, n - 1))
    kept = np.swapaxes(head[info["burn"]:], 0, 1)  # (walkers, draws, ndim)
    d = az.convert_to_dataset({"theta": kept})
    rhat = np.asarray(az.rhat(d)["theta"])
    bulk = np.asarray(az.ess(d, method="bulk")["theta"])
    tail = np.asarray(az.ess(d, method="tail")["theta"])
    return {"steps": n, "burn": info["burn"], "max_tau": float(np.max(tau)),
            "steps_over_max_tau": float(n / np.max(tau)),
            "max_rhat": float(rhat.max()), "worst_rhat_coordinate": int(rhat.argmax()),
            "min_ess_bulk": float(bulk.min()), "min_ess_tail": float(tail.min()),
            "met": bool(rhat.max() <= TARGET_RHAT and bulk.min() >= TARGET_ESS)}


def run(quick: bool) -> dict:
    import emcee
    from _common import headline

    from bayesmotion.inference.proposals import adapt_steps
    from bayesmotion.inference.sample import sample_posterior

    cfg = SETTINGS["quick" if quick else "full"]
    t0 = time.perf_counter()
    cached = model_path(cfg["max_iter"]).exists()
    model = demo_model(cfg["max_iter"], model_path(cfg["max_iter"]))
    fit_s = time.perf_counter() - t0
    path = CACHE / f"posterior_convergence_{_key(model)}.h5"
    resumed_from = (emcee.backends.HDFBackend(str(path), read_only=True).iteration
                    if path.exists() else 0)
    t0 = time.perf_counter()
    adapt = adapt_steps(cfg["steps"])
    post = sample_posterior(model, n_steps=cfg["steps"], seed=0, backend=str(path),
                            progress=False, burn=adapt, thin=1)
    sample_s = time.perf_counter() - t0
    # every step, for the checkpoints' own burn-in
    chain = emcee.backends.HDFBackend(str(path), read_only=True, name="mcmc").get_chain()
    # a file that already held every step samples none: then this call timed no step
    new_steps = max(cfg["steps"] - resumed_from, 0)
    per_step = sample_s / new_steps if new_steps else None
    points = [checkpoint(chain, n, adapt, post.target) for n in cfg["checkpoints"]
              if n <= chain.shape[0]]
    for p in points:
        p["sampling_seconds_from_scratch"] = None if per_step is None else p["steps"] * per_step
    first = next((p for p in points if p["met"]), None)
    last = points[-1]
    from bayesmotion.inference.target import gram_entries

    names = post.target.names + gram_entries(post.target, chain[:1, 0])[0]
    out = {"settings": {**cfg, "model": "demo: load_handshakes(fps=10), 20 training trials, "
                        f"HGPDM().fit(max_iter={cfg['max_iter']}, seed=0)",
                        "sampler": "sample_posterior defaults: " + SAMPLER_VERSION
                                   + ", Laplace start",
                        "n_walkers": post.info["n_walkers"], "ndim": post.target.ndim,
                        "targets": {"max_rhat": TARGET_RHAT, "min_ess_bulk": TARGET_ESS}},
           "fit_seconds": fit_s, "model_from_cache": cached,
           "fit": {k: model.diagnostics[k] for k in
                   ("iterations", "objective", "converged", "message")},
           "sampling_seconds": sample_s, "resumed_from_step": resumed_from,
           "seconds_per_step": per_step, "acceptance": float(np.mean(post.acceptance)),
           "independence_acceptance": post.info.get("independence_acceptance"),
           "adapt_steps": adapt, "refit_steps": post.info.get("refit_steps"),
           "modes_found": len(post.info.get("modes", [])),
           "gamma_acceptance": (float(np.mean(post.info["bottom_acceptance"]))
                                if post.info.get("factorised") else None),
           "checkpoints": points,
           "worst_coordinate_names": sorted({names[p["worst_rhat_coordinate"]]
                                             for p in points})}
    took = ("" if first is None or per_step is None
            else f" ({first['sampling_seconds_from_scratch']:.0f} s)")
    note = (f"first met at {first['steps']} steps{took}" if first
            else f"not met by {last['steps']} steps")
    step_note = ("no step sampled in this call (the file held them all)" if per_step is None
                 else f"{per_step:.2f} s per step")
    out["headline"] = [
        headline(f"demo-size posterior (emcee, {post.target.ndim} dims): max R-hat after "
                 f"{last['steps']} steps", last["max_rhat"], "", f"<= {TARGET_RHAT}",
                 last["max_rhat"] <= TARGET_RHAT,
                 f"chain = {last['steps_over_max_tau']:.0f} x max tau ({last['max_tau']:.0f} "
                 f"steps); {note}"),
        headline("  min bulk ESS, same chain", last["min_ess_bulk"], "", f">= {TARGET_ESS}",
                 last["min_ess_bulk"] >= TARGET_ESS,
                 f"tail {last['min_ess_tail']:.0f}; {step_note} of "
                 f"{post.info['n_walkers']} walkers"),
    ]
    return out
