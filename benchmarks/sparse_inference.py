"""Emotion inference on real walks from the exact model and from sparse ones, side by side.

    python benchmarks/run_all.py --only sparse_inference

The clip density's cost per L-BFGS iteration is the bottom layer's predictive variance against
every training frame (N^2 per clip frame for the exact model); a sparse model
(``HGPDM(inducing=M)``) conditions every layer on M inducing inputs instead (M^2). This runs
the 16 shared Bandai walks leave-one-clip-out at the settings of ``projection_budget.py`` (15
fps, 60 frames, the affective pose space, a 300-iteration fit on all walks, one fold refit of
100 warm-started iterations, the nearest-frame start, ``infer_emotion``'s default projection
budget) once per model in ``FULL["models"]`` (0: exact; M: M inducing points), each with its
own fits. Reported per model: the plain-evidence answers (accuracy, ECE, 90% label-set
coverage, wrong answers with P >= 0.99), the median seconds of an inference on a model whose
predictor is already conditioned (a program's second clip; the first fold's call includes
compilation) and, apart, the seconds of conditioning a fold model's predictor; how many level
projections stopped at the iteration limit; and the full fit's seconds. ``--quick``: two walk
contents at 7.5 fps, 20 frames, the exact model and 20 inducing points.

Current result (``results/sparse_inference.json``): see ``["headline"]``.
"""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import BANDAI_ROOT, bandai_present, headline  # noqa: E402
from projection_starts import (  # noqa: E402
    WALKS,
    level_answers,
    walk_folds,
    walks_data,
    walks_spec,
)

FULL = {"contents": WALKS, "fps": 15.0, "model_frames": 60, "max_iter": 300, "refit_iter": 100,
        "n_steps": 60, "models": (0, 100, 200)}
QUICK = {"contents": WALKS[2:], "fps": 7.5, "model_frames": 20, "max_iter": 30,
         "refit_iter": 10, "n_steps": 30, "models": (0, 20)}


def run(quick: bool, root: str | Path | None = None) -> dict:
    cfg = dict(QUICK if quick else FULL)
    root = Path(root) if root is not None else BANDAI_ROOT
    base = {"settings": {**cfg, "models": list(cfg["models"])}}
    if not bandai_present(root):
        return {**base, "skipped": f"Bandai data not found at {root}", "headline": []}
    clips = walks_data(cfg, root)
    models = [_one_model(clips, cfg, m) for m in cfg["models"]]
    return {**base, **summarize(models, list(clips.levels["emotion"]))}


def _one_model(clips, cfg: dict, inducing: int) -> dict:
    """Every fold of one model (0: exact): its fits, then each held-out walk's inference."""
    from bayesmotion.emotion.infer import infer_emotion
    from bayesmotion.emotion.ood import OutOfDistributionWarning

    spec = walks_spec(inducing or None)
    t0 = time.perf_counter()
    full = spec.fit(clips, max_iter=cfg["max_iter"], progress=False)
    fit_s = time.perf_counter() - t0
    folds = []
    for i, held, fold in walk_folds(clips, spec, full, cfg["refit_iter"]):
        t0 = time.perf_counter()
        fold.predictor()  # conditioned once per model, cached
        cond_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfDistributionWarning)
            ep = infer_emotion(fold, held, n_steps=cfg["n_steps"], seed=i,
                               latent_uncertainty=False, effective_frames=np.inf)
        folds.append({"trial": held.name, "true": held.labels["emotion"],
                      "log_evidence": ep.info["level_log_evidence"],
                      "level_iterations": ep.info["level_iterations"],
                      "seconds": time.perf_counter() - t0, "condition_seconds": cond_s})
    return {"inducing": inducing or None, "fit_seconds": fit_s, "folds": folds}


def summarize(models: list, levels: list, max_iter: int | None = None) -> dict:
    """Per model, from its folds' stored level evidences and seconds: the answers, the median
    seconds of an inference and of conditioning, and the level projections at the limit."""
    if max_iter is None:
        from bayesmotion.emotion.infer import PROJECTION_ITER as max_iter
    by, head = [], []
    for m in models:
        rows = m["folds"]
        truth = np.array([levels.index(r["true"]) for r in rows])
        ans = level_answers(np.array([r["log_evidence"] for r in rows]), truth)
        its = [n for r in rows for n in r["level_iterations"]]
        row = {"inducing": m["inducing"],
               **{k: v for k, v in ans.items() if k != "probabilities"},
               "seconds": float(np.median([r["seconds"] for r in rows])),
               "condition_seconds": float(np.median([r["condition_seconds"] for r in rows])),
               "at_limit": int(sum(n >= max_iter for n in its)), "n_projections": len(its),
               "fit_seconds": m["fit_seconds"]}
        by.append(row)
        name = "exact" if m["inducing"] is None else f"sparse, M = {m['inducing']}"
        head.append(headline(
            f"plain-evidence accuracy, {len(rows)} held-out walks, {name}",
            100 * row["accuracy"], "%", "", None,
            f"ECE {row['ece']:.3f}; 90% label sets cover {100 * row['label_set_coverage']:.0f}%; "
            f"wrong with P >= 0.99: {100 * row['confident_wrong']:.1f}%; "
            f"{row['seconds']:.1f} s per clip (median, predictor conditioned; conditioning a "
            f"fold model {row['condition_seconds']:.1f} s); level projections at the "
            f"{max_iter}-iteration limit: {row['at_limit']}/{row['n_projections']}; full fit "
            f"{row['fit_seconds']:.0f} s"))
    return {"levels": levels, "models": models, "by_model": by, "headline": head}

