"""How much a level's Laplace evidence depends on where its projection starts.

    python benchmarks/run_all.py --only projection_starts

``infer_emotion`` (``emotion_starts="vertices"``) projects a clip once per emotion level and
compares the levels by the Laplace evidence at each optimum. The clip density is multimodal in
the latents, so the optimum one start reaches is one of many. This runs the 16 shared Bandai
walks leave-one-clip-out at the settings of ``bandai_inference.py`` (15 fps, 60 frames, the
affective pose space, one fold refit of 100 warm-started iterations, projections of 1,000
L-BFGS iterations), six starts per level: the nearest-frame latents exactly
(the default) and five copies jittered by N(0, 0.02^2) in every latent coordinate
(``level_starts=6, start_jitter=0.02``; ``level_starts=k`` >= 2 runs the first k, and
``level_starts=1`` with the jitter the second).
Reported side by side, from the same projections: the spread (max - min) of each level's
evidence over the six starts, and the plain-evidence label answers of the unjittered start,
of each jittered start alone, and of the best of k jittered starts (every choice of k), with
the unjittered one (what ``level_starts`` runs) and without it (accuracy, ECE, label-set
coverage, wrong answers with P >= 0.99). ``--quick``: two walk contents at 7.5 fps, 20
frames, 3 starts.

Besides, each fold is inferred with one start per level each way, timed alone: the nearest
frames' latents (the default) and the staged start (``staged_start=True``:
:func:`bayesmotion.emotion.projection.project_levels`); their answers, seconds, and the best of
the two by objective.

Current result (``results/projection_starts.json``): see ``["headline"]``.
"""

from __future__ import annotations

import itertools
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import BANDAI_ROOT, bandai_present, headline  # noqa: E402

WALKS = ("walk", "walk-back", "walk-left", "walk-right")
FULL = {"contents": WALKS, "fps": 15.0, "model_frames": 60, "max_iter": 300, "refit_iter": 100,
        "projection_iter": 1000, "starts": 6, "n_steps": 60}
QUICK = {"contents": WALKS[2:], "fps": 7.5, "model_frames": 20, "max_iter": 30,
         "refit_iter": 10, "projection_iter": 200, "starts": 3, "n_steps": 30}
# starts: per level, the unjittered start and starts - 1 jittered ones
JITTER = 0.02


def level_answers(log_ev: np.ndarray, truth: np.ndarray) -> dict:
    """Plain-evidence label answers of (folds, K) level log evidences under a flat prior:
    accuracy, ECE, 90% label-set coverage, wrong answers with P >= 0.99, the probabilities."""
    from bayesmotion.emotion.evidence import level_posterior
    from bayesmotion.evaluation.calibration import label_calibration

    K = log_ev.shape[1]
    probs = np.array([level_posterior(e, np.full(K, -np.log(K))) for e in log_ev])
    cal = label_calibration(probs, truth, 0.9, n_draws=0)
    return {"accuracy": float(np.mean(np.argmax(probs, 1) == truth)), "ece": cal["ece"],
            "label_set_coverage": cal["label_set_coverage"],
            "confident_wrong": cal["confident_wrong"], "probabilities": probs.tolist()}


def walks_data(cfg: dict, root: Path):
    """The walks of ``cfg`` (contents, fps, cropped to model_frames) as a dataset with the
    emotion factor."""
    from bayesmotion.data.motion import MotionDataset
    from bayesmotion.datasets.bandai import load_bandai

    data = load_bandai(root, content=cfg["contents"], fps=cfg["fps"])
    return MotionDataset(tuple(t.select(slice(0, cfg["model_frames"])) for t in data),
                         {"emotion": data.levels["emotion"]}, name="Bandai walks")


def walks_spec(inducing: int | None = None):
    """The benchmarks' one-actor affective-pose spec (exact, or sparse with ``inducing``)."""
    from bayesmotion.model.spec import HGPDM

    return HGPDM(latent_dim=6, interaction_dim=3, interaction_factors=("emotion",),
                 dynamics_factors=("emotion",), canonical_side=True, pose_space="affective",
                 inducing=inducing)


def walks_model(cfg: dict, root: Path):
    """:func:`walks_data`, :func:`walks_spec` and its fit on all the walks
    (``cfg["max_iter"]`` iterations): what each fold's refit starts from."""
    clips, spec = walks_data(cfg, root), walks_spec()
    full = spec.fit(clips, max_iter=cfg["max_iter"], progress=False)
    return clips, spec, full


def walk_folds(clips, spec, full, refit_iter: int):
    """Each walk held out in turn: (i, held-out trial, the fold model: ``spec`` refitted on
    the others for ``refit_iter`` iterations, warm-started from ``full``)."""
    from bayesmotion.evaluation.evaluate import _fold_init

    for i, (train, held) in enumerate(clips.leave_one_out()):
        keep = [r for r in range(len(clips)) if r != i]
        yield i, held, spec.fit(train, max_iter=refit_iter, progress=False,
                                init=_fold_init(full, keep))


