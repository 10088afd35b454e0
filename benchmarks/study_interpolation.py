"""Side-by-side emotion interpolation study on the shared Bandai walks.

    python benchmarks/study_interpolation.py [--quick] [--root DIR] [--out FILE]
                                             [--max-iter N] [--optimize-style]
                                             [--init shared|phase] [--rest-frames]
                                             [--periodic] [--lookahead W]
                                             [--dynamics-style requested|nearest|registered]
                                             [--synthesis-setup] [--rescore] [--table]

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
source pair's real neutral clip scores 0 and its real emotional clip 1, and by its position
along the real neutral -> emotional direction in standardised clip features (``FeatureAxis``,
also 0 and 1 at the real clips); (c) by the naturalness proxies of
:mod:`bayesmotion.evaluation.naturalness` against all real walks at the same frame rate.
The ranking function reads keyframe poses and speeds, so it depends on where in the gait cycle a
clip starts: ``phase_sensitivity`` scores windows of the real clips started 0, 8 and 16 frames
in with both measures, and each method's summary says how far its s = 0 and s = 1 outputs
score from the real clips (``*_vertex_error``), and how fast its mixed outputs move against
the same blend of its ends' joint speeds (``speed_vs_blend_*``). ``cycle_strength`` averages
the ranking function over windows started at every frame of a stride, so it no longer depends
on the start phase; its summaries (``cycle_strength_*``) are judged by the same ``CRITERIA``. The
H-GPDM's outputs also record how far their latents run from the training latents
(``latent_distance``), and ``hgpdm_dynamics`` how far each emotion's dynamics is from the
others' one step ahead (:func:`dynamics_cross_prediction`).
``--init phase`` fits the H-GPDM from interaction latents on one gait-phase circle shared by
every emotion (:func:`gait_phase`). ``--rest-frames`` fits
``HGPDM(rest_frames=True, canonical_side=True)``, ``--periodic`` fits ``HGPDM(periodic=True)``
and ``--lookahead W`` rolls the H-GPDM out with ``generate(lookahead=W)``: with all three
(``--rest-frames --periodic --lookahead 10``) the H-GPDM has the synthesis benchmark's walk
settings on the study's 60-frame crops at 15 fps. ``--synthesis-setup`` also takes the synthesis
benchmark's data and model size (:func:`synthesis_setup`: whole clips at 10 fps, interaction
latents of dimension 6, 40-frame outputs), so every method is compared on that fit.
``--dynamics-style nearest`` or ``registered`` rolls the H-GPDM out with
``generate(dynamics_style=...)``: the dynamics at the nearest emotion, or each emotion's own
rollout registered in time and blended (:mod:`bayesmotion.model.registration`).

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

from _common import (  # noqa: E402
    BANDAI_ROOT,
    RESULTS,
    bandai_present,
    bandai_skip,
    headline,
    machine_info,
    write_json,
)

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
from bayesmotion.emotion.infer import infer_emotion  # noqa: E402
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
    """What one run does. ``model_frames``: frames per clip the H-GPDM trains on (None: whole
    clips)."""

    contents: tuple[str, ...] = WALK_CONTENTS
    emotions: tuple[str, ...] = ("happy", "angry", "sad")
    fps: float = 15.0
    model_frames: int | None = 60
    gen_frames: int = 60
    latent_dim: int = 6
    interaction_dim: int = 3
    max_iter: int = 1000
    optimize_style: bool = False
    latent_init: str = "pca"
    periodic: bool = False  # HGPDM(periodic=True): each clip's end loops back to its phase
    rest_frames: bool = False  # HGPDM(rest_frames=True, canonical_side=True)
    lookahead: float = 0.0  # generate(lookahead=...) of the H-GPDM's rollouts
    dynamics_style: str = "requested"  # generate(dynamics_style=...) of the H-GPDM's rollouts
    n_harmonics: int = 5
    seed: int = 0
    infer_s: tuple[float, ...] = (0.0, 0.5, 1.0)
    infer_frames: int = 30
    infer_steps: int = 100
    infer_max_iter: int = 50


QUICK = Settings(contents=("walk",), emotions=("happy",), max_iter=30, infer_s=())
"""One pair, 30 L-BFGS iterations, no infer_emotion (10-15 s a clip here, after a ~40 s
compile): about 1.5 min on 2 cores."""


def synthesis_setup(cfg: Settings) -> Settings:
    """``cfg`` with the synthesis benchmark's walk fit (benchmarks/synthesis.py): whole clips at
    10 fps, ``HGPDM``'s default latent dimensions (6 / 6), rest frames on the canonical side,
    periodic, rolled out with look-ahead 10; generated clips of 40 frames (4 s, as the default
    60 frames at 15 fps)."""
    return replace(cfg, fps=10.0, model_frames=None, gen_frames=40, latent_dim=6,
                   interaction_dim=6, rest_frames=True, periodic=True, lookahead=10.0,
                   infer_frames=20)


# --------------------------------------------------------------------------- statistics
def spearman(x, y) -> float:
    """Spearman rank correlation (average ranks for ties); 0 when either side is constant."""
    from scipy.stats import rankdata

    rx, ry = rankdata(x), rankdata(y)
    if np.ptp(rx) == 0 or np.ptp(ry) == 0:
        return 0.0
    return float(np.corrcoef(rx, ry)[0, 1])


def summarise(outputs: list[dict], target: str | None = None) -> dict:
    """Per-method summary of one pair's outputs (module docstring); with the pair's ``target``
    emotion also how ``infer_emotion`` labels the 50/50 output (:func:`infer_summary`)."""
    by_s = {o["s"]: o for o in outputs if "error" not in o}
    inside = [s for s in S_VALUES if s <= 1.0 and s in by_s]
    if len(inside) < 2:
        return {"error": "fewer than two scored outputs in [0, 1]"}
    st = np.array([by_s[s]["strength"]["normalised"] for s in inside])
    p = np.array([by_s[s]["classifier"]["p_target"] for s in inside])
    ax = np.array([by_s[s]["feature_axis"] for s in inside])
    out = {
        "strength_spearman": spearman(inside, st),
        "strength_monotonicity": float(np.mean(np.diff(st) > 0)),
        "strength_calibration_error": float(np.mean(np.abs(st - np.array(inside)))),
        "strength_normalised": st.tolist(),
        "feature_axis": ax.tolist(),
        "axis_spearman": spearman(inside, ax),
        "axis_monotonicity": float(np.mean(np.diff(ax) > 0)),
        "axis_calibration_error": float(np.mean(np.abs(ax - np.array(inside)))),
        "classifier_p_target": p.tolist(),
        "classifier_spearman": spearman(inside, p),
        "classifier_p_target_at_1": by_s.get(1.0, {}).get("classifier", {}).get("p_target"),
    }
    cyc = [by_s[s].get("cycle_strength", {}).get("normalised") for s in inside]
    if None not in cyc:  # stored results from before the cycle-averaged strength lack it
        cyc = np.array(cyc)
        out.update({"cycle_strength_spearman": spearman(inside, cyc),
                    "cycle_strength_monotonicity": float(np.mean(np.diff(cyc) > 0)),
                    "cycle_strength_calibration_error": float(np.mean(np.abs(
                        cyc - np.array(inside)))),
                    "cycle_strength_normalised": cyc.tolist()})
        if inside[0] == 0.0 and inside[-1] == 1.0:
            out["cycle_strength_vertex_error"] = float((abs(cyc[0]) + abs(cyc[-1] - 1.0)) / 2)
    speeds = [by_s[s].get("joint_speed") for s in inside]
    if None not in speeds and inside[0] == 0.0 and inside[-1] == 1.0 and len(inside) > 2:
        # each mixed output's joint speed against the same blend of the two ends' speeds
        ratio = [v / ((1 - s) * speeds[0] + s * speeds[-1])
                 for s, v in zip(inside, speeds, strict=True)]
        out["joint_speed"] = speeds
        out["speed_vs_blend_mixed"] = float(np.mean(ratio[1:-1]))
        out["speed_vs_blend_min"] = float(np.min(ratio[1:-1]))
    if inside[0] == 0.0 and inside[-1] == 1.0:  # how far each end is from its real clip
        out["strength_vertex_error"] = float((abs(st[0]) + abs(st[-1] - 1.0)) / 2)
        out["axis_vertex_error"] = float((abs(ax[0]) + abs(ax[-1] - 1.0)) / 2)
    dist = {s: by_s[s]["latent_distance"] for s in inside if "latent_distance" in by_s[s]}
    if dist:
        ends = [v for s, v in dist.items() if s in (0.0, 1.0)]
        mixed = [v for s, v in dist.items() if 0.0 < s < 1.0]
        if ends and mixed:
            out["latent_distance_vertices"] = float(np.mean(ends))
            out["latent_distance_mixed"] = float(np.mean(mixed))
    if 1.25 in by_s and 1.0 in by_s:
        out["extrapolation_gain"] = (by_s[1.25]["strength"]["normalised"]
                                     - by_s[1.0]["strength"]["normalised"])
    inf = {s: by_s[s].get("infer_emotion") for s in inside}
    inf = {s: v["target_mean"] for s, v in inf.items()
           if isinstance(v, dict) and "target_mean" in v}
    if len(inf) >= 3:
        out["infer_spearman"] = spearman(list(inf), list(inf.values()))
        out["infer_target_mean"] = list(inf.values())
        out.update(infer_summary(by_s, target))
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
                 interaction_factors=("emotion",), dynamics_factors=("emotion",),
                 periodic=cfg.periodic, rest_frames=cfg.rest_frames,
                 canonical_side=cfg.rest_frames)
    init = phase_init(spec, train, cfg.seed) if cfg.latent_init == "phase" else cfg.latent_init
    return spec.fit(train, max_iter=cfg.max_iter, seed=cfg.seed, progress=False,
                    optimize_style=cfg.optimize_style, init=init)


def dynamics_cross_prediction(model, train: MotionDataset) -> dict:
    """Each emotion level's dynamics one step ahead along every training trial's own latent
    trajectory I: the mean error of the predictive mean and the predicted RMS error
    sqrt(Q_I (var + noise)) (latent function and dynamics noise; the expected error norm of a
    calibrated prediction), both per mean step length |I_t - I_{t-1}| of that trajectory, so
    predicting no move at all scores 1. On a trial of its own level a dynamics reproduces the
    step it was fitted to; on the other levels' trials it says how far apart the levels' flows
    are where a rollout at mixed coordinates runs, and whether the model knows it."""
    import jax.numpy as jnp

    from bayesmotion.model.layers import DynamicsIndex
    from bayesmotion.model.predict import noise_variances, predict_dynamics, style_vectors

    P = model.predictor()
    levels = list(model.levels["emotion"])
    o = model.spec.order
    index = DynamicsIndex(model.data.lengths, o)
    I_all = np.asarray(model.params["I"])
    noise = float(noise_variances(P)["I"])
    q = I_all.shape[1]
    rows = []
    for r, t in enumerate(train):
        keep = index.trial_of_frame[index.out] == r
        lags = jnp.asarray(np.stack([I_all[lag[keep]] for lag in index.lag]))
        nxt = I_all[index.out[keep]]
        step = float(np.linalg.norm(nxt - np.asarray(lags[0]), axis=1).mean())
        for k, level in enumerate(levels):
            onehot = np.tile(np.eye(len(levels))[k], (nxt.shape[0], 1))
            mean, var = predict_dynamics(P, lags, style_vectors(P, ["emotion"], [onehot]))
            rows.append({"trial": t.name, "level": level, "own": level == t.labels["emotion"],
                         "error_per_step": float(np.linalg.norm(np.asarray(mean) - nxt,
                                                                axis=1).mean() / step),
                         "predicted_rms_per_step": float(
                             np.sqrt(q * (np.asarray(var) + noise)).mean() / step)})
    out = {"noise_variance": noise, "rows": rows}
    for which, own in (("own", True), ("other", False)):
        sel = [x for x in rows if x["own"] == own]
        out[f"{which}_error_per_step_median"] = float(np.median([x["error_per_step"] for x in sel]))
        out[f"{which}_predicted_rms_per_step_median"] = float(
            np.median([x["predicted_rms_per_step"] for x in sel]))
    other = [x for x in rows if not x["own"]]
    out["other_error_above_3x_predicted"] = float(np.mean(
        [x["error_per_step"] > 3 * x["predicted_rms_per_step"] for x in other]))
    return out


def latent_distance(model, I: np.ndarray) -> float:
    """Median over a rollout's generated frames of the distance from its latent to the nearest
    training latent of any trial, per median training step length: how far from the data the
    rollout runs (about 0 while it retraces a training trajectory)."""
    import jax.numpy as jnp

    from bayesmotion.gp.kernels import sqdist

    I_train = np.asarray(model.params["I"])
    o = model.spec.order
    tof = np.asarray(model.data.trial_of_frame)
    same = tof[1:] == tof[:-1]
    step = float(np.median(np.linalg.norm(np.diff(I_train, axis=0)[same], axis=1)))
    d = np.sqrt(np.asarray(sqdist(jnp.asarray(I[o:]), jnp.asarray(I_train))).min(1))
    return float(np.median(d) / step)


def gait_phase(motion: Motion) -> np.ndarray:
    """Gait phase (T,) in radians: the angle of the analytic signal (Hilbert transform) of the
    left foot's lead over the right along the body's facing direction (from the hips, y up), linear
    trend removed. The same phase means the same point of the stride in every clip."""
    from scipy.signal import detrend, hilbert

    from bayesmotion.features.pose import semantic_positions

    p = semantic_positions(motion.positions(), motion.skeleton)
    forward = np.cross(p["l_hip"] - p["r_hip"], np.array([0.0, 1.0, 0.0]))
    forward /= np.linalg.norm(forward, axis=1, keepdims=True)
    lead = np.sum((p["l_foot"] - p["r_foot"]) * forward, axis=1)
    return np.angle(hilbert(detrend(lead)))


def phase_init(spec: HGPDM, train: MotionDataset, seed: int) -> dict:
    """The package's PCA start with the interaction latents I replaced by the gait-phase circle
    (cos phi, sin phi, 0) of every frame (:func:`gait_phase`) plus the same 1e-3 jitter: every
    emotion's walks start on one circle, aligned by stride."""
    from bayesmotion.model.data import fit_codecs, prepare_data
    from bayesmotion.model.fit import init_params, initial_ar
    from bayesmotion.model.layers import DynamicsIndex
    from bayesmotion.model.params import AR_KEY

    spec = spec.resolved(train)
    if spec.inducing is not None:
        raise BayesmotionError("phase_init sets the dense model's latents only")
    data = prepare_data(spec, train, fit_codecs(spec, train))
    params = init_params(spec, data, seed)
    phi = np.concatenate([gait_phase(t.actors[0]) for t in train])
    circle = np.zeros((phi.size, spec.interaction_dim))
    circle[:, 0], circle[:, 1] = np.cos(phi), np.sin(phi)
    rng = np.random.default_rng(seed)
    I = circle + 1e-3 * rng.standard_normal(circle.shape)
    params["I"] = I
    # what init_params derives from I: the dynamics' signal variance and noise precision, and
    # the explicit autoregression's start
    var_i = float(np.mean(I**2))
    params["log_alpha"] = np.array(params["log_alpha"], dtype=np.float64)
    params["log_alpha"][0], params["log_alpha"][-1] = np.log(var_i), np.log(100.0 / var_i)
    if AR_KEY in params:
        params[AR_KEY] = initial_ar(I, DynamicsIndex(data.lengths, spec.order))
    return params


