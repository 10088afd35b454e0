"""Mixing per step of the default emcee sampler against the samplers before it: the style shear
(``bayesmotion.inference.moves.shear``) and the canonical style coordinates
(``bayesmotion.inference.moves.canonical``), same model, same seeds, same run.

The model is the full demo's (``load_handshakes(seed=0, fps=10)`` without its 4 held-out trials,
20 trials, ``HGPDM().fit(max_iter=1000, seed=0)``, read from ``posterior_convergence``'s cache
when it is there): the demo-size posterior, 26 coordinates, 54 walkers. Each sampler runs
``sample_posterior``'s defaults for ``steps`` steps per seed:

* ``default``: differential evolution and the independence step propose in coordinates where
  the output scales' logs carry the log mean style diagonal; DE moves the rotated style vectors
  through their Gram matrix's LQ factor ``T``, each walker keeping the rotation left over after
  the one that aligns ``T`` with the simplex's vertices (``CanonicalDE``); after the adaptation
  the independence step draws ``T`` with the hyperparameters (``CanonicalIndependence``);
* ``canonical_de``: the same with the rotation ``Q`` kept unaligned and the independence step
  on the hyperparameters alone, in the shear's coordinates;
* ``previous``: the same moves in the sampled coordinates (``StyleShear.for_target`` patched to
  find no shear, no canonical coordinates), i.e. the sampler before either.

The diagnostics are read from the raw chain with the same burn-in for all (the independence
step's adaptation, 150 steps): per-coordinate integrated autocorrelation time (emcee), max
R-hat and min bulk ESS over the 26 sampled coordinates (arviz, each walker a chain), and the same
over what the likelihood identifies (key ``identified``): the hyperparameters and the style
vectors' Gram entries, which the style rotations leave unchanged. Mixing is measured as the
slowest one's bulk ESS per step, against a target of 4 times the ``previous`` sampler's.

Current result (``results/style_shear.json``): see ``["headline"]`` and ``docs/results.md``.
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

SETTINGS = {"full": {"steps": 800, "seeds": (0, 1)}, "quick": {"steps": 200, "seeds": (0,)}}
BURN = 150


def _stats(kept: np.ndarray, names: list[str]) -> dict:
    import arviz as az
    import emcee

    from bayesmotion.inference.diagnostics import arviz_without_numba

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = emcee.autocorr.integrated_time(kept, quiet=True)
    x = np.swapaxes(kept, 0, 1)  # (walkers, steps, dim): each walker a chain
    with arviz_without_numba():
        ess = np.array([float(az.ess(x[..., i], method="bulk")) for i in range(x.shape[-1])])
        rhat = np.array([float(az.rhat(x[..., i])) for i in range(x.shape[-1])])
    slow = int(np.argmin(ess))
    return {"kept_steps": int(kept.shape[0]), "max_tau": float(tau.max()),
            "mean_tau": float(tau.mean()), "slowest_tau_coordinate": names[int(tau.argmax())],
            "min_ess_bulk": float(ess.min()), "min_ess_coordinate": names[slow],
            "min_ess_bulk_per_step": float(ess.min() / kept.shape[0]),
            "max_rhat": float(rhat.max()), "tau": tau.tolist()}


def chain_stats(chain: np.ndarray, names: list[str], target=None) -> dict:
    """Diagnostics of a raw (steps, walkers, dim) chain after ``BURN`` steps, over the sampled
    coordinates; with ``target``, also (key ``identified``) over what the likelihood identifies:
    the coordinates that are not style vectors and the style vectors' Gram entries
    (``bayesmotion.inference.target.gram_entries``), which the style rotations do not move."""
    kept = chain[BURN:]
    out = _stats(kept, names)
    if target is not None:
        from bayesmotion.inference.target import chain_gram

        gram_names, gram = chain_gram(target, kept)
        plain = [i for i, n in enumerate(names) if not n.startswith("style:")]
        out["identified"] = _stats(np.concatenate([kept[..., plain], gram], -1),
                                   [names[i] for i in plain] + gram_names)
    return out


VARIANTS = ("previous", "canonical_de", "default")


def sample(model, steps: int, seed: int, variant: str, path: str | None = None) -> dict:
    """``sample_posterior``'s defaults under ``variant`` (one of :data:`VARIANTS`) for
    ``steps`` steps; with ``path``, the chain is kept in that emcee file and a run stopped
    early resumes from it (the seconds per step then count this call's steps only)."""
    import emcee

    from bayesmotion.inference import emcee_runner, proposals
    from bayesmotion.inference.moves import shear as shear_mod
    from bayesmotion.inference.sample import sample_posterior

    found, canonical = shear_mod.StyleShear.for_target, proposals.CanonicalStyles
    independence = emcee_runner.CANONICAL_INDEPENDENCE
    if variant == "previous":
        shear_mod.StyleShear.for_target = classmethod(lambda cls, target: None)
        proposals.CanonicalStyles = lambda slices, shear: canonical({}, shear)
        emcee_runner.CANONICAL_INDEPENDENCE = False
    if variant == "canonical_de":
        proposals.CanonicalStyles = lambda slices, shear: canonical(slices, shear, align=False)
        emcee_runner.CANONICAL_INDEPENDENCE = False
    try:
        with tempfile.TemporaryDirectory() as tmp:
            file = path or str(Path(tmp) / "chain.h5")
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                post = sample_posterior(model, n_steps=steps, seed=seed, backend=file,
                                        progress=False)
            seconds = time.perf_counter() - t0
            chain = emcee.backends.HDFBackend(file, read_only=True, name="mcmc").get_chain()
    finally:
        shear_mod.StyleShear.for_target = found
        proposals.CanonicalStyles = canonical
        emcee_runner.CANONICAL_INDEPENDENCE = independence
    return {"seed": seed, "steps": steps, "seconds": seconds,
            # the steps' own time, without the Laplace start and the proposals' set-up
            "sampling_seconds": post.info.get("seconds"),
            # None when the file already held every step (no step was timed)
            "seconds_per_step": (post.info.get("pace") or {}).get("seconds_per_step"),
            "independence_acceptance": post.info.get("independence_acceptance"),
            **chain_stats(chain, post.target.names, post.target)}


def run(quick: bool) -> dict:
    from _common import headline
    from posterior_convergence import demo_model, model_path

    cfg = SETTINGS["quick" if quick else "full"]
    t0 = time.perf_counter()
    model = demo_model(1000, None if quick else model_path(1000))
    fit_s = time.perf_counter() - t0
    rows = {name: [] for name in VARIANTS}
    for seed in cfg["seeds"]:  # alternate, so load drifts hit all alike
        for name in VARIANTS:
            rows[name].append(sample(model, cfg["steps"], seed, name))

    def mean(name, key, part=None):
        return float(np.mean([(r if part is None else r[part])[key] for r in rows[name]]))

    def ratio(a, b, part=None):
        return (mean(a, "min_ess_bulk_per_step", part)
                / mean(b, "min_ess_bulk_per_step", part))

    out = {"settings": {"model": "full demo: load_handshakes(seed=0, fps=10), 20 training "
                                 "trials, HGPDM().fit(max_iter=1000, seed=0)",
                        "steps": cfg["steps"], "seeds": list(cfg["seeds"]), "burn": BURN,
                        "n_walkers": 54, "ndim": 26},
           "fit_or_load_seconds": fit_s, "samplers": rows,
           "min_ess_per_step_ratio": {f"{a}/{b}": ratio(a, b) for a, b in
                                      (("default", "previous"), ("canonical_de", "previous"),
                                       ("default", "canonical_de"))},
           "identified_min_ess_per_step_ratio": {
               f"{a}/{b}": ratio(a, b, "identified") for a, b in
               (("default", "previous"), ("canonical_de", "previous"),
                ("default", "canonical_de"))}}

    def note(name, part=None):
        return (f"max tau {mean(name, 'max_tau', part):.1f} (mean "
                f"{mean(name, 'mean_tau', part):.1f}), max R-hat "
                f"{mean(name, 'max_rhat', part):.3f}, {mean(name, 'seconds_per_step'):.2f} s "
                f"per step; mean of seeds {list(cfg['seeds'])}, {cfg['steps']} steps, "
                f"burn {BURN}")

    label = {"default": "default sampler (aligned canonical coordinates in DE and the "
                        "independence step, style shear)",
             "canonical_de": "unaligned canonical coordinates in DE only, style shear",
             "previous": "neither (no canonical coordinates, no shear)"}
    out["headline"] = []
    for part, what in ((None, "sampled coordinates"),
                       ("identified", "identified quantities (hyperparameters and style Gram "
                                      "entries)")):
        for i, name in enumerate(VARIANTS[::-1]):
            out["headline"].append(headline(
                (f"demo-size posterior, {what}: min bulk ESS per step, " if i == 0 else "  ")
                + label[name], mean(name, "min_ess_bulk_per_step", part), "1/step", "", None,
                note(name, part)))
        r = ratio("default", "previous", part)
        out["headline"].append(headline("  ratio, default / neither", r, "x", ">= 4", r >= 4,
                                        f"default / canonical DE only "
                                        f"{ratio('default', 'canonical_de', part):.2f}x"))
    return out


if __name__ == "__main__":
    import json

    print(json.dumps(run("--quick" in sys.argv)["headline"], indent=1))
