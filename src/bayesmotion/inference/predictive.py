"""Posterior-predictive generation: rollouts integrated over posterior draws.

For draws d = 1..M of (gamma, beta, alpha, S), the model is conditioned per draw (cached on the
Posterior) and rolled out. Given a Dask client (or ``workers``), the draws' rollouts run as tasks
on its workers: the model travels once, as its file's bytes
(:mod:`bayesmotion.model.distributed`), each task carries one draw's parameters, and the result
is the one the same draws give in this process. The predictive variance is decomposed by the law
of total variance:

    Var[y_t] = E_d[Var(y_t | d)]  (within-model: the GP's own predictive variance)
             + Var_d[E(y_t | d)]  (between-model: hyperparameter and style uncertainty)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bayesmotion.model.distributed import dask_client, model_bytes, worker_model
from bayesmotion.model.generate import (
    SAMPLE_MEMORY,
    check_decodes,
    check_sample_memory,
    generate,
)
from bayesmotion.model.predict import condition

SPACES = ("I", "X", "Y", "angles", "positions")


def generate_posterior(post, emotion="neutral", couple=None, n_frames=100, n_samples=0,
                       start=None, seed=0, n_draws=16, client=None, workers=None,
                       sample_memory=SAMPLE_MEMORY, lookahead=0.0, dynamics_style="requested",
                       **styles):
    """Rollouts for ``n_draws`` evenly spaced posterior draws, combined into one Rollout.

    The returned Rollout's means are averages over draws; ``*_var`` hold the total variance
    (within + between); ``variance_parts[space] = {"within", "between"}``; ``samples`` stacks
    ``n_samples`` sampled rollouts per draw (or the per-draw mean rollouts if n_samples = 0).
    Draw k's rollout is seeded ``seed + k`` wherever it runs: with ``client`` (a
    ``dask.distributed.Client``, kept open) or ``workers`` (a ``LocalCluster`` of that many
    processes, closed at the end) each draw is a task on the cluster, and the answer equals the
    one computed here. ``sample_memory``, ``lookahead``, ``dynamics_style`` and ``styles`` as
    in :meth:`bayesmotion.FittedHGPDM.generate`.
    """
    check_sample_memory(sample_memory, n_samples)
    check_decodes(post.model)  # before any draw's model is conditioned
    idx = np.linspace(0, post.n_draws - 1, min(n_draws, post.n_draws)).astype(int)
    if client is None and workers is None:
        rolls = [generate(post.model, emotion, couple, n_frames, n_samples, start, seed + k,
                          predictor=post.predictor(int(i)), sample_memory=sample_memory,
                          lookahead=lookahead, dynamics_style=dynamics_style,
                          **styles)
                 for k, i in enumerate(idx)]
    else:
        # checked here (the same errors as above, before any task is sent)
        generate(post.model, emotion, couple, post.model.spec.order + 1, 0, start, seed,
                 predictor=post.predictor(int(idx[0])), dynamics_style=dynamics_style, **styles)
        rolls = _generate_on_cluster(post, idx, client, 2 if workers is None else workers,
                                     (emotion, couple, n_frames, n_samples, start), seed,
                                     {**styles, "sample_memory": sample_memory,
                                      "lookahead": lookahead,
                                      "dynamics_style": dynamics_style})
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


def _draw_rollout(data: bytes, params: dict, jitter: float, args: tuple, seed: int,
                  styles: dict):
    """One draw's rollout on a worker: the model (loaded once per process) conditioned on the
    draw's parameters."""
    model = worker_model(data)
    emotion, couple, n_frames, n_samples, start = args
    return generate(model, emotion, couple, n_frames, n_samples, start, seed,
                    predictor=condition(model, params, jitter), **styles)


def _generate_on_cluster(post, idx, client, workers, args, seed, styles) -> list:
    import uuid

    data = model_bytes(post.model)
    with dask_client(client, None, workers, "Posterior.generate on a cluster") as client:
        shared = client.scatter(data, broadcast=True, hash=False)
        run = uuid.uuid4().hex[:8]
        futures = [client.submit(_draw_rollout, shared,
                                 {k: np.asarray(v) for k, v in post.params(int(i)).items()},
                                 post.target.jitter, args, seed + k, styles, pure=False,
                                 key=f"bayesmotion-draw-{run}-{k}")
                   for k, i in enumerate(idx)]
        return client.gather(futures)
