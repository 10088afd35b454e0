"""Side-by-side emotion interpolation study on the shared Bandai walks.

    python benchmarks/study_interpolation.py [--quick] [--root DIR] [--out FILE]
                                             [--max-iter N] [--optimize-style]
                                             [--init shared] [--table]

For each walk content and each emotion, four methods generate motion along the line from the
neutral clip to the emotional one, ``s ∈ {0, .25, .5, .75, 1}``, and extrapolate to ``s = 1.25``:

* ``hgpdm`` -- a one-actor hierarchical GPDM fitted (MAP) on the walks (resampled to ``fps``,
  each cropped to ``model_frames``), rolled out with emotion coordinates
  ``(1 - s)·e_neutral + s·e_emotion`` (off the simplex at 1.25, flagged) from the start state
  of the same content's training clip of the dominant emotion (neutral for s <= 0.5, as
  ``generate``'s default picks). With fixed one-hot training styles the style kernels vanish
  between emotions, so the emotions' latent regions are foreign to each other's dynamics: a
  rollout at s = 1 started from the neutral clip's state does not walk;
* ``fourier`` -- Unuma et al.: the emotional clip's Fourier model, phase-aligned to the
  neutral's, blended with it (coefficients, period, drift) at weight ``s``;
* ``amaya`` -- Amaya et al.: the speed/amplitude/posture style fitted on the pair, taken
  ``s`` of the way from identity (speed and amplitude ratios as ``ratio**s``, posture offsets
  ``s·offset``) and applied to the neutral clip;
* ``rbf`` -- Rose et al.'s verb over the content's clips at emotion coordinates (neutral at the
  origin, one unit axis per emotion), synthesised at ``s·e_emotion``; linear time
  normalisation (no key times).

Every output is scored (a) by the probability of the target emotion under the affective-feature
logistic-regression classifier trained on the real walks of the *other* contents, and by
``bayesmotion.emotion.infer.infer_emotion`` with the fitted H-GPDM where that exists; (b) by the Ho
et
al. ranking function (trained on the other contents) as raw strength and normalised so the
source pair's real neutral clip scores 0 and its real emotional clip 1; (c) by the naturalness
proxies of :mod:`bayesmotion.evaluation.naturalness` against all real walks at the same frame rate.

Per method and pair the summary gives the Spearman correlation of normalised strength with s
over [0, 1], the fraction of increasing steps, the calibration error mean |strength(s) - s|,
the strength gained from 1 to 1.25, the classifier's target probability along s and the mean
naturalness ratios. A method "interpolates the emotion" when, averaged over pairs, Spearman,
monotonicity and calibration all meet ``CRITERIA``; the conclusion string is computed from
those numbers. ``run(quick)`` returns the result (with ``settings`` and ``headline`` for
``run_all.py``) and writes it atomically to ``results/study_interpolation.json`` (or ``out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import BANDAI_ROOT, RESULTS, bandai_present, headline, machine_info, write_json  # noqa: E402

import bayesmotion  # noqa: E402, F401  (float64 on)
from bayesmotion.baselines import (  # noqa: E402
    LogisticRegression,
    apply_amaya,
    blend,
    emotion_coordinates,
    fit_amaya,
    fit_strength,
    fit_verb,
    fourier_eval,
    fourier_fit,
)
from bayesmotion.baselines.unuma import align_phase  # noqa: E402
from bayesmotion.data.emotion import EmotionStyle  # noqa: E402
from bayesmotion.data.motion import Motion, MotionDataset  # noqa: E402
from bayesmotion.datasets.bandai import WALK_CONTENTS, load_bandai  # noqa: E402
from bayesmotion.errors import BayesmotionError  # noqa: E402
from bayesmotion.evaluation.naturalness import NaturalnessReference, naturalness  # noqa: E402
from bayesmotion.features import clip_features  # noqa: E402
from bayesmotion.model.spec import HGPDM  # noqa: E402

NAME = "study_interpolation"
DATA_ROOT = BANDAI_ROOT
S_VALUES = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25)
METHODS = ("hgpdm", "fourier", "amaya", "rbf")
NEUTRAL = "neutral"
CRITERIA = {"spearman_min": 0.8, "monotonicity_min": 0.75, "calibration_error_max": 0.25}
NATURALNESS_KEYS = ("foot_sliding", "foot_sliding_ratio", "contact_fraction", "jerk",
                    "jerk_ratio", "jerk_local", "jerk_local_ratio", "joint_limit_violations",
                    "joint_limit_exceedance", "anatomical_violations")


@dataclass(frozen=True)
class Settings:
    """What one run does. ``model_frames``: frames per clip the H-GPDM trains on."""

    contents: tuple[str, ...] = WALK_CONTENTS
    emotions: tuple[str, ...] = ("happy", "angry", "sad")
    fps: float = 15.0
    model_frames: int = 60
    gen_frames: int = 60
    latent_dim: int = 6
    interaction_dim: int = 3
    max_iter: int = 1000
    optimize_style: bool = False
    latent_init: str = "pca"
    n_harmonics: int = 5
    seed: int = 0
    infer_s: tuple[float, ...] = (0.0, 0.5, 1.0)
    infer_frames: int = 30
    infer_steps: int = 100
    infer_max_iter: int = 50


QUICK = Settings(contents=("walk",), emotions=("happy",), max_iter=30, infer_s=())
"""One pair, 30 L-BFGS iterations, no infer_emotion (10-15 s a clip here, after a ~40 s
compile): about 1.5 min on 2 cores."""


# --------------------------------------------------------------------------- statistics
def spearman(x, y) -> float:
    """Spearman rank correlation (average ranks for ties); 0 when either side is constant."""
    from scipy.stats import rankdata

    rx, ry = rankdata(x), rankdata(y)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return 0.0
    return float(np.corrcoef(rx, ry)[0, 1])


def summarise(outputs: list[dict]) -> dict:
    """Per-method summary of one pair's outputs (module docstring)."""
    by_s = {o["s"]: o for o in outputs if "error" not in o}
    inside = [s for s in S_VALUES if s <= 1.0 and s in by_s]
    if len(inside) < 2:
        return {"error": "fewer than two scored outputs in [0, 1]"}
    st = np.array([by_s[s]["strength"]["normalised"] for s in inside])
    p = np.array([by_s[s]["classifier"]["p_target"] for s in inside])
    out = {
        "strength_spearman": spearman(inside, st),
        "strength_monotonicity": float(np.mean(np.diff(st) > 0)),
        "strength_calibration_error": float(np.mean(np.abs(st - np.array(inside)))),
        "strength_normalised": st.tolist(),
        "classifier_p_target": p.tolist(),
        "classifier_spearman": spearman(inside, p),
        "classifier_p_target_at_1": by_s.get(1.0, {}).get("classifier", {}).get("p_target"),
    }
    if 1.25 in by_s and 1.0 in by_s:
        out["extrapolation_gain"] = (by_s[1.25]["strength"]["normalised"]
                                     - by_s[1.0]["strength"]["normalised"])
    inf = {s: by_s[s].get("infer_emotion") for s in inside}
    inf = {s: v["target_mean"] for s, v in inf.items()
           if isinstance(v, dict) and "target_mean" in v}
    if len(inf) >= 3:
        out["infer_spearman"] = spearman(list(inf), list(inf.values()))
        out["infer_target_mean"] = list(inf.values())
    for k in ("foot_sliding_ratio", "jerk_ratio", "jerk_local_ratio", "joint_limit_violations"):
        out[f"mean_{k}"] = float(np.mean([o["naturalness"][k] for o in by_s.values()]))
    return out