def gen_hgpdm(model, train: MotionDataset, content: str, emotion: str, s: float,
              cfg: Settings) -> tuple[Motion, dict]:
    levels = model.levels["emotion"]
    eye = np.eye(len(levels))
    coords = (1 - s) * eye[levels.index(NEUTRAL)] + s * eye[levels.index(emotion)]
    dominant = NEUTRAL if s <= 0.5 else emotion
    start = next(i for i, t in enumerate(train)
                 if t.labels["content"] == content and t.labels["emotion"] == dominant)
    roll = model.generate(emotion=coords, n_frames=cfg.gen_frames, start=start,
                          lookahead=cfg.lookahead, dynamics_style=cfg.dynamics_style)
    return roll.to_motion()[0], {"extrapolated": roll.extrapolated, "start": roll.start,
                                 "latent_distance": latent_distance(model, roll.I)}


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
class FeatureAxis:
    """Emotion strength as the position along the real neutral -> emotional direction in clip
    features: ``(f(m) - f(neutral)) . d / |d|^2`` with ``d = f(emotional) - f(neutral)``, each
    feature divided by its spread over the other contents' real walks (``scale``). The real
    neutral clip is 0 and the real emotional clip 1, as for the normalised ranking strength. The
    clip features are statistics over the whole clip, so a motion's score depends far less on
    where in its gait cycle it starts than the ranking strength, which reads keyframes
    (``phase_sensitivity`` measures both)."""

    scale: np.ndarray
    origin: np.ndarray                       # f(neutral) / scale
    direction: np.ndarray                    # (f(emotional) - f(neutral)) / scale

    @classmethod
    def fit(cls, others: np.ndarray, neutral: Motion, emotional: Motion) -> FeatureAxis:
        scale = others.std(0)
        scale = np.where(scale > 0, scale, 1.0)
        origin = clip_features(neutral) / scale
        return cls(scale, origin, clip_features(emotional) / scale - origin)

    def strength(self, motion: Motion) -> float:
        d = self.direction
        return float((clip_features(motion) / self.scale - self.origin) @ d / (d @ d))


