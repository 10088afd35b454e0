"""Evaluation harness: leave-one-trial-out emotion inference, confusion matrix, calibration,
and baselines on the same folds: a logistic regression on the affective clip features
(Bhattacharya et al. 2021), Ho et al.'s (2017) relative emotion strength as a classifier
(:class:`~bayesmotion.baselines.strength.StrengthClassifier` on keyframe features) and a
nearest neighbour on the mean pose.

Each fold refits the model without the held-out trial, warm-started from the full-data MAP
(latents of the remaining trials, hyperparameters), for ``refit_iter`` L-BFGS iterations -- a
cheaper stand-in for a cold refit that still never lets the held-out trial inform the fold's
model (its frames are removed from the data, its latents from the start point).
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from bayesmotion._config import release_compiled_programs
from bayesmotion.baselines.classifier import (
    GroupCentred,
    LogisticRegression,
    NearestNeighbour,
    mean_pose_features,
    trial_features,
)
from bayesmotion.baselines.strength import StrengthClassifier, keyframe_features
from bayesmotion.data.motion import MotionDataset
from bayesmotion.emotion.clip import clip_poses
from bayesmotion.emotion.evidence import (
    calibrate_effective_frames,
    evidence_power,
    level_posterior,
)
from bayesmotion.emotion.infer import infer_emotion
from bayesmotion.emotion.ood import OutOfDistributionWarning, UnseenStyleWarning
from bayesmotion.emotion.projection import START_JITTER
from bayesmotion.emotion.result import label_set_size, top_level
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.calibration import (
    ETA_GRID,
    calibrate_likelihood_power,
    hpd_power_from_levels,
    label_calibration,
    tempered_hpd_levels,
    tempering_proposal,
)
from bayesmotion.model.params import AR_KEY, STYLE_PREFIX
from bayesmotion.model.spec import HGPDM
from bayesmotion.validate import check_projection_starts


def _fold_init(full, keep: list[int]) -> dict:
    sl = full.trial_slices()
    rows = np.concatenate([np.arange(sl[r].start, sl[r].stop) for r in keep])
    # hyperparameters, and learned style vectors (the levels stay: datasets keep their level
    # lists when trials are left out)
    init = {k: v for k, v in full.params.items()
            if k.startswith(("log_", STYLE_PREFIX)) or k == AR_KEY}
    init["X"] = np.asarray(full.params["X"])[:, rows]
    init["I"] = np.asarray(full.params["I"])[rows]
    return init


def confusion_matrix(true, pred, levels) -> np.ndarray:
    """Percentages laid out as Taubert et al. Table 1: intended emotion in columns, inferred in
    rows; each column sums to 100."""
    C = np.zeros((len(levels), len(levels)))
    for t, p in zip(true, pred, strict=True):
        C[levels.index(p), levels.index(t)] += 1
    return 100 * C / np.maximum(C.sum(0, keepdims=True), 1)


def _calibrated(rows, runs, levels, q, n_steps, seed, infer_kwargs) -> dict:
    """Re-infer every held-out trial at the likelihood power calibrated on the others: from the
    exact highest-density levels of their tempered posteriors when every posterior kept its
    density, else from the Mahalanobis distances (ellipsoids, chi-square)."""
    hpd = all(r["truth_loglik_drop"] is not None for r in rows)
    d2 = np.array([2 * r["truth_loglik_drop"] if hpd else r["truth_mahalanobis2"] for r in rows])
    if hpd:  # the regions' exact levels (importance sampling on the simplex), not chi-square
        L, lt, lpt, lp, lq = (np.array([run[4][k] for run in runs])
                              for k in ("loglik_points", "loglik_truth", "log_prior_truth",
                                        "log_prior_points", "log_proposal_points"))
        H = tempered_hpd_levels(L, lt, ETA_GRID, lp, lpt, log_proposal_points=lq)
        # with a flat prior the levels only grow with eta (tempering moves mass onto the
        # likelihood's superlevel sets): the flattest posterior covers the most
        reachable = float(np.max(np.mean(H <= q, axis=1)))
        if reachable < q:
            return {"error": f"no likelihood power makes {q:.0%} regions hold {q:.0%} of the "
                             f"truths: at best {reachable:.0%} (with a flat prior, the true "
                             f"label's likelihood is below that of {q:.0%} of the simplex in "
                             f"{1 - reachable:.0%} of the trials)",
                    "statistic": "highest-density levels (importance sampling on the simplex)",
                    "reachable_hpd_coverage": reachable}

        def power(keep):
            return hpd_power_from_levels(H[:, keep], q)
    else:
        def power(keep):
            return calibrate_likelihood_power(d2[keep], q, len(levels) - 1)
    everyone = np.arange(len(rows))
    for i, (r, (fold, held, given, truth, _)) in enumerate(zip(rows, runs, strict=True)):
        eta = power(everyone != i)
        ep = infer_flagged(fold, held, styles=given, n_steps=n_steps, seed=seed + i,
                           latent_uncertainty=False, likelihood_power=eta, **infer_kwargs)
        r["calibrated"] = {"likelihood_power": eta, "pred": ep.label, "mean": ep.mean.tolist(),
                           "probabilities": ep.probabilities.tolist(),
                           "covered": ep.region_contains(truth, q),
                           "hpd_covered": ep.hpd_contains(truth, q) if hpd else None,
                           "label_set": list(ep.label_set(q))}
    cal = [r["calibrated"] for r in rows]
    eta = np.array([c["likelihood_power"] for c in cal])
    return {"statistic": ("highest-density levels (importance sampling on the simplex)" if hpd
                          else "mahalanobis2 (ellipsoid, chi-square)"),
            "coverage": float(np.mean([c["covered"] for c in cal])),
            "hpd_coverage": float(np.mean([c["hpd_covered"] for c in cal])) if hpd else None,
            "accuracy": float(np.mean([r["calibrated"]["pred"] == r["true"] for r in rows])),
            "label_set_coverage": float(np.mean([r["true"] in r["calibrated"]["label_set"]
                                                 for r in rows])),
            "likelihood_power": {"median": float(np.median(eta)), "min": float(eta.min()),
                                 "max": float(eta.max())},
            "likelihood_power_all_trials": power(everyone >= 0)}


def _evidence_calibrated(rows, truth_idx, q) -> dict:
    """Label probabilities with n_eff (the effective frames per recording,
    :mod:`bayesmotion.emotion.evidence`) cross-fitted: trial i's from the other trials' plain
    level evidence; each row gets ``evidence_calibrated`` {n_eff, probabilities,
    label_set_size, label_index} (the answer, ties broken by the evidence as
    :attr:`EmotionPosterior.label` does). The other trials' evidence comes from fold models
    that saw trial i, the usual bias of cross-fitting on leave-one-out folds.
    Returns the calibrated label metrics (:func:`label_calibration`) and n_eff fitted on all
    trials (what :func:`bayesmotion.emotion.evidence.calibrate_evidence` stores)."""
    L = np.array([r["level_log_evidence"] for r in rows], dtype=np.float64)
    T = np.array([r["n_frames"] for r in rows])
    lp = np.log(np.array([r["level_prior"] for r in rows], dtype=np.float64))
    w = np.array([r["in_distribution_weight"] for r in rows], dtype=np.float64)
    everyone = np.arange(len(rows))
    probs, labels = [], []
    for i, r in enumerate(rows):
        keep = everyone != i
        n_eff = calibrate_effective_frames(L[keep], T[keep], truth_idx[keep], lp[keep],
                                           w[keep])["n_eff"]
        p, label = recording_effect_answer(r, n_eff)
        probs.append(p)
        labels.append(label)
        r["evidence_calibrated"] = {"n_eff": n_eff, "probabilities": p.tolist(),
                                    "label_set_size": label_set_size(p, q),
                                    "label_index": labels[-1]}
    n_eff = np.array([r["evidence_calibrated"]["n_eff"] for r in rows])
    return {"label_calibration": label_calibration(np.array(probs), truth_idx, q,
                                                   labels=np.array(labels)),
            "n_eff": {"median": float(np.median(n_eff)), "min": float(n_eff.min()),
                      "max": float(n_eff.max())},
            "n_eff_all_trials": calibrate_effective_frames(L, T, truth_idx, lp, w)["n_eff"]}


def recording_effect_answer(row: dict, n_eff: float) -> tuple[np.ndarray, int]:
    """One :func:`leave_one_out` row's label probabilities with the recording effect at
    ``n_eff`` (its plain level evidence raised to the power n_eff / (n_eff + T), shrunk by its
    in-distribution weight) and its answer, ties broken by the evidence as
    :attr:`EmotionPosterior.label` does."""
    lp = np.log(np.asarray(row["level_prior"], dtype=np.float64))
    w = float(row["in_distribution_weight"])
    p_in = level_posterior(np.asarray(row["level_log_evidence"], dtype=np.float64), lp,
                           evidence_power(row["n_frames"], n_eff))
    p = w * p_in + (1 - w) * np.exp(lp)
    return p, top_level(p, p_in)


def score_labels(result: dict, with_evidence: bool | None = None) -> dict:
    """The label summaries of a :func:`leave_one_out` result from its per-trial rows:
    ``label_calibration`` of the plain answers and, with ``with_evidence`` (default: when the
    result has them), ``evidence`` (the recording effect, n_eff cross-fitted). Each clip is
    scored as answered: an answer shrunk to a flat prior counts as the label it reports (the
    level its evidence favours), not as the first tied level. A function of the stored rows, so
    a stored result can be summarised again without refitting. With the evidence it (re)writes
    each row's ``evidence_calibrated`` in place, as :func:`leave_one_out` does.

    Returns:
        ``{"label_calibration": ..., "evidence": ...}`` (the second only with the evidence).
    """
    rows, levels, q = result["trials"], list(result["levels"]), result["credible_level"]
    truth_idx = np.array([levels.index(r["true"]) for r in rows])
    answered = np.array([levels.index(r["pred"]) for r in rows])
    out = {"label_calibration": label_calibration([r["probabilities"] for r in rows],
                                                  truth_idx, q, labels=answered)}
    if with_evidence is None:
        with_evidence = "evidence" in result
    if with_evidence:
        out["evidence"] = _evidence_calibrated(rows, truth_idx, q)
    return out


# the affective-feature classifier on features relative to each trial's content
BY_CONTENT = "affective_features_by_content"


def _content_groups(dataset: MotionDataset, factor: str) -> np.ndarray | None:
    """Every trial's "content" label when the trials carry one and every content has trials
    of at least two levels of ``factor`` (so each fold still sees the held-out trial's
    content); else None."""
    if factor == "content":
        return None
    groups = [t.labels.get("content") for t in dataset]
    if any(not isinstance(g, str) for g in groups) or len(set(groups)) < 2:
        return None
    y = dataset.labels(factor)
    for g in set(groups):
        if len({v for v, h in zip(y, groups, strict=True) if h == g}) < 2:
            return None
    return np.array(groups)


def _baselines(dataset: MotionDataset, factor: str) -> tuple[dict, dict]:
    y = np.array(dataset.labels(factor))
    feats = trial_features(dataset)
    keys = trial_features(dataset, keyframe_features)
    poses = trial_features(dataset, mean_pose_features)
    levels = list(dataset.levels[factor])
    out = {"affective_features": [], "relative_strength": [], "mean_pose_nn": []}
    probs = {"affective_features": np.zeros((len(dataset), len(levels)))}  # in level order
    groups = _content_groups(dataset, factor)
    if groups is not None:
        out[BY_CONTENT] = []
        probs[BY_CONTENT] = np.zeros((len(dataset), len(levels)))
    for i in range(len(dataset)):
        tr = np.arange(len(dataset)) != i
        clf = LogisticRegression().fit(feats[tr], y[tr])
        out["affective_features"].append(clf.predict(feats[i:i + 1])[0])
        # a level missing from the fold's training trials gets probability 0
        probs["affective_features"][i, [levels.index(c) for c in clf.classes]] = \
            clf.predict_proba(feats[i:i + 1])[0]
        if groups is not None:
            rel = GroupCentred().fit(feats[tr], y[tr], groups[tr])
            p = rel.predict_proba(feats[i:i + 1], groups[i:i + 1])[0]
            out[BY_CONTENT].append(rel.classes[int(np.argmax(p))])
            probs[BY_CONTENT][i, [levels.index(c) for c in rel.classes]] = p
        out["relative_strength"].append(
            StrengthClassifier().fit(keys[tr], y[tr]).predict(keys[i:i + 1])[0])
        out["mean_pose_nn"].append(NearestNeighbour().fit(poses[tr], y[tr]).predict(
            poses[i:i + 1])[0])
    return out, probs


def leave_one_out(dataset: MotionDataset, full_model=None, *, spec=None, refit_iter: int = 100,
                  n_steps: int = 400, q: float = 0.9, baselines: bool = True, progress=False,
                  seed: int = 0, fit_kwargs: dict | None = None, calibrate: bool | str = False,
                  infer_kwargs: dict | None = None) -> dict:
    """Leave-one-trial-out emotion inference.

    Args:
        dataset: labelled trials (factor "emotion" required).
        full_model: a FittedHGPDM fitted on all of ``dataset`` (fitted here if None).
        spec: HGPDM specification used when fitting (default HGPDM()).
        refit_iter: warm-started L-BFGS iterations per fold.
        n_steps: emcee steps of each inference.
        q: credible level whose coverage is reported.
        baselines: also run the affective-feature classifier, Ho et al.'s relative-strength
            ranking and a mean-pose nearest neighbour on the same folds, and, when the trials
            carry a "content" label with each content in at least two emotions, the
            affective-feature classifier on features relative to each trial's content
            (``affective_features_by_content``,
            :class:`~bayesmotion.baselines.classifier.GroupCentred`).
        fit_kwargs: further options of every fit (e.g. ``optimize_style=("content",)``).
        calibrate: True: calibrate the label probabilities and the coordinates' regions on
            held-out trials, each trial's calibration cross-fitted from the others alone;
            "labels": the label probabilities only (no second inference per trial). The label
            probabilities: n_eff, the frames one recording's evidence is worth
            (:mod:`bayesmotion.emotion.evidence`), from the other trials' plain level evidence,
            under ``"evidence"`` (with ``n_eff_all_trials`` for
            :func:`bayesmotion.emotion.evidence.calibrate_evidence`). The coordinates:
            also infer each held-out trial from a tempered posterior whose likelihood
            power is calibrated on the *other* trials' plain posteriors (without trial i:
            :func:`calibrate_hpd_power` on their clip likelihoods over the simplex when every
            posterior kept its density, else :func:`calibrate_likelihood_power` on their
            Mahalanobis distances), and report that posterior's
            coverage and accuracy under ``"calibrated"``: cross-fitted, eta_i uses only the
            other trials' held-out statistics (whose folds' models did see trial i's data).
            Needs at least three trials. If no power can be calibrated, ``"calibrated"``
            holds the error and the plain results are kept.
        infer_kwargs: further options of every ``infer_emotion`` call (not ``styles``,
            ``couple``, ``n_steps``, ``seed``, which the harness sets; ``likelihood_power`` only
            without ``calibrate``).

    The held-out trial's labels of the model's other style factors (couple, content, ...) are
    given to ``infer_emotion``; only its emotion is inferred.
    Returns:
        dict: per-trial true/pred labels, means, probabilities, coverage, plain level
        evidence, inference seconds; accuracy and its binomial sd; confusion matrix (percent,
        Taubert layout); baseline accuracies; seconds. ``label_calibration``: ECE, reliability
        bins, label-set coverage, confident errors and log score of the label probabilities
        (:func:`bayesmotion.evaluation.calibration.label_calibration`), and
        ``baseline_label_calibration`` the same for the affective-feature classifiers.
        Four coverages of the true label's coordinates (a vertex of the simplex) at level ``q``:
        ``coverage``, by the ellipsoidal credible region
        (:meth:`EmotionPosterior.region_contains`); ``hpd_coverage``, by the highest-density
        region (:meth:`EmotionPosterior.hpd_contains`; None when the posteriors kept no
        density);
        ``label_set_coverage``, the true label inside the smallest set of levels holding
        probability ``q``; ``interval_coverage``, every coordinate inside its equal-tailed
        interval -- almost always 0 for a one-hot truth (equal-tailed intervals of a
        posterior on the open simplex reach 0 or 1 only when samples underflow to the vertex),
        kept for reference.
    """
    if "emotion" not in dataset.levels:
        raise BayesmotionError("leave_one_out needs an 'emotion' label on every trial")
    t0 = time.perf_counter()
    spec = spec or (full_model.spec if full_model is not None else HGPDM())
    fit_kwargs = dict(fit_kwargs or {})
    infer_kwargs = dict(infer_kwargs or {})
    taken = {"styles", "couple", "n_steps", "seed", "latent_uncertainty"} & set(infer_kwargs)
    if calibrate and "likelihood_power" in infer_kwargs:
        taken.add("likelihood_power")
    if calibrate and "effective_frames" in infer_kwargs:
        taken.add("effective_frames")  # the calibration needs the plain evidence
    if taken:
        raise BayesmotionError(f"infer_kwargs may not set {sorted(taken)}: leave_one_out sets "
                               f"them")
    check_projection_starts(infer_kwargs.get("emotion_starts", "vertices"),
                            infer_kwargs.get("level_starts", 1),
                            infer_kwargs.get("start_jitter", START_JITTER))
    if calibrate not in (True, False, "labels"):
        raise BayesmotionError(f"calibrate must be True, False or 'labels', got {calibrate!r}")
    if calibrate and len(dataset) < 3:
        raise BayesmotionError(f"calibrate={calibrate!r} needs at least 3 trials, got "
                               f"{len(dataset)}")
    if calibrate and infer_kwargs.get("emotion_starts", "vertices") != "vertices":
        raise BayesmotionError("calibrating the label probabilities needs the levels' evidence: "
                               "emotion_starts='vertices'")
    # the baselines first: they are cheap, and a skeleton their features cannot read must fail
    # before any fit, not after the folds' refits
    b, b_probs = _baselines(dataset, "emotion") if baselines else (None, None)
    if full_model is None:
        full_model = spec.fit(dataset, progress=progress, seed=seed, **fit_kwargs)
    levels = list(dataset.levels["emotion"])
    rows, runs = [], []
    for i, (train, held) in enumerate(dataset.leave_one_out()):
        release_compiled_programs()  # folds of other sizes compile anew: keep the maps bounded
        keep = [r for r in range(len(dataset)) if r != i]
        fold = spec.fit(train, max_iter=refit_iter, progress=False, seed=seed,
                        init=_fold_init(full_model, keep), **fit_kwargs)
        given = {f: held.labels[f] for f in fold.spec.factors if f != "emotion"}
        ep = infer_flagged(fold, held, styles=given, n_steps=n_steps, seed=seed + i,
                           latent_uncertainty=False, **infer_kwargs)
        truth = np.eye(len(levels))[levels.index(held.labels["emotion"])]
        lo, hi = ep.interval(q)
        dens = ep.log_likelihood is not None
        if calibrate is True:
            dens_at = None
            if dens:  # the clip's likelihood over the simplex, for the regions' exact levels
                U, lq = tempering_proposal(ep.mean, seed=seed)
                dens_at = {"loglik_points": np.asarray(ep.log_likelihood(U)),
                           "log_proposal_points": lq,
                           "loglik_truth": float(np.asarray(ep.log_likelihood(truth[None]))[0]),
                           "log_prior_truth": float(ep._tempered(np.zeros(1), truth[None])[0]),
                           "log_prior_points": np.asarray(ep._tempered(np.zeros(len(U)), U))}
            runs.append((fold, held, given, truth, dens_at))
        rows.append({"trial": held.name, "true": held.labels["emotion"], "pred": ep.label,
                     "mean": ep.mean.tolist(), "probabilities": ep.probabilities.tolist(),
                     "covered": ep.region_contains(truth, q),
                     "truth_mahalanobis2": ep.mahalanobis2(truth),
                     "hpd_covered": ep.hpd_contains(truth, q) if dens else None,
                     "truth_loglik_drop": ep.loglik_drop(truth) if dens else None,
                     "label_set": list(ep.label_set(q)),
                     "n_frames": int(ep.info["n_frames"]),
                     "level_log_evidence": ep.info.get("level_log_evidence"),
                     "level_prior": ep.info.get("level_prior"),
                     "in_distribution_weight": ep.info.get("in_distribution_weight"),
                     "seconds": float(ep.info["seconds"]),
                     "out_of_distribution": ep.out_of_distribution,
                     "unseen_levels": ep.info.get("unseen_levels", {}),
                     "ood_score": ep.info["ood"]["score"],
                     "intervals_cover": bool(np.all((truth >= lo) & (truth <= hi))),
                     "true_coordinate_interval": [float(lo[levels.index(held.labels["emotion"])]),
                                                  float(hi[levels.index(held.labels["emotion"])])]})
    true = [r["true"] for r in rows]
    pred = [r["pred"] for r in rows]
    acc = float(np.mean([t == p for t, p in zip(true, pred, strict=True)]))
    out = {
        "levels": levels,
        "trials": rows,
        "accuracy": acc,
        "accuracy_sd": float(np.sqrt(acc * (1 - acc) / len(rows))),
        "confusion_percent": confusion_matrix(true, pred, levels).tolist(),
        "coverage": float(np.mean([r["covered"] for r in rows])),
        "hpd_coverage": (float(np.mean([r["hpd_covered"] for r in rows]))
                         if all(r["hpd_covered"] is not None for r in rows) else None),
        "label_set_coverage": float(np.mean([r["true"] in r["label_set"] for r in rows])),
        "out_of_distribution_rate": float(np.mean([r["out_of_distribution"] for r in rows])),
        # folds whose true emotion no training trial had with the held-out trial's other
        # labels (infer_emotion's unseen_levels): judged by its layers' GP prior there
        "true_level_unseen_rate": float(np.mean([r["true"] in r["unseen_levels"]
                                                 for r in rows])),
        "interval_coverage": float(np.mean([r["intervals_cover"] for r in rows])),
        "credible_level": q,
        "refit_iter": refit_iter,
        "likelihood_power": float(infer_kwargs.get("likelihood_power", 1.0)),
    }
    out.update(score_labels(out, with_evidence=bool(calibrate)))
    truth_idx = np.array([levels.index(t) for t in true])
    if calibrate is True:
        try:
            out["calibrated"] = _calibrated(rows, runs, levels, q, n_steps, seed, infer_kwargs)
        except BayesmotionError as e:  # keep the plain results
            out["calibrated"] = {"error": str(e)}
    if baselines:
        out["baselines"] = {k: float(np.mean([p == t for p, t in zip(v, true, strict=True)]))
                            for k, v in b.items()}
        # the one baseline that answers with probabilities; Ho et al.'s ranking and the
        # nearest neighbour give labels only
        out["baseline_label_calibration"] = {
            k: label_calibration(p, truth_idx, q) for k, p in b_probs.items()}
    out["seconds"] = time.perf_counter() - t0
    return out


def online_sharpening(model, trials, fractions=(0.25, 0.5, 0.75, 1.0), seed: int = 0,
                      **infer_kwargs) -> dict:
    """How the emotion posterior sharpens as a clip's frames arrive (online inference).

    Each trial is read from its first ``ceil(f * T)`` frames for every fraction ``f`` (at least
    the dynamics order + 1 frames), padded as the whole trial is (:func:`infer_emotion`'s
    ``pad_to``, so that the prefixes share one compilation), and its emotion inferred; reported
    per fraction: the mean over trials of the coordinates' differential entropy
    (:attr:`EmotionPosterior.coordinate_entropy`) and of the label entropy
    (:attr:`EmotionPosterior.entropy`), and the fraction of trials inferred correctly. The
    trials should be held out of ``model``'s training data.

    Args:
        model: a FittedHGPDM (or a Posterior, as for :func:`infer_emotion`).
        trials: labelled Trials (their labels of the model's other factors are given).
        fractions: increasing prefix fractions in (0, 1].
        **infer_kwargs: further options of :func:`infer_emotion` (not ``styles``, ``seed``,
            ``latent_uncertainty``, which this sets: the styles from each trial's labels).
    """
    taken = {"styles", "seed", "latent_uncertainty"} & set(infer_kwargs)
    if taken:
        raise BayesmotionError(f"infer_kwargs may not set {sorted(taken)}: online_sharpening "
                               f"sets them (each trial's known styles, and the poses' group of "
                               f"a model with relative_to, come from the trial's labels)")
    fr = np.asarray(fractions, dtype=float)
    if fr.ndim != 1 or fr.size < 2 or np.any(np.diff(fr) <= 0) or fr[0] <= 0 or fr[-1] > 1:
        raise BayesmotionError(f"fractions must increase within (0, 1], at least two, got "
                               f"{list(fractions)}")
    fitted = getattr(model, "model", model)
    o = fitted.spec.order
    per_trial = []
    for i, t in enumerate(trials):
        given = {f: t.labels[f] for f in fitted.spec.factors if f != "emotion"}
        n = t.n_frames
        whole = clip_poses(fitted, t)[0].shape[0]  # the whole trial as infer_emotion reads it
        rows = []
        for f in fr:
            k = min(n, max(o + 1, int(np.ceil(f * n))))
            ep = infer_flagged(model, t.select(slice(0, k)), styles=given, seed=seed + i,
                               latent_uncertainty=False, **{"pad_to": whole, **infer_kwargs})
            rows.append({"frames": k, "coordinate_entropy": ep.coordinate_entropy,
                         "label_entropy": ep.entropy, "correct": ep.label == t.labels["emotion"]})
        per_trial.append({"trial": t.name, "prefixes": rows})
    mean = {key: [float(np.mean([p["prefixes"][j][key] for p in per_trial]))
                  for j in range(fr.size)]
            for key in ("coordinate_entropy", "label_entropy", "correct")}
    return {"fractions": fr.tolist(), "trials": per_trial,
            "mean_coordinate_entropy": mean["coordinate_entropy"],
            "mean_label_entropy": mean["label_entropy"], "accuracy": mean["correct"],
            "entropy_decreases": bool(mean["coordinate_entropy"][-1]
                                      < mean["coordinate_entropy"][0])}


def format_confusion(result: dict) -> str:
    """Plain-text table: rows = inferred, columns = intended (percent)."""
    levels = result["levels"]
    C = np.asarray(result["confusion_percent"])
    w = max(len(l) for l in levels) + 2
    head = "inferred \\ intended".ljust(20) + "".join(l.rjust(w) for l in levels)
    lines = [head] + [l.ljust(20) + "".join(f"{C[i, j]:{w}.1f}" for j in range(len(levels)))
                      for i, l in enumerate(levels)]
    lines.append(f"overall {100 * result['accuracy']:.1f}% +- {100 * result['accuracy_sd']:.1f}")
    return "\n".join(lines)


def interval_coverage(truth, mean, var, qs=(0.5, 0.9), fps: float = 1.0, n_observed: int = 0,
                      horizon_s: float = 1.0) -> dict:
    """How often the truth falls inside central Gaussian predictive intervals, per horizon.

    Args:
        truth: (..., T, ...) array with time on axis ``-3`` (joint positions (A, T, J, 3)) --
            any layout whose axis -3 is time.
        mean: predictive mean, same layout.
        var: predictive variance, same layout.
        qs: nominal levels.
        fps: frame rate (horizons are reported in seconds).
        n_observed: leading frames copied from data (excluded: zero variance there).
        horizon_s: width of each horizon bin in seconds.
    Returns:
        {"overall": {q: fraction}, "first_second": {q: fraction}, "by_horizon":
        [{"from_s", "to_s", q: fraction, ...}]}, fractions over every coordinate in the window.
    """
    from scipy.stats import norm

    truth, mean, var = (np.asarray(a, dtype=np.float64) for a in (truth, mean, var))
    if not truth.shape == mean.shape == var.shape or truth.ndim < 3:
        raise BayesmotionError(f"truth, mean and var must share one shape with time on axis -3;"
                               f" got {truth.shape}, {mean.shape}, {var.shape}")
    T = truth.shape[-3]
    if not 0 <= n_observed < T:
        raise BayesmotionError(f"n_observed must be in [0, {T}), got {n_observed}")
    sd = np.sqrt(np.maximum(var, 1e-300))
    err = np.abs(truth - mean)
    inside = {str(q): err <= norm.ppf(0.5 + q / 2) * sd for q in qs}

    def frac(a, b):
        return {q: float(ins[..., a:b, :, :].mean()) for q, ins in inside.items()}

    width = max(int(round(horizon_s * fps)), 1)
    bins = [{"from_s": (a - n_observed) / fps, "to_s": (min(a + width, T) - n_observed) / fps,
             **frac(a, min(a + width, T))} for a in range(n_observed, T, width)]
    return {"overall": frac(n_observed, T), "first_second": frac(n_observed, n_observed + width),
            "by_horizon": bins}


def infer_flagged(*args, **kwargs):
    """:func:`infer_emotion` whose out-of-distribution flag and unseen levels are kept on the
    result (and in the harness's rows) instead of warning once per held-out clip."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfDistributionWarning)
        warnings.simplefilter("ignore", UnseenStyleWarning)
        return infer_emotion(*args, **kwargs)