# --------------------------------------------------------------------------- data
def load_walks(root: Path, fps: float) -> MotionDataset:
    return load_bandai(root, content=WALK_CONTENTS, fps=fps)


def clip(data: MotionDataset, content: str, emotion: str) -> Motion:
    for t in data:
        if t.labels["content"] == content and t.labels["emotion"] == emotion:
            return t.actors[0]
    raise BayesmotionError(f"no Bandai walk with content={content!r}, emotion={emotion!r}")


def training_set(data: MotionDataset, cfg: Settings) -> MotionDataset:
    """The H-GPDM's trials: the study's contents and emotions, cropped to model_frames."""
    levels = (NEUTRAL, *cfg.emotions)
    trials = [t.select(slice(0, cfg.model_frames)) for t in data
              if t.labels["content"] in cfg.contents and t.labels["emotion"] in levels]
    return MotionDataset(tuple(trials), {"emotion": levels}, name="study walks")


# --------------------------------------------------------------------------- generators
def fit_hgpdm(train: MotionDataset, cfg: Settings):
    spec = HGPDM(latent_dim=cfg.latent_dim, interaction_dim=cfg.interaction_dim,
                 interaction_factors=("emotion",), dynamics_factors=("emotion",))
    return spec.fit(train, max_iter=cfg.max_iter, seed=cfg.seed, progress=False,
                    optimize_style=cfg.optimize_style, init=cfg.latent_init)