def joint_speed(motion: Motion) -> float:
    """Mean speed of the skeleton's joints over the clip (position units per second): how
    much the body moves, which the ranking function reads through its keyframe speeds."""
    p = motion.positions()
    return float(np.linalg.norm(np.diff(p, axis=0), axis=-1).mean() * motion.fps)


@dataclass(frozen=True, eq=False)
class Scorers:
    """Everything one content's outputs are scored with (fitted on the other contents)."""

    classifier: LogisticRegression
    strength: object
    anchors: tuple[float, float]            # raw strength of the real neutral, emotional clip
    cycle_anchors: tuple[float, float]      # the same, cycle-averaged (:func:`cycle_strength`)
    axis: FeatureAxis
    reference: NaturalnessReference
    model: object                            # the fitted H-GPDM, for infer_emotion
    cfg: Settings
    cache: dict                              # (id(motion), target) -> infer result, real clips


def score(motion: Motion, target: str, sc: Scorers, infer: bool) -> dict:
    """(a) classifier and infer_emotion, (b) strength, (c) naturalness of one motion."""
    probs = sc.classifier.predict_proba(clip_features(motion)[None])[0]
    classes = list(sc.classifier.classes)
    raw = sc.strength.score(motion)
    r0, r1 = sc.anchors
    c0, c1 = sc.cycle_anchors
    cyc, n_windows = cycle_strength(sc.strength, motion, sc.cfg)
    nat = naturalness(motion, sc.reference)
    return {
        "n_frames": motion.n_frames,
        "classifier": {"p_target": float(probs[classes.index(target)]),
                       "p_neutral": float(probs[classes.index(NEUTRAL)]),
                       "predicted": classes[int(np.argmax(probs))]},
        "strength": {"raw": raw, "normalised": (raw - r0) / (r1 - r0)},
        "cycle_strength": {"raw": cyc, "normalised": (cyc - c0) / (c1 - c0),
                           "windows": n_windows},
        "feature_axis": sc.axis.strength(motion),
        "joint_speed": joint_speed(motion),
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
    """infer_emotion's posterior on the first ``infer_frames`` frames, or the package's reason
    for refusing the clip."""
    levels = list(sc.model.levels["emotion"])
    cfg = sc.cfg
    t0 = time.perf_counter()
    try:
        post = infer_emotion(sc.model, motion, frames=slice(0, cfg.infer_frames),
                             n_steps=cfg.infer_steps, max_iter=cfg.infer_max_iter,
                             latent_uncertainty=False, seed=cfg.seed)
    except BayesmotionError as e:  # the package refused this clip: record why, go on
        return {"error": str(e)}
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
    feats = np.stack([clip_features(m) for m in motions])
    clf = LogisticRegression().fit(feats, labels)
    strength = fit_strength(motions, labels, neutral=NEUTRAL,
                            groups=[t.labels["content"] for t in train])
    neutral, emotional = clip(data, content, NEUTRAL), clip(data, content, emotion)
    anchors = (strength.score(neutral), strength.score(emotional))
    cycle_anchors = (cycle_strength(strength, neutral, cfg)[0],
                     cycle_strength(strength, emotional, cfg)[0])
    axis = FeatureAxis.fit(feats, neutral, emotional)
    return Scorers(clf, strength, anchors, cycle_anchors, axis, reference, model, cfg, cache)


STRIDE_SECONDS = 1.2
"""About one gait cycle of the Bandai walks: the windows of :func:`cycle_strength` start at
every frame of one such span, so their mean covers every phase of the stride."""


def cycle_window(cfg: Settings) -> int:
    """Frames per window of :func:`cycle_strength`: the generated clips' length less one stride,
    so a generated clip holds a window started at each frame of a stride (and one more)."""
    return max(4, cfg.gen_frames - int(round(STRIDE_SECONDS * cfg.fps)))


def cycle_strength(strength, motion: Motion, cfg: Settings,
                   offsets: range | None = None) -> tuple[float, int]:
    """The ranking function's mean over windows of :func:`cycle_window` frames started at each
    of ``offsets`` (default: every start the clip allows) and how many windows that is. A
    generated clip of ``gen_frames`` frames gives a window per frame of a stride (and one more),
    a real clip every window it holds, so the score no longer depends on where in its gait
    cycle the clip starts, as the single-window ranking strength does
    (:func:`phase_sensitivity` measures both). A clip shorter than a window is scored whole
    (one window)."""
    w = cycle_window(cfg)
    if motion.n_frames <= w:
        return float(strength.score(motion)), 1
    offsets = range(motion.n_frames - w + 1) if offsets is None else offsets
    starts = [o for o in offsets if o + w <= motion.n_frames]
    return float(np.mean([strength.score(motion.select(slice(o, o + w))) for o in starts])), \
        len(starts)


PHASE_OFFSETS = (0, 8, 16)
"""Start frames of the real clips' windows in :func:`phase_sensitivity` (at 15 fps about half
a stride and one stride apart)."""


def phase_sensitivity(motion: Motion, sc: Scorers) -> dict:
    """Both strength measures of windows of ``gen_frames`` frames (the H-GPDM's and Fourier's
    output length) cut from one real clip at :data:`PHASE_OFFSETS`, and their spread
    (max - min): the same recording started at another point of its gait cycle. A generated
    clip whose timing drifts from the real clip's (the H-GPDM's rollouts, Fourier's blends)
    moves its ranking strength by as much, without any change of emotion."""
    n = sc.cfg.gen_frames
    r0, r1 = sc.anchors
    offsets = [o for o in PHASE_OFFSETS if o + n <= motion.n_frames]
    wins = [motion.select(slice(o, o + n)) for o in offsets]
    st = [(sc.strength.score(w) - r0) / (r1 - r0) for w in wins]
    ax = [sc.axis.strength(w) for w in wins]
    out = {"clip": motion.name, "offsets": offsets, "strength": st, "feature_axis": ax}
    if len(wins) >= 2:
        out["strength_spread"] = float(np.ptp(st))
        out["feature_axis_spread"] = float(np.ptp(ax))
    stride = int(round(STRIDE_SECONDS * sc.cfg.fps))
    if motion.n_frames >= cycle_window(sc.cfg) + 2 * stride - 1:
        # the cycle-averaged strength from the first stride's starts and from the next's
        c0, c1 = sc.cycle_anchors
        halves = [(cycle_strength(sc.strength, motion, sc.cfg, range(a, a + stride))[0] - c0)
                  / (c1 - c0) for a in (0, stride)]
        out["cycle_strength_halves"] = halves
        out["cycle_strength_spread"] = float(abs(halves[1] - halves[0]))
    return out


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
            "phase_sensitivity": {"neutral": phase_sensitivity(ctx["neutral"], sc),
                                  "emotion": phase_sensitivity(ctx["emotional"], sc)},
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
        pair["methods"][method] = {"outputs": outputs, "summary": summarise(outputs, emotion)}
    return pair


def infer_summary(by_s: dict, target: str | None) -> dict:
    """``infer_emotion``'s reading of one pair's outputs at s = 0, 0.5 and 1: the target's
    coordinate at each (``infer_target_mean_at_*``), their mean |coordinate - s|
    (``infer_calibration_error``), and the 50/50 output's label as the target, the source
    (neutral) or another emotion (``infer_label_at_half``; with ``target``)."""
    got = {s: by_s[s].get("infer_emotion") for s in (0.0, 0.5, 1.0) if s in by_s}
    got = {s: v for s, v in got.items() if isinstance(v, dict) and "target_mean" in v}
    if len(got) < 3:
        return {}
    out = {f"infer_target_mean_at_{s:g}": float(v["target_mean"]) for s, v in got.items()}
    out["infer_calibration_error"] = float(np.mean([abs(v["target_mean"] - s)
                                                    for s, v in got.items()]))
    if target is not None:
        label = got[0.5]["label"]
        out["infer_label_at_half"] = ("target" if label == target else
                                      "source" if label == NEUTRAL else "other")
    return out


def meets_criteria(agg: dict, measure: str) -> bool:
    """Whether a method's pair means of ``measure`` (``strength`` or ``cycle_strength``) meet
    every one of ``CRITERIA``."""
    return bool(agg[f"{measure}_spearman"] >= CRITERIA["spearman_min"]
                and agg[f"{measure}_monotonicity"] >= CRITERIA["monotonicity_min"]
                and agg[f"{measure}_calibration_error"] <= CRITERIA["calibration_error_max"])


def aggregate(pairs: list[dict]) -> dict:
    """Per method, the mean of each scalar summary over the pairs that have it."""
    out = {}
    for method in METHODS:
        sums = [p["methods"][method]["summary"] for p in pairs
                if "error" not in p["methods"][method]["summary"]]
        keys = sorted({k for s in sums for k, v in s.items() if isinstance(v, float | int)})
        agg = {k: float(np.mean([s[k] for s in sums if s.get(k) is not None])) for k in keys}
        agg["n_pairs"] = len(sums)
        halves = [s["infer_label_at_half"] for s in sums if "infer_label_at_half" in s]
        if halves:  # how many 50/50 outputs infer_emotion labels as what
            agg["infer_labels_at_half"] = {k: halves.count(k)
                                           for k in ("target", "source", "other")}
        agg["interpolates_emotion"] = bool(sums) and meets_criteria(agg, "strength")
        if "cycle_strength_spearman" in agg:
            agg["interpolates_emotion_cycle_strength"] = meets_criteria(agg, "cycle_strength")
        out[method] = agg
    return out


def phase_summary(pairs: list[dict]) -> dict:
    """Median and largest spread of each strength measure over the real clips' windows
    (:func:`phase_sensitivity`), over every pair's neutral and emotional clip that is long
    enough for two windows (``n_scorings``; a neutral clip is scored once per pair, against
    that pair's anchors, so ``n_clips`` distinct clips)."""
    clips = [p["phase_sensitivity"][k] for p in pairs for k in ("neutral", "emotion")
             if "strength_spread" in p["phase_sensitivity"][k]]
    out = {"offsets": list(PHASE_OFFSETS), "n_scorings": len(clips),
           "n_clips": len({c["clip"] for c in clips})}
    for key in ("strength_spread", "feature_axis_spread"):
        v = [c[key] for c in clips]
        out[f"{key}_median"] = float(np.median(v)) if v else None
        out[f"{key}_max"] = float(np.max(v)) if v else None
    cyc = [p["phase_sensitivity"][k]["cycle_strength_spread"] for p in pairs
           for k in ("neutral", "emotion")
           if "cycle_strength_spread" in p["phase_sensitivity"][k]]
    out["cycle_strength_spread_n_scorings"] = len(cyc)
    out["cycle_strength_spread_median"] = float(np.median(cyc)) if cyc else None
    out["cycle_strength_spread_max"] = float(np.max(cyc)) if cyc else None
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
    axis = [m for m in scored if summary[m].get("axis_spearman") is not None]
    if axis:
        top = max(axis, key=lambda m: summary[m]["axis_spearman"])
        parts.append("along the feature axis, Spearman " + ", ".join(
            f"{m} {summary[m]['axis_spearman']:.2f}" for m in axis)
            + f" (highest: {top})")
    return "; ".join(parts) + "."


def headlines(summary: dict, phase: dict | None = None, dynamics: dict | None = None
              ) -> list[dict]:
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
            f"foot sliding ratio {s['mean_foot_sliding_ratio']:.2f}; feature axis: Spearman "
            f"{s['axis_spearman']:.2f}, monotone {s['axis_monotonicity']:.2f}, calibration "
            f"error {s['axis_calibration_error']:.2f}"))
    for m in METHODS:
        s = summary[m]
        if s["n_pairs"] and "cycle_strength_spearman" in s:
            rows.append(headline(
                f"{m}: cycle-averaged strength Spearman vs s", s["cycle_strength_spearman"],
                "", f">= {CRITERIA['spearman_min']}",
                s["cycle_strength_spearman"] >= CRITERIA["spearman_min"],
                f"calibration error {s['cycle_strength_calibration_error']:.2f}, monotone "
                f"{s['cycle_strength_monotonicity']:.2f}; ends "
                f"{s.get('cycle_strength_vertex_error', float('nan')):.2f} from the real "
                f"clips; all three criteria "
                f"{'met' if s['interpolates_emotion_cycle_strength'] else 'not met'}; mixed "
                f"outputs' joint speed {s.get('speed_vs_blend_mixed', float('nan')):.2f}x the "
                f"blend of the ends' (each pair's lowest, averaged: "
                f"{s.get('speed_vs_blend_min', float('nan')):.2f})"))
    if phase and phase.get("cycle_strength_spread_median") is not None:
        rows.append(headline(
            "real clips: cycle-averaged strength, first stride's window starts against the "
            "next stride's (median |difference|)", phase["cycle_strength_spread_median"], "",
            "", None, f"largest {phase['cycle_strength_spread_max']:.2f}; "
            f"{phase['cycle_strength_spread_n_scorings']} scorings"))
    if phase and phase.get("n_clips"):
        rows.append(headline(
            "real clips: spread of the normalised strength over windows started "
            f"{'/'.join(map(str, phase['offsets']))} frames in (median)",
            phase["strength_spread_median"], "", "", None,
            f"largest {phase['strength_spread_max']:.2f}; feature axis: median "
            f"{phase['feature_axis_spread_median']:.2f}, largest "
            f"{phase['feature_axis_spread_max']:.2f}; {phase['n_scorings']} scorings of "
            f"{phase['n_clips']} clips"))
    if dynamics:
        rows.append(headline(
            "hgpdm: one-step error of each emotion's dynamics on the other emotions' training "
            "trajectories (median, per step; no move: 1)",
            dynamics["other_error_per_step_median"], "", "", None,
            f"predicted RMS error {dynamics['other_predicted_rms_per_step_median']:.3f} per "
            f"step; error above 3x predicted in "
            f"{100 * dynamics['other_error_above_3x_predicted']:.0f}%; on its own trials "
            f"{dynamics['own_error_per_step_median']:.1e}; dynamics noise variance "
            f"{dynamics['noise_variance']:.1e}"))
    return rows


