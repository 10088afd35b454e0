"""How well the default sampler's independence proposal fits the demo-size posterior: its
acceptance when fitted to the adaptation's states (steps 50-150, the proposal of the first
sampling phase) or refitted to every state since the adaptation (steps 150-250, 150-500 and
150-1000, the refits at ``bayesmotion.inference.proposals.REFIT_STEPS``), each a multivariate t
(df 20) in the canonical coordinates, with and without the per-coordinate sinh-arcsinh map
(``bayesmotion.inference.moves.SinhArcsinh``) the t is taken after.

The model and chain are ``posterior_convergence``'s (its cached demo fit and the default
sampler's chain file, extended to ``steps`` if shorter). Each proposal is built with the
package's own ``canonical_mixture`` and move; at ``n_states`` steps spread over the chain's
second half (posterior draws), every walker draws one proposal and the Metropolis-Hastings
acceptance probability ``min(1, p(x') q(x) / (p(x) q(x')))`` is averaged. ``stuck`` is the
fraction of (step, walker) states whose acceptance probability is under 0.02: walkers there
wait for DE to move them.

Current result (``results/independence_refit.json``): see ``["headline"]`` and
``docs/results.md``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

SETTINGS = {"full": {"steps": 2000, "n_states": 40, "windows": [(50, 150), (150, 250), (150, 500),
                                                                  (150, 1000)]},
            "quick": {"steps": 400, "n_states": 6, "windows": [(50, 150), (150, 200)]}}


def _acceptance(target, move, chain, at, seed) -> np.ndarray:
    """(len(at), walkers) MH acceptance probabilities of one proposal per walker at chain[at]."""
    from bayesmotion.inference.target import in_halves

    rng = np.random.RandomState(seed)
    W = chain.shape[1]
    out = []
    for s in at:
        x = chain[s]
        lp = in_halves(target.logp_batch, x, W)
        new, log_ratio = move.get_proposal(x, rng)
        lp_new = in_halves(target.logp_batch, new, W)
        with np.errstate(over="ignore", invalid="ignore"):
            a = np.minimum(1.0, np.exp(np.minimum(0.0, lp_new - lp + log_ratio)))
        out.append(np.where(np.isfinite(a), a, 0.0))
    return np.array(out)


def run(quick: bool) -> dict:
    import emcee
    import posterior_convergence as pc
    from _common import headline

    from bayesmotion.inference import proposals as P
    from bayesmotion.inference.sample import sample_posterior
    from bayesmotion.inference.target import Target

    cfg = pc.SETTINGS["full"]
    settings = SETTINGS["quick" if quick else "full"]
    model = pc.demo_model(cfg["max_iter"], pc.model_path(cfg["max_iter"]))
    path = pc.CACHE / f"posterior_convergence_{pc._key(model)}.h5"
    have = (emcee.backends.HDFBackend(str(path), read_only=True).iteration
            if path.exists() else 0)
    if have < settings["steps"]:
        sample_posterior(model, n_steps=max(settings["steps"], have), seed=0,
                         backend=str(path), progress=False, burn=P.adapt_steps(cfg["steps"]),
                         thin=1)
    chain = emcee.backends.HDFBackend(str(path), read_only=True, name="mcmc").get_chain()
    target = Target(model)
    centre, _ = target.conditional_map(progress=False)
    cov = target.laplace(centre)
    block = P.independence_block(target, cov)
    modes = P.idle_factor_modes(target, centre, cov, block)
    can = P.canonical_styles(target)
    n = chain.shape[0]
    at = np.linspace(n // 2, n - 1, settings["n_states"]).astype(int)
    rows = []
    for lo, hi in settings["windows"]:
        z = chain[lo:hi].reshape(-1, target.ndim)
        for mapped in (False, True):
            P.MARGINAL_MAP = mapped
            try:
                t0 = time.perf_counter()
                proposal = P.canonical_mixture(can, block, modes, z)
                fit_s = time.perf_counter() - t0
            finally:
                P.MARGINAL_MAP = True
            move = P.default_moves(target, False, proposal, canonical_proposal=can).moves[-1]
            acc = _acceptance(target, move, chain, at, seed=1)
            rows.append({"window": [lo, hi], "sinh_arcsinh": mapped,
                         "acceptance": float(acc.mean()), "stuck": float((acc < 0.02).mean()),
                         "fit_seconds": fit_s})
            print(f"  steps {lo}-{hi}, map {mapped}: acceptance {acc.mean():.3f}, "
                  f"stuck {(acc < 0.02).mean():.3f}", flush=True)
    first = next(r for r in rows if r["window"] == [50, 150] and not r["sinh_arcsinh"])
    best = max(rows, key=lambda r: r["acceptance"])
    out = {"settings": {**settings, "model": "posterior_convergence's demo fit",
                        "chain": f"posterior_convergence's default-sampler chain, {n} steps",
                        "states": at.tolist(), "n_walkers": int(chain.shape[1]),
                        "block_size": int(P.canonical_block(can, block).size)},
           "modes": len(modes), "rows": rows}
    out["headline"] = [headline(
        f"independence proposal's acceptance, refitted to steps {best['window'][0]}-"
        f"{best['window'][1]}" + (" after the sinh-arcsinh map" if best["sinh_arcsinh"] else ""),
        best["acceptance"], "", f"> {first['acceptance']:.3f} (adaptation's states, no map)",
        best["acceptance"] > first["acceptance"],
        f"stuck states {best['stuck']:.2f} against {first['stuck']:.2f}")]
    return out