def gen_hgpdm(model, train: MotionDataset, content: str, emotion: str, s: float,
              cfg: Settings) -> tuple[Motion, dict]:
    levels = model.levels["emotion"]
    eye = np.eye(len(levels))
    coords = (1 - s) * eye[levels.index(NEUTRAL)] + s * eye[levels.index(emotion)]
    dominant = NEUTRAL if s <= 0.5 else emotion
    start = next(i for i, t in enumerate(train)
                 if t.labels["content"] == content and t.labels["emotion"] == dominant)
    roll = model.generate(emotion=coords, n_frames=cfg.gen_frames, start=start)
    return roll.to_motion()[0], {"extrapolated": roll.extrapolated, "start": roll.start}


def gen_fourier(neutral: Motion, emotional: Motion, s: float, cfg: Settings):
    fa = fourier_fit(neutral, cfg.n_harmonics)
    fb = align_phase(fa, fourier_fit(emotional, cfg.n_harmonics))
    m = blend(fa, fb, s)
    return fourier_eval(m, cfg.gen_frames, cfg.fps), {"period_s": m.period}


def scaled_style(style: EmotionStyle, s: float) -> EmotionStyle:
    """The style ``s`` of the way from identity: ratios as ``ratio**s``, offsets times s."""
    return EmotionStyle(speed=style.speed**s,
                        amplitude={k: v**s for k, v in style.amplitude.items()},
                        posture={j: tuple(s * np.asarray(v)) for j, v in style.posture.items()})


def gen_amaya(neutral: Motion, emotional: Motion, s: float, cfg: Settings):
    style = fit_amaya(neutral, emotional, speed_from="angular_speed")
    return apply_amaya(scaled_style(style, s), neutral), {"speed": style.speed**s}


def gen_rbf(data: MotionDataset, content: str, emotion: str, s: float, cfg: Settings):
    trials = [t for t in data if t.labels["content"] == content]
    labels = [t.labels["emotion"] for t in trials]
    emotions = [e for e in data.levels["emotion"] if e != NEUTRAL and e in labels]
    verb = fit_verb([t.actors[0] for t in trials],
                    emotion_coordinates(labels, emotions, NEUTRAL))
    point = s * np.eye(len(emotions))[emotions.index(emotion)]
    return verb.synthesize(point), {
        "n_examples": len(trials),
        "rbf_weight_max": float(np.abs(verb.interpolant.c).max()),  # 0: linear blend only
    }


# --------------------------------------------------------------------------- scoring
@dataclass(frozen=True, eq=False)
class Scorers:
    """Everything one content's outputs are scored with (fitted on the other contents)."""

    classifier: LogisticRegression
    strength: object
    anchors: tuple[float, float]            # raw strength of the real neutral, emotional clip
    reference: NaturalnessReference
    model: object                            # the fitted H-GPDM, for infer_emotion
    cfg: Settings
    cache: dict                              # (id(motion), target) -> infer result, real clips


def _infer_emotion():
    try:
        from bayesmotion.emotion.infer import infer_emotion
    except ImportError:
        return None
    return infer_emotion


def score(motion: Motion, target: str, sc: Scorers, infer: bool) -> dict:
    """(a) classifier and infer_emotion, (b) strength, (c) naturalness of one motion."""
    probs = sc.classifier.predict_proba(clip_features(motion)[None])[0]
    classes = list(sc.classifier.classes)
    raw = sc.strength.score(motion)
    r0, r1 = sc.anchors
    nat = naturalness(motion, sc.reference)
    return {
        "n_frames": motion.n_frames,
        "classifier": {"p_target": float(probs[classes.index(target)]),
                       "p_neutral": float(probs[classes.index(NEUTRAL)]),
                       "predicted": classes[int(np.argmax(probs))]},
        "strength": {"raw": raw, "normalised": (raw - r0) / (r1 - r0)},
        "naturalness": {k: nat[k] for k in NATURALNESS_KEYS},
        "infer_emotion": score_infer(motion, target, sc) if infer else "not run at this s",
    }


