"""Calibration of emotion posteriors: the likelihood power (tempering) that makes credible
regions cover at their nominal rate, estimated from leave-one-out folds; the label
probabilities' reliability, ECE, and what a calibrated posterior would score on the same clips."""

from __future__ import annotations

import numpy as np

from bayesmotion.emotion.result import label_set_size
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.params import log_dirichlet


def calibrate_likelihood_power(result_or_distances, q: float = 0.9, dim: int | None = None,
                               region: str = "hpd") -> float:
    """The likelihood power eta that makes ``q`` credible regions cover the truth in a fraction
    ``q`` of labelled clips (a one-step version of Syring & Martin 2019's calibration of
    generalised posteriors).

    For a well-specified model, d2 = twice the clip's untempered log-likelihood drop from its
    best point to the true label (:meth:`EmotionPosterior.loglik_drop`; ``region="hpd"``, for
    highest-density regions), or the truth's squared Mahalanobis distance under the plain
    posterior (:meth:`EmotionPosterior.mahalanobis2`; ``region="ellipsoid"``), is about
    chi-square with K - 1 degrees of freedom. In the posterior tempered by eta both scale by eta
    (a flat prior; for the ellipsoid, a Gaussian shape), so eta = chi2_q(K - 1) / quantile_q(d2)
    puts a fraction ``q`` of the truths inside.
    eta < 1 widens overconfident posteriors, eta > 1 narrows underconfident ones. These are
    approximations on a bounded simplex: check the coverage that results
    (``leave_one_out(..., calibrate=True)`` does, on held-out folds).

    Args:
        result_or_distances: a :func:`leave_one_out` result (its trials' ``truth_loglik_drop``,
            which does not depend on the run's own likelihood power, or ``truth_mahalanobis2``,
            which for a run tempered by eta0 is relative to eta0) or an array of d2 (Mahalanobis
            distances under the plain posterior).
        q: the credible level to calibrate.
        dim: K - 1 (taken from the result's levels when a result is given).
        region: "hpd" or "ellipsoid": which statistic to read from a result.
    """
    from scipy.stats import chi2

    if region not in ("hpd", "ellipsoid"):
        raise BayesmotionError(f"region must be 'hpd' or 'ellipsoid', got {region!r}")
    eta0 = 1.0
    if isinstance(result_or_distances, dict):
        res = result_or_distances
        if region == "hpd":
            drops = [t.get("truth_loglik_drop") for t in res["trials"]]
            if any(d is None for d in drops):
                raise BayesmotionError("this result has no log-likelihood drops (pooled or "
                                       "couple-inferred posteriors): use region='ellipsoid'")
            d2 = 2 * np.asarray(drops, dtype=np.float64)
        else:
            d2 = [t["truth_mahalanobis2"] for t in res["trials"]]
            eta0 = float(res.get("likelihood_power", 1.0))
        dim = len(res["levels"]) - 1 if dim is None else dim
    else:
        d2 = result_or_distances
    d2 = np.asarray(d2, dtype=np.float64).ravel()
    if dim is None or dim < 1:
        raise BayesmotionError("calibrate_likelihood_power needs dim = K - 1 >= 1")
    if not 0 < q < 1:
        raise BayesmotionError(f"q must lie in (0, 1), got {q}")
    if d2.size < 2 or not np.all(np.isfinite(d2)) or np.any(d2 < 0):
        raise BayesmotionError("calibration needs at least two finite, non-negative distances")
    scale = float(np.quantile(d2, q))
    if scale <= 1e-12:
        raise BayesmotionError(f"the {q:.0%} quantile of d2 is {scale:.2g}: the truths sit at "
                               f"the likelihood's best point, so no power can be calibrated")
    return float(eta0 * chi2.ppf(q, dim) / scale)


def uniform_simplex_points(K: int, n: int = 8192, seed: int = 0) -> np.ndarray:
    """(n, K) points drawn uniformly on the simplex (Dirichlet(1)): a proposal for
    :func:`tempered_hpd_levels` (``log_proposal_points`` 0) when the tempered posteriors are
    wide; :func:`tempering_proposal` adds points for sharp ones."""
    return np.random.default_rng(seed).dirichlet(np.ones(K), size=n)


# total concentrations of the Dirichlet ladder around a clip's posterior mean: from nearly flat
# to sharper than the plain posteriors of the built-in handshakes (interval widths ~5e-4)
_LADDER = (10.0, 30.0, 100.0, 300.0, 1e3, 3e3, 1e4, 3e4, 1e5, 3e5)