def run(quick: bool, root: str | Path | None = None) -> dict:
    from bayesmotion.emotion.infer import infer_emotion
    from bayesmotion.emotion.ood import OutOfDistributionWarning

    cfg = dict(QUICK if quick else FULL)
    root = Path(root) if root is not None else BANDAI_ROOT
    base = {"settings": dict(cfg)}
    if not bandai_present(root):
        return {**base, "skipped": f"Bandai data not found at {root}", "headline": []}
    clips, spec, full = walks_model(cfg, root)
    levels = list(clips.levels["emotion"])
    rows = []
    for i, held, fold in walk_folds(clips, spec, full, cfg["refit_iter"]):
        t0 = time.perf_counter()
        kw = dict(n_steps=cfg["n_steps"], seed=i, max_iter=cfg["projection_iter"],
                  latent_uncertainty=False, effective_frames=np.inf)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfDistributionWarning)
            lap = infer_emotion(fold, held, level_starts=cfg["starts"], start_jitter=JITTER,
                                staged_start=False, **kw).info["level_laplace"]
            seconds = time.perf_counter() - t0
            # one start per level, each way, timed alone: the nearest frames' latents (the
            # default) and the staged start
            single = {}
            for name, staged in (("nearest", False), ("staged", True)):
                t1 = time.perf_counter()
                info = infer_emotion(fold, held, staged_start=staged, **kw).info
                single[name] = {"seconds": time.perf_counter() - t1,
                                "log_evidence": info["level_log_evidence"],
                                "objectives": info["level_objectives"]}
        rows.append({"trial": held.name, "true": held.labels["emotion"], "seconds": seconds,
                     "start_log_evidence": [d["start_log_evidence"] for d in lap],
                     "start_objectives": [d["start_objectives"] for d in lap],
                     "single_start": single})
    return {**base, **summarize(rows, levels, cfg["starts"])}


