"""Posterior-predictive generation: rollouts integrated over posterior draws.

For draws d = 1..M of (gamma, beta, alpha, S), the model is conditioned per draw (cached on the
Posterior) and rolled out. The predictive variance is decomposed by the law of total variance:

    Var[y_t] = E_d[Var(y_t | d)]  (within-model: the GP's own predictive variance)
             + Var_d[E(y_t | d)]  (between-model: hyperparameter and style uncertainty)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bayesmotion.model.generate import check_decodes, generate

SPACES = ("I", "X", "Y", "angles", "positions")


def generate_posterior(post, emotion="neutral", couple=None, n_frames=100, n_samples=0,
                       start=None, seed=0, n_draws=16, **styles):
    """Rollouts for ``n_draws`` evenly spaced posterior draws, combined into one Rollout.

    The returned Rollout's means are averages over draws; ``*_var`` hold the total variance
    (within + between); ``variance_parts[space] = {"within", "between"}``; ``samples`` stacks
    ``n_samples`` sampled rollouts per draw (or the per-draw mean rollouts if n_samples = 0).
    """
    check_decodes(post.model)  # before any draw's model is conditioned
    idx = np.linspace(0, post.n_draws - 1, min(n_draws, post.n_draws)).astype(int)
    rolls = [generate(post.model, emotion, couple, n_frames, n_samples, start, seed + k,
                      predictor=post.predictor(int(i)), **styles)
             for k, i in enumerate(idx)]
    parts, fields = {}, {}
    for s in SPACES:
        means = np.stack([getattr(r, s) for r in rolls])
        within = np.mean([getattr(r, f"{s}_var") for r in rolls], 0)
        between = means.var(0)
        parts[s] = {"within": within, "between": between}
        fields[s] = means.mean(0)
        fields[f"{s}_var"] = within + between
    if n_samples:
        samples = {k: np.concatenate([r.samples[k] for r in rolls]) for k in rolls[0].samples}
    else:
        samples = {s: np.stack([getattr(r, s) for r in rolls]) for s in SPACES}
    return replace(rolls[0], samples=samples,
                   sample_var={k: v.var(0) for k, v in samples.items()}, variance_parts=parts,
                   draws=idx, **fields)