def score_real(motion: Motion, target: str, sc: Scorers) -> dict:
    """:func:`score` of a real clip; its infer_emotion result is computed once per run."""
    key = (id(motion), target)
    out = score(motion, target, sc, False)
    if sc.cfg.infer_s:
        if key not in sc.cache:
            sc.cache[key] = score_infer(motion, target, sc)
        out["infer_emotion"] = sc.cache[key]
    return out


def score_infer(motion: Motion, target: str, sc: Scorers):
    """infer_emotion's posterior on the first ``infer_frames`` frames, or why there is none."""
    infer = _infer_emotion()
    if infer is None:
        return "not available"
    levels = list(sc.model.levels["emotion"])
    cfg = sc.cfg
    t0 = time.perf_counter()
    try:
        post = infer(sc.model, motion, frames=slice(0, cfg.infer_frames),
                     n_steps=cfg.infer_steps, max_iter=cfg.infer_max_iter,
                     latent_uncertainty=False, seed=cfg.seed)
    except Exception as e:  # a colleague's new API: record the failure, finish the study
        return {"error": f"{type(e).__name__}: {e}"}
    mean, prob = np.asarray(post.mean), np.asarray(post.probabilities)
    k = levels.index(target)
    return {"target_mean": float(mean[k]), "p_target": float(prob[k]), "label": post.label,
            "mean": mean.tolist(), "levels": levels, "seconds": time.perf_counter() - t0}


def fit_scorers(data: MotionDataset, content: str, emotion: str, reference, model,
                cfg: Settings, cache: dict) -> Scorers:
    """Classifier and ranking function on the real walks of the other contents."""
    train = [t for t in data if t.labels["content"] != content] or list(data)
    motions = [t.actors[0] for t in train]
    labels = [t.labels["emotion"] for t in train]
    clf = LogisticRegression().fit(np.stack([clip_features(m) for m in motions]), labels)
    strength = fit_strength(motions, labels, neutral=NEUTRAL,
                            groups=[t.labels["content"] for t in train])
    anchors = (strength.score(clip(data, content, NEUTRAL)),
               strength.score(clip(data, content, emotion)))
    return Scorers(clf, strength, anchors, reference, model, cfg, cache)


# --------------------------------------------------------------------------- the study
def generate(method: str, s: float, ctx: dict) -> tuple[Motion, dict]:
    c, e, cfg = ctx["content"], ctx["emotion"], ctx["cfg"]
    if method == "hgpdm":
        return gen_hgpdm(ctx["model"], ctx["train"], c, e, s, cfg)
    if method == "fourier":
        return gen_fourier(ctx["neutral"], ctx["emotional"], s, cfg)
    if method == "amaya":
        return gen_amaya(ctx["neutral"], ctx["emotional"], s, cfg)
    return gen_rbf(ctx["data"], c, e, s, cfg)


def study_pair(data, content, emotion, model, train, reference, cfg, cache) -> dict:
    sc = fit_scorers(data, content, emotion, reference, model, cfg, cache)
    ctx = {"content": content, "emotion": emotion, "cfg": cfg, "model": model, "train": train,
           "data": data, "neutral": clip(data, content, NEUTRAL),
           "emotional": clip(data, content, emotion)}
    pair = {"content": content, "emotion": emotion,
            "strength_anchors": {"neutral": sc.anchors[0], "emotion": sc.anchors[1]},
            "real": {"neutral": score_real(ctx["neutral"], emotion, sc),
                     "emotion": score_real(ctx["emotional"], emotion, sc)},
            "methods": {}}
    for method in METHODS:
        outputs = []
        for s in S_VALUES:
            try:
                motion, info = generate(method, s, ctx)
                outputs.append({"s": s, **info,
                                **score(motion, emotion, sc, s in cfg.infer_s)})
            except BayesmotionError as err:  # e.g. a clip too short for two gait cycles
                outputs.append({"s": s, "error": str(err)})
        pair["methods"][method] = {"outputs": outputs, "summary": summarise(outputs)}
    return pair