def tempering_proposal(center, n_uniform: int = 8192, n_per_rung: int = 2048,
                       ladder=_LADDER, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the simplex and their proposal log-density, for :func:`tempered_hpd_levels`.

    A deterministic mixture (each point's density is the mixture's, Veach's balance heuristic):
    ``n_uniform`` uniform points, plus ``n_per_rung`` from Dirichlet(1 + c * center) for each
    total concentration c of ``ladder``. Uniform points alone cannot resolve a posterior tempered
    by a power at which it is still much narrower than the simplex (the importance weights' ESS
    collapses, and :func:`tempered_hpd_levels` answers NaN); the ladder puts points at every
    scale between the prior and the plain posterior around its mean.

    Returns:
        (M, K) points and (M,) log proposal density at them.
    """
    c = np.clip(np.asarray(center, dtype=np.float64), 1e-12, None)
    c = c / c.sum()
    K = c.size
    rng = np.random.default_rng([seed, 1])  # the ladder's stream, apart from the flat points'
    alphas = [np.ones(K)] + [1.0 + a * c for a in ladder]
    counts = [n_uniform] + [n_per_rung] * len(ladder)
    W = np.concatenate([uniform_simplex_points(K, n_uniform, seed)]
                       + [rng.dirichlet(a, size=n_per_rung) for a in alphas[1:]])
    W = np.clip(W, 1e-300, None)
    W = W / W.sum(1, keepdims=True)
    parts = np.stack([np.asarray(log_dirichlet(W, a)) + np.log(n / len(W))
                      for a, n in zip(alphas, counts, strict=True)])
    return W, np.logaddexp.reduce(parts, axis=0)


ETA_GRID = np.logspace(-8, 2, 401)


def tempered_hpd_levels(loglik_points, loglik_truth, etas, log_prior_points=0.0,
                        log_prior_truth=0.0, min_ess: float = 100.0,
                        log_proposal_points=0.0) -> np.ndarray:
    """The smallest highest-density level that holds the truth, for each clip and power.

    For clip j with log-likelihood l_j over the emotion simplex and prior p, the posterior
    tempered by eta has density p(s) exp(eta l_j(s)) / Z; the truth t lies in its ``q``
    highest-density region iff h_j(eta) = P(p(S) e^{eta l_j(S)} >= p(t) e^{eta l_j(t)}) <= q.
    h is integrated by self-normalised importance sampling from points on the simplex, exact as
    the points grow: uniform points (:func:`uniform_simplex_points`, ``log_proposal_points`` 0)
    or any proposal whose log-density is given (:func:`tempering_proposal`). Where the estimate
    is unreliable -- the importance weights' effective sample size below ``min_ess`` -- the
    level is NaN (unknown, never counted as covering): a posterior sharper than the points'
    spacing puts its weight on one or two points, and the estimate then says 0 (truth covered)
    whenever the truth beats them. On the built-in handshakes that made a power of 100 look
    calibrated while its regions covered no truth.

    Args:
        loglik_points: (n_clips, M) l_j at the M points. loglik_truth: (n_clips,) l_j(t_j).
        etas: (E,) powers. log_prior_points: (M,) or (n_clips, M) log p at the points (0: flat).
        log_prior_truth: (n_clips,) log p(t_j).
        log_proposal_points: (M,) or (n_clips, M) log-density of the proposal that drew the
            points (0: uniform, up to a constant).
    Returns:
        (E, n_clips) h_j(eta), NaN where the importance sampling is unreliable.
    """
    L = np.asarray(loglik_points, dtype=np.float64)
    lt = np.asarray(loglik_truth, dtype=np.float64)
    lp = np.broadcast_to(np.asarray(log_prior_points, dtype=np.float64), L.shape)
    lq = np.broadcast_to(np.asarray(log_proposal_points, dtype=np.float64), L.shape)
    lpt = np.broadcast_to(np.asarray(log_prior_truth, dtype=np.float64), lt.shape)
    out = np.empty((len(etas), L.shape[0]))
    for e, eta in enumerate(np.asarray(etas, dtype=np.float64)):
        logd = eta * L + lp  # tempered log density at the points
        logw = logd - lq
        w = np.exp(logw - logw.max(1, keepdims=True))
        h = np.sum(w * (logd >= (eta * lt + lpt)[:, None]), 1) / w.sum(1)
        ess = w.sum(1) ** 2 / np.sum(w**2, 1)
        out[e] = np.where(ess >= min_ess, h, np.nan)
    return out


def calibrate_hpd_power(loglik_points, loglik_truth, q: float = 0.9, log_prior_points=0.0,
                        log_prior_truth=0.0, etas=None, log_proposal_points=0.0) -> float:
    """The largest likelihood power whose tempered ``q`` highest-density regions hold the truth
    for at least a fraction ``q`` of the clips, their levels computed by
    :func:`tempered_hpd_levels` (no chi-square approximation: the simplex's faces, where the
    regions of nearly flat posteriors are cut off, are accounted for). The largest such power
    is the most informative posterior with that coverage. ``log_proposal_points``: as in
    :func:`tempered_hpd_levels` (0 for uniform points).

    Raises:
        BayesmotionError: no power on the grid (default 1e-8..100, log-spaced) reaches the
            coverage -- even the prior's regions leave too many truths out.
    """
    if not 0 < q < 1:
        raise BayesmotionError(f"q must lie in (0, 1), got {q}")
    L = np.atleast_2d(np.asarray(loglik_points, dtype=np.float64))
    if L.shape[0] < 2 or not np.all(np.isfinite(L)) or not np.all(np.isfinite(loglik_truth)):
        raise BayesmotionError("calibration needs at least two clips with finite "
                               "log-likelihoods")
    etas = ETA_GRID if etas is None else np.sort(np.asarray(etas, dtype=np.float64))
    return hpd_power_from_levels(tempered_hpd_levels(L, loglik_truth, etas, log_prior_points,
                                                     log_prior_truth,
                                                     log_proposal_points=log_proposal_points),
                                 q, etas)


def hpd_power_from_levels(levels, q: float = 0.9, etas=None) -> float:
    """:func:`calibrate_hpd_power` from precomputed levels (E, n_clips) on the grid ``etas``
    (cross-fitting drops columns instead of recomputing them)."""
    etas = ETA_GRID if etas is None else np.asarray(etas, dtype=np.float64)
    cover = np.mean(np.asarray(levels) <= q, axis=1)  # NaN (unreliable) never covers
    ok = etas[cover >= q]
    if ok.size == 0:
        raise BayesmotionError(f"no likelihood power in [{etas[0]:.2g}, {etas[-1]:.2g}] makes "
                               f"{q:.0%} regions hold {q:.0%} of the truths (best "
                               f"{cover.max():.0%})")
    return float(ok.max())


def reliability(probabilities, truth, n_bins: int = 10, labels=None) -> list[dict]:
    """Reliability diagram of top-label probabilities (Guo et al. 2017): the answers binned by
    their confidence (the probability of the answer) into ``n_bins`` equal-width bins on
    [0, 1].

    Args:
        probabilities: (n, K) label probabilities of n clips. truth: (n,) true level indices.
        n_bins: the number of equal-width bins.
        labels: (n,) the level indices that were answered, each a most probable level (default
            the first most probable; :attr:`EmotionPosterior.label` breaks ties by the
            evidence, so an answer shrunk to a flat prior is scored as the label it reports).
    Returns:
        per non-empty bin ``{"lower", "upper", "count", "confidence"`` (mean),
        ``"accuracy"}``: a calibrated posterior has accuracy = confidence in every bin.
    """
    p, t = _label_args(probabilities, truth)
    if int(n_bins) != n_bins or n_bins < 1:
        raise BayesmotionError(f"n_bins must be a positive integer, got {n_bins!r}")
    a = _answers(p, labels)
    conf = p[np.arange(p.shape[0]), a]
    right = a == t
    edges = np.linspace(0.0, 1.0, int(n_bins) + 1)
    idx = _bin_index(conf, n_bins)
    return [{"lower": float(edges[b]), "upper": float(edges[b + 1]),
             "count": int(np.sum(idx == b)), "confidence": float(conf[idx == b].mean()),
             "accuracy": float(right[idx == b].mean())}
            for b in range(int(n_bins)) if np.any(idx == b)]


def _bin_index(conf, n_bins: int) -> np.ndarray:
    """The equal-width bin of each confidence on [0, 1]; the top bin is closed, so a
    confidence of exactly 1 falls in it."""
    edges = np.linspace(0.0, 1.0, int(n_bins) + 1)
    return np.minimum(np.searchsorted(edges, conf, side="right") - 1, int(n_bins) - 1)


def expected_calibration_error(probabilities, truth, n_bins: int = 10, labels=None) -> float:
    """Top-label expected calibration error: sum over :func:`reliability` bins of
    (count / n) |accuracy - confidence|. 0 for a calibrated posterior; a posterior answering
    P = 1 at accuracy 0.8 scores 0.2. ``labels``: the answers given (:func:`reliability`)."""
    return _ece_of(reliability(probabilities, truth, n_bins, labels))


def _ece_of(bins) -> float:
    """The ECE of :func:`reliability`'s bins."""
    n = sum(b["count"] for b in bins)
    return float(sum(b["count"] / n * abs(b["accuracy"] - b["confidence"]) for b in bins))


def calibration_consistency(probabilities, truth, n_bins: int = 10, n_draws: int = 2000,
                            level: float = 0.9, seed: int = 0, labels=None) -> dict:
    """What a calibrated posterior would show on these clips: consistency resampling (Broecker
    and Smith 2007), conditional on the answers given.

    A posterior is calibrated when its top label is right with the probability it states. With
    the answers held (the conditional form; Broecker and Smith also resample the answers, which
    gives wider bars), each of ``n_draws`` replicates draws every clip's outcome as right with
    its top probability, then computes the ECE and each reliability bin's accuracy. On few clips
    a calibrated posterior's ECE is far from 0 (the bins hold a handful of clips each), so the
    observed ECE is read against that distribution, not against 0.

    Args:
        probabilities: (n, K) label probabilities. truth: (n,) true level indices.
        n_bins: the reliability bins (:func:`reliability`).
        n_draws: replicates.
        level: the central probability of the intervals.
        seed: seeds the replicates.
        labels: the answers given (:func:`reliability`).

    Returns:
        ``ece`` (observed); ``ece_if_calibrated``: the replicates' ``mean`` and central
        ``interval`` (the mean: the ECE of a few clips takes few values, so its median is a
        coarse summary); ``p_value``: (1 + the replicates whose ECE is at least the observed)
        / (1 + ``n_draws``), ties counted against calibration, so the test is conservative
        (small: the answers are miscalibrated beyond what n clips explain); ``bins``: per
        non-empty bin ``lower``, ``upper``, ``count``, ``confidence``, ``accuracy`` and the
        replicates' central ``accuracy_interval`` (the bin's consistency bar); ``n_draws``,
        ``level``.
    """
    p, t = _label_args(probabilities, truth)
    if int(n_draws) != n_draws or n_draws < 1:
        raise BayesmotionError(f"n_draws must be a positive integer, got {n_draws!r}")
    if not 0 < level < 1:
        raise BayesmotionError(f"level must lie in (0, 1), got {level}")
    bins = reliability(p, t, n_bins, labels)
    conf = p[np.arange(p.shape[0]), _answers(p, labels)]
    idx = _bin_index(conf, n_bins)
    rng = np.random.default_rng(seed)
    # each replicate's right answers per bin, drawn in chunks of about a million clips
    kept = np.unique(idx)  # the non-empty bins, in the order reliability() lists them
    chunk = max(1, 1_000_000 // conf.size)
    hits = np.concatenate([_bin_hits(rng.random((min(chunk, int(n_draws) - s), conf.size)) < conf,
                                     idx, kept) for s in range(0, int(n_draws), chunk)])
    lo, hi = (1 - level) / 2, (1 + level) / 2
    ece = np.zeros(int(n_draws))
    out_bins = []
    for j, b in enumerate(bins):
        acc = hits[:, j] / b["count"]
        ece += b["count"] / conf.size * np.abs(acc - b["confidence"])
        out_bins.append({**b, "accuracy_interval": [float(np.quantile(acc, lo)),
                                                     float(np.quantile(acc, hi))]})
    observed = _ece_of(bins)
    return {"ece": observed,
            "ece_if_calibrated": {"mean": float(np.mean(ece)),
                                  "interval": [float(np.quantile(ece, lo)),
                                               float(np.quantile(ece, hi))]},
            "p_value": float((1 + np.sum(ece >= observed - 1e-12)) / (1 + ece.size)),
            "bins": out_bins,
            "n_draws": int(n_draws), "level": float(level)}


def _bin_hits(right, idx, kept) -> np.ndarray:
    """(draws, clips) right answers -> (draws, bins) their count in each bin of ``kept``."""
    return np.stack([right[:, idx == k].sum(1) for k in kept], 1)


def label_calibration(probabilities, truth, q: float = 0.9, n_bins: int = 10,
                      confident: float = 0.99, n_draws: int = 2000, labels=None) -> dict:
    """What users read off label probabilities, for n labelled clips.

    ``labels``: the level indices that were answered (default the first most probable level;
    see :func:`reliability`). Accuracy, ECE, the reliability bins and the confident wrong
    answers score these answers.

    Returns a dict: ``accuracy``; ``ece`` and ``reliability`` (:func:`reliability`);
    ``label_set_coverage`` (the truth inside the smallest set of levels holding probability
    ``q``) and the sets' mean size; ``confident_wrong`` (the fraction of clips answered wrongly
    with probability >= ``confident``); ``log_score`` (mean log probability of the truth) and
    ``brier`` (mean squared error of the probability vector against the one-hot truth);
    ``ece_if_calibrated`` and ``ece_p_value``: the ECE a calibrated posterior would show with
    these answers on these clips (mean and 90% interval), and how often it reaches the observed
    one (:func:`calibration_consistency` with ``n_draws`` replicates, seed 0; its cost grows as
    ``n_draws`` x n; ``n_draws=0`` leaves both out, None)."""
    p, t = _label_args(probabilities, truth)
    if not 0 < q < 1:
        raise BayesmotionError(f"q must lie in (0, 1), got {q}")
    n, K = p.shape
    order = np.argsort(-p, 1, kind="stable")
    size = np.array([label_set_size(row, q) for row in p])
    inside = np.array([t[i] in order[i, :size[i]] for i in range(n)])
    a = _answers(p, labels)
    right = a == t
    onehot = np.eye(K)[t]
    consistency = (calibration_consistency(p, t, n_bins, n_draws, labels=a) if n_draws
                   else {"ece_if_calibrated": None, "p_value": None})
    return {"n": n, "accuracy": float(right.mean()),
            "ece": expected_calibration_error(p, t, n_bins, a),
            "reliability": reliability(p, t, n_bins, a),
            "credible_level": q,
            "label_set_coverage": float(inside.mean()),
            "label_set_mean_size": float(size.mean()),
            "confident_wrong": float(np.mean(~right & (p[np.arange(n), a] >= confident))),
            "confident_threshold": confident,
            "log_score": float(np.mean(np.log(np.maximum(p[np.arange(n), t], 1e-300)))),
            "brier": float(np.mean(np.sum((p - onehot) ** 2, 1))),
            "ece_if_calibrated": consistency["ece_if_calibrated"],
            "ece_p_value": consistency["p_value"]}


def _answers(p: np.ndarray, labels) -> np.ndarray:
    """The answered level of each clip: ``labels``, each checked to be a most probable level
    of its row, or by default the first most probable level."""
    if labels is None:
        return np.argmax(p, 1)
    a = np.asarray(labels)
    if a.shape != (p.shape[0],) or a.dtype.kind not in "iu" \
            or np.any((a < 0) | (a >= p.shape[1])):
        raise BayesmotionError(f"labels must be ({p.shape[0]},) level indices in "
                               f"[0, {p.shape[1]}), got {labels!r}")
    a = a.astype(int)
    top = p.max(1)
    off = np.flatnonzero(p[np.arange(p.shape[0]), a] < top - 1e-9 * np.maximum(top, 1e-300))
    if off.size:
        raise BayesmotionError(f"labels must each be a most probable level of their row; "
                               f"rows {off[:5].tolist()} answer a less probable level")
    return a


def _label_args(probabilities, truth) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(probabilities, dtype=np.float64)
    t = np.asarray(truth)
    if p.ndim != 2 or p.shape[0] < 1 or p.shape[1] < 2:
        raise BayesmotionError(f"probabilities must be (n clips, K >= 2 levels), got shape "
                               f"{p.shape}")
    if not np.all(np.isfinite(p)) or np.any(p < 0) or np.any(np.abs(p.sum(1) - 1) > 1e-6):
        raise BayesmotionError("every row of probabilities must be finite, non-negative and "
                               "sum to 1")
    if t.shape != (p.shape[0],) or t.dtype.kind not in "iu" or np.any((t < 0) | (t >= p.shape[1])):
        raise BayesmotionError(f"truth must be ({p.shape[0]},) level indices in "
                               f"[0, {p.shape[1]}), got {t!r}")
    return p, t.astype(int)