def summarize(rows: list, levels: list, S: int) -> dict:
    """The comparison, from the folds' stored start objectives and evidences alone (so a
    stored result can be summarised again without projecting). Column 0 of each level is the
    unjittered start, columns 1..S-1 the jittered ones."""
    truth = np.array([levels.index(r["true"]) for r in rows])
    ev = np.array([r["start_log_evidence"] for r in rows])  # (folds, K, starts)
    obj = np.array([r["start_objectives"] for r in rows])

    def best_of(idx):  # each level's evidence at the best objective among the starts idx
        idx = list(idx)
        e, o = ev[..., idx], obj[..., idx]
        return np.take_along_axis(e, np.argmin(o, 2)[..., None], 2)[..., 0]

    keys = ("accuracy", "ece", "label_set_coverage", "confident_wrong")

    def spread_of(subsets):  # mean, min and max over every choice of starts
        runs = [level_answers(best_of(c), truth) for c in subsets]
        return {"subsets": len(runs), **{
            key: {"mean": float(np.mean([r[key] for r in runs])),
                  "min": float(np.min([r[key] for r in runs])),
                  "max": float(np.max([r[key] for r in runs]))} for key in keys}}

    jittered = range(1, S)
    best = best_of(range(S))
    unjittered, many = level_answers(ev[..., 0], truth), level_answers(best, truth)
    # the best of k jittered starts, every such choice among the S - 1 run here; and the same
    # with the unjittered start added (level_starts = k >= 2 at start_jitter=JITTER runs one
    # of those choices, the first k - 1 jittered starts)
    by_starts = [{"starts": k, **spread_of(itertools.combinations(jittered, k))}
                 for k in range(1, S)]
    with_unjittered = [{"starts": k, **spread_of((0, *c) for c in
                                                  itertools.combinations(jittered, k - 1))}
                       for k in range(1, S + 1)]
    single = [{"start": j, "jitter": 0.0 if j == 0 else JITTER,
               **{key: v for key, v in level_answers(ev[..., j], truth).items()
                  if key != "probabilities"}} for j in range(S)]
    beaten = (obj < obj[..., :1]).sum(2)  # jittered starts better than the unjittered one
    spread = ev.max(2) - ev.min(2)  # (folds, K)
    gain = best - ev[..., 0]
    flips = int(np.sum(np.argmax(best, 1) != np.argmax(ev[..., 0], 1)))
    n = len(rows)
    one = by_starts[0]
    out = {"levels": levels, "folds": rows,
           "unjittered_start": unjittered, "best_of_starts": many, "by_starts": by_starts,
           "with_unjittered": with_unjittered, "each_start_alone": single,
           "jittered_starts_beating_the_first": np.bincount(beaten.ravel(),
                                                            minlength=S).tolist(),
           "evidence_spread": {"median": float(np.median(spread)),
                               "max": float(spread.max()),
                               "per_fold_level": spread.tolist()},
           "best_gain_over_first": {"median": float(np.median(gain)), "max": float(gain.max())},
           "label_changes": flips,
           "seconds_per_clip": float(np.median([r["seconds"] for r in rows]))}

    if all("single_start" in r for r in rows):
        out["single_start"] = _single_starts(rows, truth)

    def pct(b, key="accuracy"):
        return f"{100 * b[key]['mean']:.1f}% ({100 * b[key]['min']:.1f}-" \
               f"{100 * b[key]['max']:.1f})"

    out["headline"] = [
        headline(f"one level's Laplace evidence over {S} starts, {n} held-out walks: spread "
                 f"(max - min)", float(np.median(spread)), "nats", "", None,
                 f"median over folds and levels; largest {spread.max():.0f}; the best start "
                 f"beats the unjittered one by {np.median(gain):.0f} nats (median)"),
        headline("  plain-evidence accuracy, the unjittered start (the default)",
                 100 * unjittered["accuracy"], "%", "", None,
                 f"ECE {unjittered['ece']:.3f}; wrong with P >= 0.99: "
                 f"{100 * unjittered['confident_wrong']:.1f}%"),
        headline(f"  plain-evidence accuracy, one jittered start (start_jitter={JITTER:g})",
                 100 * one["accuracy"]["mean"], "%", "", None,
                 f"mean over the {S - 1} jittered starts, range "
                 f"{100 * one['accuracy']['min']:.1f}-{100 * one['accuracy']['max']:.1f}%; ECE "
                 f"{one['ece']['mean']:.3f}; wrong with P >= 0.99: "
                 f"{100 * one['confident_wrong']['mean']:.1f}%"),
        headline(f"  plain-evidence accuracy, best of {S - 1} jittered starts",
                 100 * by_starts[-1]["accuracy"]["mean"], "%", "", None,
                 "best of k (mean over every choice, range): "
                 + "; ".join(f"{b['starts']}: {pct(b)}" for b in by_starts)),
        headline(f"  the same with the unjittered start added, best of {S}",
                 100 * many["accuracy"], "%", "", None,
                 f"ECE {many['ece']:.3f}; best of the unjittered and k - 1 jittered: "
                 + "; ".join(f"{b['starts']}: {pct(b)}" for b in with_unjittered)),
        headline(f"  seconds per clip with {S} starts per level", out["seconds_per_clip"], "s",
                 "", None, "median, inference only"),
    ]
    if "single_start" in out:
        one = out["single_start"]
        for name, what in (("nearest", "the nearest frames' latents (the default)"),
                           ("staged", "the staged start (staged_start=True)")):
            r = one[name]
            out["headline"].append(headline(
                f"  one start per level, {what}: plain-evidence accuracy",
                100 * r["accuracy"], "%", "", None,
                f"ECE {r['ece']:.3f}; wrong with P >= 0.99: {100 * r['confident_wrong']:.1f}%; "
                f"{r['seconds']:.1f} s per clip (median, inference alone)"))
        b2 = one["best_of_both"]
        out["headline"].append(headline(
            "  best of the two single starts per level (by objective)", 100 * b2["accuracy"],
            "%", "", None, f"ECE {b2['ece']:.3f}; the staged start's objective is the lower "
            f"in {100 * one['staged_lower_objective']:.0f}% of fold-levels"))
    return out


def _single_starts(rows: list, truth: np.ndarray) -> dict:
    """Each single start's answers and median seconds, and the best of the two per level by
    objective, from the folds' ``single_start`` records."""
    out = {}
    for name in ("nearest", "staged"):
        ev = np.array([r["single_start"][name]["log_evidence"] for r in rows])
        ans = level_answers(ev, truth)
        out[name] = {**{k: v for k, v in ans.items() if k != "probabilities"},
                     "seconds": float(np.median([r["single_start"][name]["seconds"]
                                                 for r in rows]))}
    ev = np.stack([[r["single_start"][n]["log_evidence"] for r in rows]
                   for n in ("nearest", "staged")], -1)  # (folds, K, 2)
    obj = np.stack([[r["single_start"][n]["objectives"] for r in rows]
                    for n in ("nearest", "staged")], -1)
    best = np.take_along_axis(ev, np.argmin(obj, 2)[..., None], 2)[..., 0]
    ans = level_answers(best, truth)
    out["best_of_both"] = {k: v for k, v in ans.items() if k != "probabilities"}
    out["staged_lower_objective"] = float(np.mean(obj[..., 1] < obj[..., 0]))
    return out