def markdown_table(result: dict) -> str:
    """The README's results table, rendered from a study result (``--table``)."""
    if "summary" not in result:
        return f"(study not run: {result.get('skipped', 'no summary')})"

    def f(v, fmt="{:.2f}"):
        return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else fmt.format(v)

    head = ("| method | pairs | Spearman(strength, s) | monotone steps | calibration error "
            "| Spearman(axis, s) | axis calibration error "
            "| gain 1 -> 1.25 | classifier p(target) at s = 1 | Spearman(p, s) | jerk / real "
            "| foot sliding / real | interpolates the emotion |")
    rows = [head, "|" + "---|" * 13]
    for m in result["methods"]:
        a = result["summary"][m]
        if not a.get("n_pairs"):
            rows.append(f"| {m} | 0 |" + " - |" * 11)
            continue
        rows.append(
            f"| {m} | {a['n_pairs']} | {f(a.get('strength_spearman'))} "
            f"| {f(a.get('strength_monotonicity'))} | {f(a.get('strength_calibration_error'))} "
            f"| {f(a.get('axis_spearman'))} | {f(a.get('axis_calibration_error'))} "
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
        return bandai_skip(base, root, out)
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
    phase = {**phase_summary(pairs), "window_frames": cfg.gen_frames}
    dynamics = dynamics_cross_prediction(model, train)
    result = {
        **base,
        "s_values": list(S_VALUES), "methods": list(METHODS), "criteria": CRITERIA,
        "data": {"root": str(root), "clips": [t.name for t in data],
                 "hgpdm_training": [t.name for t in train],
                 "hgpdm_frames": int(sum(t.n_frames for t in train))},
        "hgpdm_fit": {k: v for k, v in model.diagnostics.items() if k != "trace"},
        "hgpdm_dynamics": dynamics,
        "infer_emotion": (f"run at s in {list(cfg.infer_s)} and on the real clips"
                          if cfg.infer_s else "not run (infer_s is empty)"),
        "pairs": pairs, "summary": summary, "phase_sensitivity": phase,
        "conclusion": conclusion(summary), "headline": headlines(summary, phase, dynamics),
        "timing_s": {"hgpdm_fit": t_fit, "total": time.perf_counter() - t0},
        "status": "ok", "machine": machine_info(),
    }
    write_json(out, result)
    return result


def _same(a, b) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float | int | list) and isinstance(b, float | int | list):
        a, b = np.asarray(a, float), np.asarray(b, float)
        return a.shape == b.shape and bool(np.allclose(a, b, rtol=1e-12, atol=0, equal_nan=True))
    return a == b