def aggregate(pairs: list[dict]) -> dict:
    """Per method, the mean of each scalar summary over the pairs that have it."""
    out = {}
    for method in METHODS:
        sums = [p["methods"][method]["summary"] for p in pairs
                if "error" not in p["methods"][method]["summary"]]
        keys = sorted({k for s in sums for k, v in s.items() if isinstance(v, float | int)})
        agg = {k: float(np.mean([s[k] for s in sums if s.get(k) is not None])) for k in keys}
        agg["n_pairs"] = len(sums)
        agg["interpolates_emotion"] = bool(sums) and (
            agg["strength_spearman"] >= CRITERIA["spearman_min"]
            and agg["strength_monotonicity"] >= CRITERIA["monotonicity_min"]
            and agg["strength_calibration_error"] <= CRITERIA["calibration_error_max"])
        out[method] = agg
    return out


def conclusion(summary: dict) -> str:
    ok = [m for m in METHODS if summary[m]["n_pairs"] and summary[m]["interpolates_emotion"]]
    rest = [m for m in METHODS if m not in ok and summary[m]["n_pairs"]]
    scored = [m for m in METHODS if summary[m]["n_pairs"]]
    if not scored:
        return "no method produced scorable outputs"
    best = min(scored, key=lambda m: summary[m]["strength_calibration_error"])
    smooth = min(scored, key=lambda m: abs(np.log(summary[m]["mean_jerk_ratio"])))
    limbs = min(scored, key=lambda m: abs(np.log(summary[m]["mean_jerk_local_ratio"])))
    slide = min(scored, key=lambda m: summary[m]["mean_foot_sliding_ratio"])
    fmt = ", ".join
    parts = [f"Interpolates the emotion (mean Spearman >= {CRITERIA['spearman_min']}, "
             f"monotone steps >= {CRITERIA['monotonicity_min']}, calibration error <= "
             f"{CRITERIA['calibration_error_max']}): {fmt(ok) or 'none'}",
             f"motion only: {fmt(rest) or 'none'}",
             f"best calibrated: {best} (error {summary[best]['strength_calibration_error']:.2f}, "
             f"Spearman {summary[best]['strength_spearman']:.2f})",
             f"jerk closest to real: {smooth} (ratio {summary[smooth]['mean_jerk_ratio']:.2f}; "
             f"body frame: {limbs}, {summary[limbs]['mean_jerk_local_ratio']:.2f})",
             f"least foot sliding: {slide} "
             f"(ratio {summary[slide]['mean_foot_sliding_ratio']:.2f})"]
    return "; ".join(parts) + "."


def headlines(summary: dict) -> list[dict]:
    rows = []
    for m in METHODS:
        s = summary[m]
        if not s["n_pairs"]:
            rows.append(headline(f"{m}: strength Spearman vs s", None, "", "", None, "no output"))
            continue
        rows.append(headline(
            f"{m}: strength Spearman vs s", s["strength_spearman"], "",
            f">= {CRITERIA['spearman_min']}", s["strength_spearman"] >= CRITERIA["spearman_min"],
            f"calibration error {s['strength_calibration_error']:.2f}, monotone "
            f"{s['strength_monotonicity']:.2f}, jerk ratio {s['mean_jerk_ratio']:.2f}, "
            f"foot sliding ratio {s['mean_foot_sliding_ratio']:.2f}"))
    return rows


def markdown_table(result: dict) -> str:
    """The README's results table, rendered from a study result (``--table``)."""
    if "summary" not in result:
        return f"(study not run: {result.get('skipped', 'no summary')})"

    def f(v, fmt="{:.2f}"):
        return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)

    head = ("| method | pairs | Spearman(strength, s) | monotone steps | calibration error "
            "| gain 1 -> 1.25 | classifier p(target) at s = 1 | Spearman(p, s) | jerk / real "
            "| foot sliding / real | interpolates the emotion |")
    rows = [head, "|" + "---|" * 11]
    for m in result["methods"]:
        a = result["summary"][m]
        if not a.get("n_pairs"):
            rows.append(f"| {m} | 0 |" + " - |" * 9)
            continue
        rows.append(
            f"| {m} | {a['n_pairs']} | {f(a.get('strength_spearman'))} "
            f"| {f(a.get('strength_monotonicity'))} | {f(a.get('strength_calibration_error'))} "
            f"| {f(a.get('extrapolation_gain'), '{:+.2f}')} "
            f"| {f(a.get('classifier_p_target_at_1'))} | {f(a.get('classifier_spearman'))} "
            f"| {f(a.get('mean_jerk_ratio'))} | {f(a.get('mean_foot_sliding_ratio'))} "
            f"| {'yes' if a['interpolates_emotion'] else 'no'} |")
    return "\n".join(rows) + "\n\n" + result["conclusion"]


