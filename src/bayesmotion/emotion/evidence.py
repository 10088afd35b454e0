"""How much evidence one recording carries: the label posterior of a clip when recordings of
one emotion differ from each other.

The model's evidence for level k, log p(Y* | e_k) (the Laplace evidence of
:func:`bayesmotion.emotion.projection.project_levels`), treats the clip's T frames as
independent observations given its latents. They are not independent in what decides the
label: a recording is one performance, and what sets it apart from other recordings of its
emotion (the actor's tempo, posture, how strongly the emotion is played) is shared by all of
its frames. The evidence then grows with T while the information about the emotion does not:
on the held-out Bandai walks the plain evidence puts the chosen level 14 to 865 nats ahead of
the next, wrong labels included (``benchmarks/results/bandai_inference.json``, key
``result.trials[*].level_log_evidence``): P = 1.00 for every clip.

The label posterior here gives each recording a random effect. In the Gaussian case -- a
recording of level k has its own mean m = mu_k + delta, delta ~ N(0, tau^2), and its T frames
scatter around m with variance sigma^2 -- the fixed-style model's evidence is
-T |ybar - mu_k|^2 / (2 sigma^2) + const, while the hierarchical model's is
-|ybar - mu_k|^2 / (2 (tau^2 + sigma^2 / T)) + const: the same evidence raised to the power

    eta = n_eff / (n_eff + T),    n_eff = sigma^2 / tau^2,

the number of frames whose within-recording noise equals the between-recording spread. So

    p(k | Y*) proportional to p(k) exp(eta log p(Y* | e_k)).

A short clip is weighed almost fully (eta -> 1 for T << n_eff); a long one carries at most
the evidence of n_eff frames, however long it is. ``n_eff`` = infinity is the fixed-style model
(eta = 1, the plain evidence); ``n_eff`` -> 0 returns the prior. With a flat prior (the
default) the order of the levels, and so the label, does not depend on ``n_eff``; how sure the
answer is does.

``n_eff`` is a property of the training population, not of a clip: it is chosen by the log
score of labelled recordings held out of the fit (:func:`calibrate_effective_frames`;
``leave_one_out(..., calibrate=True)`` cross-fits it), a proper scoring rule, so the
probabilities are calibrated against recordings the model has not seen. Beyond the Gaussian
case this is generalised Bayes with a learned learning rate (Grunwald & van Ommen 2017; Syring
& Martin 2019 calibrate it the same way), its 1 / T decay for long clips taken from the
random-effect model.
"""

from __future__ import annotations

import numpy as np

from bayesmotion.errors import BayesmotionError

#: n_eff values :func:`calibrate_effective_frames` searches: 10^-3 to 10^7 frames, 201
#: log-spaced values (at the largest, eta > 0.99 for any clip up to 10^5 frames)
N_EFF_GRID = np.logspace(-3, 7, 201)


def evidence_power(n_frames: int, n_eff: float) -> float:
    """eta = n_eff / (n_eff + T): the power on the levels' evidence of a clip of T frames
    (1 for n_eff = infinity)."""
    if not (n_eff > 0):
        raise BayesmotionError(f"n_eff (effective frames per recording) must be > 0, got "
                               f"{n_eff!r}")
    if np.isinf(n_eff):
        return 1.0
    return float(n_eff / (n_eff + max(int(n_frames), 1)))


def level_posterior(log_evidence, log_prior, power: float = 1.0) -> np.ndarray:
    """(K,) probabilities of the levels: p(k) exp(power * log evidence_k), normalised; a level
    of evidence -inf gets probability 0."""
    L = np.asarray(log_evidence, np.float64)
    lp = power * L + np.asarray(log_prior, np.float64)
    if np.any(np.isnan(lp)) or np.any(L == np.inf) or not np.any(np.isfinite(lp)):
        raise BayesmotionError(f"the levels' log evidence must be finite or -inf, with at "
                               f"least one finite, got {log_evidence}")
    return np.exp(lp - np.logaddexp.reduce(lp))


#: log-likelihood tolerance (nats, summed over the clips) of :func:`calibrate_effective_frames`:
#: the edge of the 68% likelihood-ratio interval of log n_eff (chi-square(1) / 2 at 0.68)
TOLERANCE = 0.5