def rescore(path: Path) -> dict:
    """Add the summaries a stored result lacks (e.g. :func:`infer_summary`'s) from its own
    per-pair outputs and rewrite it atomically, with ``rescored_utc``. Nothing measured is
    redone, and every summary the file already holds must come out the same from its outputs,
    or nothing is written (a SystemExit names the first difference)."""
    import json
    from datetime import UTC, datetime

    stored = json.loads(path.read_text())
    for pair in stored["pairs"]:
        for method, res in pair["methods"].items():
            new = summarise(res["outputs"], pair["emotion"])
            for k, v in res["summary"].items():
                if not _same(v, new.get(k)):
                    raise SystemExit(f"{path.name}: {pair['content']} {pair['emotion']} "
                                     f"{method} {k}: stored {v!r}, recomputed {new.get(k)!r}")
            res["summary"] = {**new, **res["summary"]}
    for method, agg in aggregate(stored["pairs"]).items():
        old = stored["summary"][method]
        for k, v in old.items():
            if not _same(v, agg.get(k)):
                raise SystemExit(f"{path.name}: summary {method} {k}: stored {v!r}, "
                                 f"recomputed {agg.get(k)!r}")
        stored["summary"][method] = {**agg, **old}
    stored["rescored_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
    write_json(path, stored)
    return stored


def result_name(cfg: Settings) -> str:
    """The default result file's name: the study's, with the H-GPDM's variant appended
    (``_learned_styles`` with ``--optimize-style``, ``_shared_latents`` with ``--init shared``,
    ``_phase_latents`` with ``--init phase``, ``_rest_frames`` with ``--rest-frames``,
    ``_periodic`` with ``--periodic``, ``_lookahead`` with ``--lookahead W > 0``;
    ``_synthesis_setup`` alone for :func:`synthesis_setup`'s settings; ``_nearest_dynamics``
    or ``_registered_dynamics`` last with ``--dynamics-style nearest`` or ``registered``)."""
    last = "" if cfg.dynamics_style == "requested" else f"_{cfg.dynamics_style}_dynamics"
    if synthesis_setup(cfg) == cfg:
        return (NAME + ("_learned_styles" if cfg.optimize_style else "")
                + ("_shared_latents" if cfg.latent_init == "shared" else "")
                + ("_phase_latents" if cfg.latent_init == "phase" else "")
                + "_synthesis_setup" + last)
    return (NAME + ("_learned_styles" if cfg.optimize_style else "")
            + ("_shared_latents" if cfg.latent_init == "shared" else "")
            + ("_phase_latents" if cfg.latent_init == "phase" else "")
            + ("_rest_frames" if cfg.rest_frames else "")
            + ("_periodic" if cfg.periodic else "")
            + ("_lookahead" if cfg.lookahead > 0 else "") + last)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one pair, few iterations")
    ap.add_argument("--root", default=None, help=f"Bandai folder (default {DATA_ROOT})")
    ap.add_argument("--out", default=None, help="JSON path (default results/<name>.json)")
    ap.add_argument("--max-iter", type=int, default=None, help="override the H-GPDM iterations")
    ap.add_argument("--optimize-style", action="store_true",
                    help="learn the emotions' style vectors in the H-GPDM fit")
    ap.add_argument("--init", choices=("pca", "shared", "phase"), default="pca",
                    help="the H-GPDM's latent initialisation (fit(init=...)); 'shared' starts "
                         "every emotion's trials in one region of the interaction latents, "
                         "'phase' on one gait-phase circle (gait_phase)")
    ap.add_argument("--rest-frames", action="store_true",
                    help="fit HGPDM(rest_frames=True, canonical_side=True): joint angles about "
                         "each joint's mean rotation, left/right walks on one side")
    ap.add_argument("--periodic", action="store_true",
                    help="fit HGPDM(periodic=True): each clip's end loops back to its phase")
    ap.add_argument("--lookahead", type=float, default=0.0,
                    help="roll the H-GPDM out with generate(lookahead=W)")
    ap.add_argument("--dynamics-style", choices=("requested", "nearest", "registered"),
                    default="requested",
                    help="roll the H-GPDM out with generate(dynamics_style=...): 'nearest' "
                         "runs the dynamics at the trained emotion nearest the coordinates "
                         "and blends only the mapping; 'registered' rolls out each emotion "
                         "at its own level and blends the time-registered paths")
    ap.add_argument("--synthesis-setup", action="store_true",
                    help="the synthesis benchmark's walk fit and rollouts (synthesis_setup: "
                         "whole clips at 10 fps, latent dimensions 6 / 6, rest frames, "
                         "periodic, look-ahead 10); replaces --rest-frames, --periodic and "
                         "--lookahead")
    ap.add_argument("--rescore", action="store_true",
                    help="no run: add the summaries a stored result (--out or the flags' "
                         "default file) lacks from its per-pair outputs (rescore)")
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
    if a.lookahead < 0:
        ap.error(f"--lookahead must be >= 0, got {a.lookahead}")
    cfg = replace(cfg, periodic=a.periodic, lookahead=a.lookahead, rest_frames=a.rest_frames,
                  dynamics_style=a.dynamics_style)
    if a.synthesis_setup:
        if a.lookahead not in (0.0, 10.0):
            ap.error(f"--synthesis-setup rolls out with look-ahead 10; --lookahead "
                     f"{a.lookahead:g} contradicts it")
        cfg = synthesis_setup(cfg)
    if a.rescore:
        path = Path(a.out) if a.out else RESULTS / f"{result_name(cfg)}.json"
        rescore(path)
        print(f"{path.name}: summaries added")
        return 0
    res = run(a.quick, a.root, a.out, cfg)
    print(res.get("skipped") or res["conclusion"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