def run(quick: bool, root: str | Path | None = None, out: str | Path | None = None,
        settings: Settings | None = None) -> dict:
    """Run the study (QUICK or full ``Settings``), write the JSON atomically, return it."""
    cfg = settings or (QUICK if quick else Settings())
    root = Path(root) if root is not None else DATA_ROOT
    out = Path(out) if out is not None else RESULTS / f"{result_name(cfg)}.json"
    base = {"name": NAME, "mode": "quick" if quick else "full", "settings": asdict(cfg)}
    if not bandai_present(root):
        result = {**base, "skipped": f"Bandai data not found at {root}", "headline": []}
        write_json(out, result)
        return result
    t0 = time.perf_counter()
    data = load_walks(root, cfg.fps)
    reference = NaturalnessReference.from_motions([t.actors[0] for t in data], cfg.fps)
    train = training_set(data, cfg)
    t_fit = time.perf_counter()
    model = fit_hgpdm(train, cfg)
    t_fit = time.perf_counter() - t_fit
    cache: dict = {}
    pairs = []
    for c in cfg.contents:
        for e in cfg.emotions:
            t_pair = time.perf_counter()
            pairs.append(study_pair(data, c, e, model, train, reference, cfg, cache))
            pairs[-1]["seconds"] = time.perf_counter() - t_pair
            print(f"[{NAME}] {c} neutral -> {e}: {pairs[-1]['seconds']:.0f} s", file=sys.stderr,
                  flush=True)
    summary = aggregate(pairs)
    result = {
        **base,
        "s_values": list(S_VALUES), "methods": list(METHODS), "criteria": CRITERIA,
        "data": {"root": str(root), "clips": [t.name for t in data],
                 "hgpdm_training": [t.name for t in train],
                 "hgpdm_frames": int(sum(t.n_frames for t in train))},
        "hgpdm_fit": {k: v for k, v in model.diagnostics.items() if k != "trace"},
        "infer_emotion": ("not available" if _infer_emotion() is None
                          else f"run at s in {list(cfg.infer_s)} and on the real clips"
                          if cfg.infer_s else "available, not run (infer_s is empty)"),
        "pairs": pairs, "summary": summary, "conclusion": conclusion(summary),
        "headline": headlines(summary),
        "timing_s": {"hgpdm_fit": t_fit, "total": time.perf_counter() - t0},
        "status": "ok", "machine": machine_info(),
    }
    write_json(out, result)
    return result


def result_name(cfg: Settings) -> str:
    """The default result file's name: the study's, with the H-GPDM's variant appended
    (``_learned_styles`` with ``--optimize-style``, ``_shared_latents`` with ``--init shared``)."""
    return (NAME + ("_learned_styles" if cfg.optimize_style else "")
            + ("_shared_latents" if cfg.latent_init == "shared" else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one pair, few iterations")
    ap.add_argument("--root", default=None, help=f"Bandai folder (default {DATA_ROOT})")
    ap.add_argument("--out", default=None, help="JSON path (default results/<name>.json)")
    ap.add_argument("--max-iter", type=int, default=None, help="override the H-GPDM iterations")
    ap.add_argument("--optimize-style", action="store_true",
                    help="learn the emotions' style vectors in the H-GPDM fit")
    ap.add_argument("--init", choices=("pca", "shared"), default="pca",
                    help="the H-GPDM's latent initialisation (fit(init=...)); 'shared' starts "
                         "every emotion's trials in one region of the interaction latents")
    ap.add_argument("--table", action="store_true",
                    help="print the markdown table of an existing result (--out or the default "
                         "results file) instead of running")
    a = ap.parse_args(argv)
    if a.table:
        import json

        path = Path(a.out) if a.out else RESULTS / f"{NAME}.json"
        print(markdown_table(json.loads(path.read_text())))
        return 0
    cfg = QUICK if a.quick else Settings()
    if a.max_iter is not None:
        cfg = replace(cfg, max_iter=a.max_iter)
    if a.optimize_style:
        cfg = replace(cfg, optimize_style=True)
    if a.init != "pca":
        cfg = replace(cfg, latent_init=a.init)
    res = run(a.quick, a.root, a.out, cfg)
    print(res.get("skipped") or res["conclusion"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