def calibrate_effective_frames(log_evidence, n_frames, truth, log_prior=None,
                               in_distribution=None, grid=N_EFF_GRID) -> dict:
    """The n_eff that labelled recordings held out of the fit support, by their log score.

    The held-out log likelihood of the true labels, sum_j log p(truth_j | Y*_j, n_eff), is
    computed on ``grid``; the answer is the smallest n_eff (the most cautious) whose total is
    within :data:`TOLERANCE` nats of the best -- the cautious end of the 68% likelihood-ratio
    interval. When every held-out label is right, the log score only creeps towards 0 as
    n_eff grows (perfect separation: no finite maximum); the interval's end is then the point
    beyond which more confidence is no longer supported by the recordings at hand.

    Args:
        log_evidence: (n_clips, K) the plain log evidence of each level for recordings the
            model did not see (``EmotionPosterior.info["level_log_evidence"]`` of
            leave-one-out folds).
        n_frames: (n_clips,) their frames at the model's rate.
        truth: (n_clips,) their true level indices.
        log_prior: (K,) or (n_clips, K) log prior probabilities of the levels (default flat).
        in_distribution: (n_clips,) weights w of the evidence against the prior
            (``info["in_distribution_weight"]``, :mod:`bayesmotion.emotion.ood`; default 1):
            the scored probabilities are w p(k | Y*, n_eff) + (1 - w) p(k), as answered.
        grid: the n_eff values searched (default :data:`N_EFF_GRID`).
    Returns:
        dict: ``n_eff`` (the chosen value; the grid's largest means the plain evidence is
        supported),
        ``log_score`` (mean log probability of the truths) at it, ``log_score_best`` (the
        grid's best) and ``log_score_plain`` (the plain evidence), ``n_clips``, and ``grid``
        / ``log_scores``.
    """
    L = np.asarray(log_evidence, np.float64)
    T = np.asarray(n_frames)
    t = np.asarray(truth)
    if L.ndim != 2 or L.shape[0] < 2 or L.shape[1] < 2:
        raise BayesmotionError(f"log_evidence must be (n clips >= 2, K levels >= 2), got shape "
                               f"{L.shape}")
    if not np.all(np.isfinite(L)):
        raise BayesmotionError("every log evidence must be finite")
    n = L.shape[0]
    if T.shape != (n,) or not np.all(np.isfinite(T)) or np.any(T < 1):
        raise BayesmotionError(f"n_frames must be ({n},) positive frame counts")
    if t.shape != (n,) or t.dtype.kind not in "iu" or np.any((t < 0) | (t >= L.shape[1])):
        raise BayesmotionError(f"truth must be ({n},) level indices in [0, {L.shape[1]})")
    grid = np.asarray(grid, np.float64)
    if grid.ndim != 1 or grid.size < 1 or np.any(~(grid > 0)) or np.any(~np.isfinite(grid)):
        raise BayesmotionError("grid must hold finite positive n_eff values")
    grid = np.sort(grid)  # the first value within the tolerance is then the most cautious
    w = np.ones(n) if in_distribution is None else np.asarray(in_distribution, np.float64)
    if w.shape != (n,) or np.any(~((w >= 0) & (w <= 1))):
        raise BayesmotionError(f"in_distribution must be ({n},) weights in [0, 1]")
    lp = np.broadcast_to(np.zeros(L.shape[1]) if log_prior is None
                         else np.asarray(log_prior, np.float64), L.shape)

    def scores(eta):  # (..., n) powers -> (..., n) log p(truth)
        post = eta[..., None] * L + lp
        post = post - np.logaddexp.reduce(post, axis=-1, keepdims=True)
        p = w[:, None] * np.exp(post) + (1 - w[:, None]) * np.exp(lp)
        return np.log(np.maximum(p[..., np.arange(n), t], 1e-300))

    per = scores(grid[:, None] / (grid[:, None] + T[None, :])).sum(1)  # (G,)
    best = float(per.max())
    pick = int(np.flatnonzero(per >= best - TOLERANCE)[0])
    return {"n_eff": float(grid[pick]), "log_score": float(per[pick] / n),
            "log_score_best": best / n,
            "log_score_plain": float(scores(np.ones(n)).mean()),
            "n_clips": int(n), "grid": grid.tolist(), "log_scores": (per / n).tolist()}


def calibrate_evidence(model, held_out):
    """``model`` with its emotion evidence calibrated on recordings held out of its fit.

    Args:
        model: a FittedHGPDM.
        held_out: a :func:`bayesmotion.evaluation.evaluate.leave_one_out` result on the
            model's training data (each trial inferred by a model fitted without it), whose
            trials' plain level evidence sets n_eff, the frames one recording's evidence is
            worth (:func:`calibrate_effective_frames`).
    Returns:
        a new FittedHGPDM whose ``calibration`` holds n_eff (``infer_emotion`` uses it, and
        model files keep it); ``model`` is unchanged.
    """
    rows = held_out.get("trials") if isinstance(held_out, dict) else None
    need = ("true", "n_frames", "level_log_evidence", "level_prior", "in_distribution_weight")
    if not rows or "levels" not in held_out or any(
            not isinstance(r, dict) or any(r.get(k) is None for k in need) for r in rows):
        raise BayesmotionError(f"calibrate_evidence needs a leave_one_out result whose trials "
                               f"kept their level evidence (emotion_starts='vertices'; each "
                               f"trial with {', '.join(need)})")
    levels = list(held_out["levels"])
    own = list(model.levels.get("emotion", ()))
    if levels != own:
        raise BayesmotionError(f"the result's emotion levels {levels} are not the model's "
                               f"{own}")
    cal = calibrate_effective_frames([r["level_log_evidence"] for r in rows],
                                     [r["n_frames"] for r in rows],
                                     np.array([levels.index(r["true"]) for r in rows]),
                                     np.log([r["level_prior"] for r in rows]),
                                     [r["in_distribution_weight"] for r in rows])
    return model.with_calibration({
        "effective_frames": cal["n_eff"], "log_score": cal["log_score"],
        "log_score_plain": cal["log_score_plain"], "n_recordings": cal["n_clips"],
        "method": "leave-one-recording-out log score"})
