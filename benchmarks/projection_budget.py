"""How many L-BFGS iterations a clip's level projections need before the answer settles.

    python benchmarks/run_all.py --only projection_budget

``infer_emotion`` projects a clip once per emotion level, each projection at most ``max_iter``
L-BFGS iterations (it stops earlier where it converges), and compares the levels by the
Laplace evidence at each end point. This runs the 16 shared Bandai walks leave-one-clip-out
at the settings of ``bandai_inference.py`` and ``projection_starts.py`` (15 fps, 60 frames,
the affective pose space, one fold refit of 100 warm-started iterations, the nearest-frame
start) and infers every held-out walk at each budget of ``FULL["budgets"]``, from the same
fold model, each inference from scratch as a user's call with that ``max_iter`` would run.
Reported per budget: the plain-evidence answers (accuracy, ECE, 90% label-set coverage, wrong
answers with P >= 0.99), how often the answer is the largest budget's, and the median seconds
of an inference (the first fold's first call includes compilation). ``--quick``: two walk
contents at 7.5 fps, 20 frames.

Current result (``results/projection_budget.json``): see ``["headline"]``.
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
from projection_starts import WALKS, level_answers, walk_folds, walks_model  # noqa: E402

FULL = {"contents": WALKS, "fps": 15.0, "model_frames": 60, "max_iter": 300, "refit_iter": 100,
        "budgets": (50, 100, 200, 400, 1000), "n_steps": 60}
QUICK = {"contents": WALKS[2:], "fps": 7.5, "model_frames": 20, "max_iter": 30,
         "refit_iter": 10, "budgets": (20, 50, 200), "n_steps": 30}


def run(quick: bool, root: str | Path | None = None) -> dict:
    from bayesmotion.emotion.infer import infer_emotion
    from bayesmotion.emotion.ood import OutOfDistributionWarning

    cfg = dict(QUICK if quick else FULL)
    root = Path(root) if root is not None else BANDAI_ROOT
    base = {"settings": {**cfg, "budgets": list(cfg["budgets"])}}
    if not bandai_present(root):
        return {**base, "skipped": f"Bandai data not found at {root}", "headline": []}
    clips, spec, full = walks_model(cfg, root)
    rows = []
    for i, held, fold in walk_folds(clips, spec, full, cfg["refit_iter"]):
        per = {}
        for k in cfg["budgets"]:
            t0 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", OutOfDistributionWarning)
                info = infer_emotion(fold, held, n_steps=cfg["n_steps"], seed=i, max_iter=k,
                                     latent_uncertainty=False, effective_frames=np.inf).info
            per[str(k)] = {"seconds": time.perf_counter() - t0,
                           "log_evidence": info["level_log_evidence"],
                           "objectives": info["level_objectives"]}
        rows.append({"trial": held.name, "true": held.labels["emotion"], "budgets": per})
    return {**base, **summarize(rows, list(clips.levels["emotion"]), cfg["budgets"])}


def summarize(rows: list, levels: list, budgets) -> dict:
    """Per budget, from the folds' stored level evidences and seconds: the answers, the share
    of folds whose answer is the largest budget's, and the median seconds."""
    truth = np.array([levels.index(r["true"]) for r in rows])
    top = str(max(budgets))
    final = np.argmax([r["budgets"][top]["log_evidence"] for r in rows], 1)
    by = []
    for k in budgets:
        ev = np.array([r["budgets"][str(k)]["log_evidence"] for r in rows])
        ans = level_answers(ev, truth)
        by.append({"max_iter": int(k),
                   **{key: v for key, v in ans.items() if key != "probabilities"},
                   "same_answer_as_largest": float(np.mean(np.argmax(ev, 1) == final)),
                   "seconds": float(np.median([r["budgets"][str(k)]["seconds"]
                                               for r in rows]))})
    n = len(rows)
    head = [headline(f"plain-evidence accuracy, {n} held-out walks, projections of at most "
                     f"{b['max_iter']} iterations", 100 * b["accuracy"], "%", "", None,
                     f"same answer as at {top} in {round(b['same_answer_as_largest'] * n)}/"
                     f"{n}; ECE {b['ece']:.3f}; wrong with P >= 0.99: "
                     f"{100 * b['confident_wrong']:.1f}%; {b['seconds']:.1f} s per clip "
                     f"(median)") for b in by]
    return {"levels": levels, "folds": rows, "by_budget": by, "headline": head}

