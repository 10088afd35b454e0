"""Emotion-style inference from observed motion: ``infer_emotion(model, clip)``.

One concept: the inference pipeline of one clip (encode, project, assess, sample the styles,
combine the level evidence), its stages kept together so that their order and what each
passes on are read in one place.

1. The clip is read (Trial, Motions, BVH paths, or model-space arrays), matched to the model's
   skeleton by joint names, resampled to the model's frame rate and encoded.
2. Projection: the latents X*, I* and the clip's style vectors are found jointly by MAP
   (L-BFGS) of the clip's predictive log-density (bayesmotion.emotion.density) with the model
   fixed. By default (``emotion_starts="vertices"``) one projection per emotion level with the
   emotion held at it, from the latents of the nearest frames of that level's training trials
   (``staged_start=True``: X* by the bottom layer alone, shared by the levels, then the
   level's I* with X* held); the level is chosen by its Laplace evidence
   (bayesmotion.emotion.projection), then its latents and the free emotion are refined
   together. With "nearest", one start from the latents of
   the nearest training frames and the style of most of them; "levels" adds one start per
   emotion level and keeps the best optimum. When the couple is inferred: one start per couple
   level, the best optimum kept. L-BFGS runs in coordinates scaled by the exact Hessian
   diagonal.
   Latent uncertainty: a diagonal Laplace approximation (exact diag H, coloured HVPs).
3. Style posterior: an ensemble sampler with emcee's differential-evolution move
   (bayesmotion.inference.ensemble, one compiled program; or emcee itself) samples the clip's
   emotion coordinates (and its couple style when not given) on the simplex, with the latents
   held at their MAP -- i.e. the conditional posterior
   p(s* | Y*, X*, I*) proportional to p(s*) p(X* | I*, s*) p(I* | s*) (interaction and dynamics
   predictive likelihoods). With a Posterior as ``model`` this is repeated for several posterior
   draws of the hyperparameters and the samples are pooled (a mixture over draws).
   With the latents fixed, the density is a low-degree polynomial in the styles; it is expanded
   once per clip (bayesmotion.emotion.density.style_expansion), so each walker step costs
   O(T P D) instead of O(T N^2).

Arrays are padded to frame buckets (four sizes per doubling,
:func:`bayesmotion.shapes.padded_length`) so
clips of many lengths share compiled functions.
"""

from __future__ import annotations

import time
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from bayesmotion._config import release_compiled_programs
from bayesmotion.emotion.clip import encode_clip
from bayesmotion.emotion.density import (
    expanded_log_density,
    expanded_log_likelihood,
    style_expansion,
    styles_from,
)
from bayesmotion.emotion.evidence import evidence_power, level_posterior
from bayesmotion.emotion.ood import (
    STATISTICS,
    OutOfDistributionWarning,
    UnseenStyleWarning,
    assess,
    clip_z2,
    in_distribution_weight,
    recording_distance,
    recording_reference,
    training_reference,
    worst_statistic,
)
from bayesmotion.emotion.projection import (
    START_JITTER,
    STATIC_ARGS,
    best_fit,
    diag_hessian,
    minimize_scaled,
    minimize_scaled_many,
    other_starts,
    project_levels,
    projection_starts,
    seen_predictor,
)
from bayesmotion.emotion.result import EmotionPosterior, pool_posteriors
from bayesmotion.errors import BayesmotionError, warn
from bayesmotion.inference.ensemble import run_de
from bayesmotion.inference.posterior import Posterior
from bayesmotion.inference.target import (
    capped_covariance,
    difference_hessian,
    draw_start,
    in_halves,
)
from bayesmotion.model.generate import style_coords
from bayesmotion.model.params import STYLE_PREFIX, simplex_to_style, style_to_simplex
from bayesmotion.model.predict import sparse_layers, style_vectors
from bayesmotion.shapes import padded_length
from bayesmotion.validate import (
    check_infer_args,
    check_infer_memory,
    check_pad_to,
    check_projection_starts,
)


@partial(jax.jit, static_argnames=STATIC_ARGS + ("free",))
def _expansion(latents, P, Ys, mask, fixed, conc, int_factors, dyn_factors, init_var, free):
    return style_expansion(P, latents, Ys, mask, fixed, dict(free), int_factors, dyn_factors,
                           init_var)


def _style_logp(x, E, conc, power, int_factors, dyn_factors, free):
    """log p of the clip at free styles ``x`` (sum K_f - 1,), latents fixed: O(T P D) through
    the style expansion (bayesmotion.emotion.density); the likelihood raised to ``power``."""
    params, start = {}, 0
    for f, K in free:
        params[STYLE_PREFIX + f] = x[start:start + K - 1]
        start += K - 1
    return expanded_log_density(E, params, conc, dict(free), int_factors, dyn_factors, power)


_STYLE_STATIC = ("int_factors", "dyn_factors", "free")
# infer_emotion's default L-BFGS iterations per projection (its max_iter docstring gives the
# measurements behind it)
PROJECTION_ITER = 400


@partial(jax.jit, static_argnames=_STYLE_STATIC)
def _style_logp_batch(flat, E, conc, power, int_factors, dyn_factors, free):
    return jax.vmap(lambda x: _style_logp(x, E, conc, power, int_factors, dyn_factors,
                                          free))(flat)


@partial(jax.jit, static_argnames=_STYLE_STATIC)
def _style_neg_vg(x, E, conc, power, int_factors, dyn_factors, free):
    f = lambda y: -_style_logp(y, E, conc, power, int_factors, dyn_factors, free)
    return jax.value_and_grad(f)(x)


@partial(jax.jit, static_argnames=_STYLE_STATIC)
def _loglik_at_coords(W, E, int_factors, dyn_factors, free):
    """(n,) untempered clip log-likelihood at emotion coordinates W (n, K), the simplex closed."""
    return jax.vmap(lambda w: expanded_log_likelihood(E, {"emotion": w}, dict(free), int_factors,
                                                      dyn_factors))(W)


def _given_styles(model, couple, styles) -> dict:
    """The style factors the caller fixed: ``styles`` plus the ``couple`` shortcut."""
    given = dict(styles or {})
    if couple is not None:
        if "couple" in given:
            raise BayesmotionError("give the couple either as couple= or in styles=, not both")
        given["couple"] = couple
    if "emotion" in given:
        raise BayesmotionError("the emotion is what infer_emotion infers; it cannot be given")
    unknown = [f for f in given if f not in model.spec.factors]
    if unknown:
        raise BayesmotionError(f"the model has no style factor {unknown}; its factors are "
                               f"{list(model.spec.factors)}")
    return given


def _style_setup(model, given: dict, prior):
    """Which factors are inferred, fixed vectors of the others, Dirichlet concentrations."""
    if "emotion" not in model.levels:
        raise BayesmotionError("the model has no 'emotion' style factor")
    fixed, conc, inferred = {}, {}, []
    for f in model.spec.factors:
        K = len(model.levels[f])
        if K == 1:  # a single level: the style is trivially [1] (a given value is still checked)
            fixed[f] = style_coords(model, f, given[f]) if f in given else np.ones(1)
        elif f == "emotion" or f not in given:
            inferred.append(f)
            c = np.ones(K) if (f != "emotion" or prior is None) else np.asarray(prior, float)
            if c.shape != (K,) or np.any(c <= 0):
                raise BayesmotionError(f"prior must be {K} positive Dirichlet concentrations "
                                       f"over {list(model.levels[f])}")
            conc[f] = c
        else:
            fixed[f] = style_coords(model, f, given[f])
    return fixed, conc, inferred


def unseen_levels(model, fixed: dict) -> dict[str, list[str]]:
    """Emotion levels no training trial had together with the given styles, with the layers
    (``"interaction"``, ``"dynamics"``) whose style cells they miss.

    Args:
        model: a fitted model.
        fixed: factor -> the given (K_f,) style coordinates over the levels; a factor left out
            is free and matches any level. A coordinate vector matches every level it puts
            weight on.

    With one-hot styles a layer's kernel is zero between different style cells, so a level
    whose cell (with the given styles) holds no training frame is predicted by that layer's
    GP prior (in the dynamics layer of ``dynamics_linear="stable"``, the default, around the
    autoregression all cells share): it is then
    judged by how well the prior explains the clip, against levels judged by fitted
    mappings. A clip of an action seen in training only under other
    emotions (``HGPDM(interaction_factors=("content", "emotion"))``, a held-out clip in
    leave-one-clip-out) meets exactly this.
    """
    E = np.asarray(model.data.onehot["emotion"]) > 0
    out: dict[str, list[str]] = {}
    for layer, factors in (("interaction", model.spec.interaction_factors),
                           ("dynamics", model.spec.dynamics_factors)):
        if "emotion" not in factors:
            continue
        match = np.ones(E.shape[0], dtype=bool)
        for f in factors:
            if f != "emotion" and f in fixed:
                match &= (np.asarray(model.data.onehot[f]) @ (np.asarray(fixed[f]) != 0)) > 0
        for k, level in enumerate(model.levels["emotion"]):
            if not np.any(match & E[:, k]):
                out.setdefault(level, []).append(layer)
    return out


def _unseen_message(model, unseen: dict, fixed: dict) -> str:
    """What the unseen-level warning says."""
    given = ", ".join(f"{f}={model.levels[f][int(np.argmax(v))]!r}"
                      if np.count_nonzero(v) == 1 else f"{f}={np.round(v, 3).tolist()}"
                      for f, v in fixed.items() if len(model.levels[f]) > 1)
    levels = ", ".join(f"{lv!r} ({' and '.join(ls)})" for lv, ls in unseen.items())
    factors = {f for f in (*model.spec.interaction_factors, *model.spec.dynamics_factors)
               if f != "emotion"}
    learned = any(STYLE_PREFIX + f in model.params for f in (*factors, "emotion"))
    shared = (" (around the shared autoregression in the dynamics)"
              if model.spec.dynamics_linear == "stable" else "")
    how = ("their predictions borrow from other cells only through the learned style vectors"
           if learned else f"with one-hot styles they are judged by the GP prior{shared}, so "
                           f"the levels the training data cover are favoured")
    E = np.asarray(model.data.onehot["emotion"]) > 0
    absent = [lv for k, lv in enumerate(model.levels["emotion"]) if not E[:, k].any()]
    others = sorted({f for f in fixed if f in factors and len(model.levels[f]) > 1})
    also = f" together with the given styles ({given})" if given else ""
    instead = (f" A model without the {' and '.join(others)} style factor (for a label that "
               f"sets the poses' baseline, such as an action: HGPDM(pose_space='affective', "
               f"relative_to=...)) compares every emotion on training data"
               if others and len(absent) < len(unseen) else "")
    if absent:
        instead += f" No training trial has emotion {', '.join(map(repr, absent))} at all."
    return (f"no training trial had emotion {levels}{also}: {how} "
            f"(EmotionPosterior.info['unseen_levels']).{instead}")


def infer_emotion(model, clip, *, frames=None, couple=None, styles=None, prior=None,
                  method: str = "ensemble", seed: int = 0, n_walkers: int = 64, n_steps: int = 150,
                  n_draws: int = 4, max_iter: int = PROJECTION_ITER,
                  latent_uncertainty: bool = True, likelihood_power: float = 1.0,
                  emotion_starts: str = "vertices", level_starts: int = 1,
                  start_jitter: float = START_JITTER,
                  effective_frames: float | None = None,
                  staged_start: bool = False, pad_to: int | None = None) -> EmotionPosterior:
    """Posterior over the emotion coordinates of an observed clip.

    Args:
        model: a FittedHGPDM, or a Posterior (the answer then pools ``n_draws`` draws).
        clip: a Trial, one or two Motions, BVH path(s), or model-space poses (T, D) / (A, T, D).
        frames: a slice or index array of frames to use (online inference: ``slice(0, k)``),
            counted after the clip is resampled to the model's frame rate.
        couple: the clip's couple (label or coordinates); inferred when None.
        styles: other style factors of the clip that are known, factor -> label or coordinates
            (e.g. ``{"content": "walk-left"}``); a factor neither given nor the emotion is
            inferred alongside it.
        prior: Dirichlet concentrations over the emotion levels (default flat, all ones).
        method: the style sampler, both with emcee's differential-evolution move:
            "ensemble" (the default: :func:`bayesmotion.inference.ensemble.run_de`, the whole
            run one compiled JAX program, no host round trip per step) or "emcee" (emcee's
            ``EnsembleSampler``, the log-density called from the host twice per step). The
            two sample the same distribution with different random numbers.
        seed: seeds the walkers.
        n_walkers: emcee walkers.
        n_steps: emcee steps. With a Posterior as ``model`` the steps are shared
            out: each of the ``n_draws`` draws runs ``n_steps // n_draws + 50`` steps (the 50
            covering each chain's burn-in), and their samples are pooled.
        max_iter: L-BFGS iterations of the projection (per start); a projection stops
            earlier where it converges. On 60-frame real walks the level answer settles late:
            inferred from the same fold models, the answer at 200 iterations matched the
            1000-iteration one in 9 of 16 held-out Bandai walks (50% right), at 400, the
            default, in all 16 (87.5%, a median 21.5 s per clip against 30.5 s at 1000;
            ``benchmarks/results/projection_budget.json``). The level projections of held-out
            17-frame handshakes converge within it (at most 318 iterations; 200 cut 10 of 32
            short; ``benchmarks/results/infer_speed.json``). ``info["level_iterations"]``
            says which stopped at the limit.
        latent_uncertainty: compute the diagonal Laplace sd of the latents.
        likelihood_power: eta in the tempered posterior p(s) p(clip | s)^eta over the styles
            (generalised Bayes). 1, the default, is the plain posterior. Below 1 widens it to
            allow for model misspecification: with many frames the plain posterior is often
            narrower than the distance from its mean to the true label. Choose eta from labelled
            data with :func:`bayesmotion.evaluation.calibration.calibrate_hpd_power`.
        emotion_starts: "vertices" (the default: one projection per level with the emotion
            held at that level; the level of largest Laplace evidence of the latents is
            chosen (bayesmotion.emotion.projection) and its latents and free emotion are refined
            together; about K + 1 projections plus K Hessians), "nearest" (one projection from
            the nearest training frames, about a third of the cost) or "levels" (that start
            plus one per emotion level, from the nearest frames of that level's training
            trials; the best optimum is kept; K + 1 times the projection's cost). A better
            joint optimum is not always the right label; "vertices" compares every level at
            its own optimum (24 of 24 held-out built-in handshakes right,
            ``benchmarks/results/handshake_inference.json``). On generated clips between two
            emotions (demo model, s in {0, .25, .5, .75, 1}) its mean absolute error in s is 0.027
            (neutral to happy) and 0.13 (sad to angry, s = 0.5 read as neutral), against
            0.027 and 0.47 with "nearest", which reads sad to angry from s = 0.5 on as happy
            (``benchmarks/results/infer_speed.json``, key ``modes.*.interpolation``). With
            "vertices" ``info`` holds ``level_log_evidence``, ``level_probabilities`` (the
            plain evidence's posterior; ``probabilities`` adds the recording effect and the
            out-of-distribution shrinkage) and the Laplace details per level.
        level_starts: projections per emotion level (``emotion_starts="vertices"``): one
            from the level's start (``staged_start``) and ``level_starts`` - 1 from copies of it
            jittered by ``start_jitter`` (> 0 when ``level_starts`` > 1); each level keeps
            its best optimum (by density, never by label), and ``info``'s ``level_laplace``
            holds every start's objective and evidence. Each start adds a projection and a
            Hessian per level.
        start_jitter: sd of the N(0, sd^2) jitter added to every latent coordinate of each
            jittered level projection's start (``emotion_starts="vertices"``; with one start
            per level, that start), seeded by ``seed`` and the level. 0, the default, starts
            exactly at the level's start.
            The clip density is multimodal in the latents: on 16 held-out Bandai walks one
            level's evidence moved by a median 163 nats between starts
            (``benchmarks/results/projection_starts.json``). The full walk benchmark read 13
            of 16 right from one start per level, unjittered or jittered by 0.02
            (``bandai_inference.json``, ``bandai_inference_jittered.json``), and 15 of 16 with
            ``level_starts=3, start_jitter=0.02`` (``bandai_inference_starts3.json``, at
            about three times the projection cost); recommended for real recordings. On
            generated handshakes between sad and angry one jittered start read s = 0.75 as
            neutral (mean absolute error 0.20 against 0.13 unjittered, which reads s = 0.5 as
            neutral), three starts gave the unjittered answers (``infer_speed.json``).
        effective_frames: n_eff, how many of the clip's frames count as independent evidence
            for its label (:mod:`bayesmotion.emotion.evidence`): the label probabilities
            raise the levels' evidence to the power n_eff / (n_eff + T)
            (``emotion_starts="vertices"``). None: the model's calibrated value
            (``model.calibration["effective_frames"]``, set by
            :func:`bayesmotion.emotion.evidence.calibrate_evidence`), else infinity -- the plain
            evidence, whose probabilities are overconfident on recordings unlike the training ones
            (``info["evidence_calibrated"]`` says which).
        staged_start: start each level's projection (``emotion_starts="vertices"``) in two
            stages, X* by the bottom layer alone and then I* with X* held
            (:func:`bayesmotion.emotion.projection.project_levels`), instead of at the nearest
            training frames' latents (the default). ``benchmarks/projection_starts.py``
            compares the two on the same folds (``single_start``).
        pad_to: pad the clip's frames as a clip of ``pad_to`` frames would be padded
            (:func:`bayesmotion.shapes.padded_length`; at least the clip's frames after
            ``frames``; a longer clip is refused). Each padded length compiles its programs
            once per process: on this 2-core CPU a fresh process's first inference with a
            demo-size model took 19.8 s, the next 1.4 s
            (``benchmarks/results/compile_cache.json``). Growing prefixes of one stream
            (``frames=slice(0, k)``) given the stream's final length share one compilation, at
            the cost of every prefix computing over the padded frames (:func:`infer_online`
            and :func:`bayesmotion.evaluation.evaluate.online_sharpening` pad to the whole
            clip). The padded frames are masked out of the density; the answer equals the
            unpadded one up to the projection's optimisation tolerance. None: the clip's own
            length.
    Returns:
        EmotionPosterior. ``info["unseen_levels"]`` lists the emotion levels no training trial
        had together with the given styles (:func:`unseen_levels`); they also raise an
        :class:`~bayesmotion.emotion.ood.UnseenStyleWarning`.
    """
    check_infer_args(seed, n_walkers, n_steps, n_draws, couple, styles, prior)
    release_compiled_programs()  # clips of new lengths compile anew: keep the maps bounded
    fitted = model.model if isinstance(model, Posterior) else model
    check_pad_to(pad_to)
    check_infer_memory(clip, fitted.fps, fitted.predictor_rows, fitted.n_actors + 2,
                       n_walkers, n_steps, pad_to)
    check_projection_starts(emotion_starts, level_starts, start_jitter)
    if method not in ("ensemble", "emcee"):
        raise BayesmotionError(f"method must be 'ensemble' or 'emcee', got {method!r}")
    if not isinstance(staged_start, bool | np.bool_):
        raise BayesmotionError(f"staged_start must be True or False, got {staged_start!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or max_iter < 1:
        raise BayesmotionError(f"max_iter (L-BFGS iterations of the projection) must be a "
                               f"positive integer, got {max_iter!r}")
    if not (isinstance(likelihood_power, int | float | np.floating | np.integer)
            and not isinstance(likelihood_power, bool)
            and np.isfinite(likelihood_power) and likelihood_power > 0):
        raise BayesmotionError(f"likelihood_power must be a positive finite number, got "
                               f"{likelihood_power!r}")
    styles, group = _relative_group(fitted, styles)
    given = _given_styles(fitted, couple, styles)
    n_eff = _resolve_effective_frames(fitted, effective_frames)
    if isinstance(model, Posterior):
        idx = np.linspace(0, model.n_draws - 1, min(n_draws, model.n_draws)).astype(int)
        parts = [_infer_one(model.model, model.predictor(int(i)), clip, frames, given, prior,
                            seed + k, n_walkers, n_steps // max(1, len(idx)) + 50, max_iter,
                            latent_uncertainty and k == 0, likelihood_power, emotion_starts,
                            n_eff, int(level_starts), float(start_jitter), method,
                            staged_start, pad_to, group)
                 for k, i in enumerate(idx)]
        return pool_posteriors(parts)
    return _infer_one(model, model.predictor(), clip, frames, given, prior, seed, n_walkers,
                      n_steps, max_iter, latent_uncertainty, likelihood_power, emotion_starts,
                      n_eff, int(level_starts), float(start_jitter), method, staged_start,
                      pad_to, group)


def _relative_group(model, styles):
    """(styles without the label the poses are read relative to, that label or None): a model
    fitted with ``relative_to`` takes the clip's group from ``styles`` when it is there, else
    from the trial's labels (the label is never a style factor: ``HGPDM.resolved``)."""
    rel = model.spec.relative_to
    if rel is None or not styles or rel not in styles:
        return styles, None
    group = styles[rel]
    if not isinstance(group, str):
        raise BayesmotionError(f"styles[{rel!r}] must be the clip's {rel!r} label (one of "
                               f"{list(model.codecs[0].groups)}), got {group!r}: the model "
                               f"reads poses relative to their {rel!r}")
    return {k: v for k, v in styles.items() if k != rel}, group


def _resolve_effective_frames(model, effective_frames) -> tuple[float, bool]:
    """(n_eff, calibrated): the given value, else the model's calibrated one, else infinity."""
    if effective_frames is None:
        cal = getattr(model, "calibration", None) or {}
        if "effective_frames" in cal:
            return float(cal["effective_frames"]), True
        return float("inf"), False
    if isinstance(effective_frames, bool) or not isinstance(
            effective_frames, int | float | np.floating | np.integer) or not effective_frames > 0:
        raise BayesmotionError(f"effective_frames must be a number > 0 (inf: the plain "
                               f"evidence), got {effective_frames!r}")
    return float(effective_frames), False


def _infer_one(model, P, clip, frames, given, prior, seed, n_walkers, n_steps, max_iter,
               latent_uncertainty, likelihood_power=1.0, emotion_starts="vertices",
               n_eff=(float("inf"), False), level_starts=1, start_jitter=START_JITTER,
               method="ensemble", staged_start=False, pad_to=None, group=None):
    import emcee

    t0 = time.perf_counter()
    stages, last = {}, [t0]

    def stage(name):  # wall seconds per step, in info["stage_seconds"]
        now = time.perf_counter()
        stages[name] = now - last[0]
        last[0] = now

    Ys, mirrored, group = encode_clip(model, clip, group)
    if frames is not None:
        ok = isinstance(frames, slice)
        if not ok and not isinstance(frames, int | np.integer | str):
            idx = np.asarray(frames)
            ok = idx.ndim == 1 and idx.dtype.kind in "iu"
        if not ok:
            raise BayesmotionError(f"frames must be a slice or a 1-D integer index array of the "
                                   f"clip's frames (counted at the model's {model.fps:g} fps), "
                                   f"got {frames!r}")
        Ys = [Y[frames] for Y in Ys]
    T = Ys[0].shape[0]
    o = model.spec.order
    if T <= o:
        raise BayesmotionError(f"the clip needs more than {o} frames, got {T}")
    if pad_to is not None and pad_to < T:
        raise BayesmotionError(f"pad_to ({pad_to}) must be at least the clip's {T} frames")
    B = padded_length(T if pad_to is None else int(pad_to))
    mask = jnp.asarray(np.arange(B) < T)
    Yp = tuple(jnp.asarray(np.concatenate([Y, np.zeros((B - T, Y.shape[1]))])) for Y in Ys)
    fixed, conc, inferred = _style_setup(model, given, prior)
    unseen, fixed_coords = unseen_levels(model, fixed), dict(fixed)
    # given coordinates -> the kernels' style vectors (learned ones when the fit learned them)
    fixed = dict(zip(fixed, style_vectors(P, list(fixed), list(fixed.values())), strict=True))
    statics = {"int_factors": tuple(model.spec.interaction_factors),
               "dyn_factors": tuple(model.spec.dynamics_factors),
               "init_var": float(model.spec.priors.init_var)}
    fixed_j = {k: jnp.asarray(v) for k, v in fixed.items()}
    conc_j = {k: jnp.asarray(v) for k, v in conc.items()}
    # the given styles' cells alone (exact): a built-in handshake with its couple given sees 4
    # of the 8 cells of the interaction and dynamics layers
    P_seen = seen_predictor(P, fixed_j, statics["int_factors"], statics["dyn_factors"])
    args = (P_seen, Yp, mask, fixed_j, conc_j)
    stage("encode")
    levels_info = {}
    if emotion_starts == "vertices":
        params, res, fits, levels_info = _vertex_choice(model, P, Ys, B, T, args, statics,
                                                       max_iter, inferred, conc, level_starts,
                                                       seed, start_jitter, staged_start)
        # the chosen level's latents and the free styles together, from just inside its vertex:
        # the clip's emotion may lie between levels (an interpolated clip: mean absolute error
        # 0.046 over s in {0, .25, .5, .75, 1} on generated handshakes, infer_speed.json)
        params, res = minimize_scaled(params, args, statics, max_iter)
    else:
        starts = projection_starts(model, Ys, B, inferred, conc, emotion_starts)
        jobs = [[(q, args) for q in other_starts(p, inferred, conc)] for p in starts]
        flat = minimize_scaled_many([j for js in jobs for j in js], statics, max_iter)
        fits, at = [], 0
        for js in jobs:  # each start's best over its other-style starts
            fits.append(best_fit(flat[at:at + len(js)]))
            at += len(js)
        params, res = min(fits, key=lambda pr: pr[1].fun)
    stage("project")
    latents = {"X": params["X"], "I": params["I"]}
    ood = _distance_from_training(model, P, params, fixed_j, Ys, T)
    if group is not None and not model.codecs[0].knows(group):
        ood["unknown_group"] = {"label": model.spec.relative_to, "group": group,
                                "training_groups": list(model.codecs[0].groups)}
        ood["out_of_distribution"] = True
    stage("ood")
    sd = {}
    if latent_uncertainty:
        diag = diag_hessian(params, args, statics)  # exact, from coloured HVPs
        sd = {f"{k}_sd": np.asarray(1.0 / jnp.sqrt(jnp.maximum(diag[k], 1e-12)))[..., :T, :]
              for k in ("X", "I")}
    stage("latent_sd")
    free = tuple((f, len(model.levels[f])) for f in sorted(inferred))
    keys = tuple((STYLE_PREFIX + f, K - 1) for f, K in free)
    E = _expansion(latents, *args, **statics, free=free)
    x0 = np.concatenate([np.asarray(params[k]) for k, _ in keys])
    ndim = x0.size
    W = max(n_walkers, 2 * ndim + 2)
    W += W % 2
    sty = (E, conc_j, jnp.asarray(float(likelihood_power)), statics["int_factors"],
           statics["dyn_factors"], free)
    if emotion_starts == "vertices":  # the styles' mode at the chosen level's latents
        x0 = _style_mode(x0, sty)

    def log_prob(xs):  # in emcee's half-ensemble chunks: one compilation
        return in_halves(lambda x: _style_logp_batch(x, *sty), xs, W)

    # Laplace start; variances capped at 1 in stick-breaking units (beyond that the style is
    # barely identified and the quadratic approximation means little). The Hessian by
    # differences of the gradient the style mode compiled (a non-finite entry counts as no
    # curvature, so the cap).
    H = difference_hessian(lambda x: _style_neg_vg(jnp.asarray(x), *sty)[1], x0)
    cov = capped_covariance(np.where(np.isfinite(H), H, 0.0), 1.0)
    p0 = draw_start(lambda x: _style_logp_batch(x, *sty), x0, cov, W,
                    np.random.default_rng(seed))
    stage("expand")

    # differential-evolution moves from a Laplace start: autocorrelation ~7 steps here, against
    # ~20 for the default stretch move from a ball (measured on the demo's held-out trials)
    if method == "ensemble":  # the same move, the whole run one compiled program
        run = run_de(_style_logp_batch, sty[:3], p0, n_steps, seed,
                     static=tuple(zip(_STYLE_STATIC, sty[3:], strict=True)))
        burn = n_steps // 3
        chain, lp = np.asarray(run.chain)[burn:], np.asarray(run.log_prob)[burn:]
        acceptance = float(np.mean(np.asarray(run.accepted))) / n_steps
    else:
        sampler = emcee.EnsembleSampler(W, ndim, log_prob, vectorize=True,
                                        moves=emcee.moves.DEMove())
        state = emcee.State(p0, random_state=np.random.RandomState(seed).get_state())
        sampler.run_mcmc(state, n_steps, progress=False)
        burn = n_steps // 3
        chain = sampler.get_chain(discard=burn)  # (steps, W, ndim)
        lp = sampler.get_log_prob(discard=burn)
        acceptance = float(np.mean(sampler.acceptance_fraction))
    with np.errstate(invalid="ignore", divide="ignore"):  # a coordinate no walker moved
        tau = np.asarray(emcee.autocorr.integrated_time(chain, tol=0), dtype=float)
    tau[~np.isfinite(tau)] = np.inf  # it holds no effective sample
    styles = {}
    start = 0
    for k, n in keys:
        u = chain[..., start:start + n]
        s = np.asarray(style_to_simplex(jnp.asarray(u.reshape(-1, n))))
        styles[k[len(STYLE_PREFIX):]] = np.swapaxes(s.reshape(*u.shape[:2], n + 1), 0, 1)
        start += n
    stage("sample")
    info = {"n_frames": T, "padded_frames": B, "mirrored": mirrored,
            "seconds": time.perf_counter() - t0, "stage_seconds": stages,
            "tau": tau, "likelihood_power": float(likelihood_power),
            "acceptance": acceptance, "sampler": method,
            "map_objective": float(res.fun), "map_iterations": int(res.nit),
            "emotion_starts": emotion_starts, "level_starts": level_starts,
            "start_jitter": start_jitter, "staged_start": bool(staged_start), **levels_info,
            "start_objectives": [float(r.fun) for _, r in fits],
            "unseen_levels": unseen,
            "n_samples": int(chain.shape[0] * chain.shape[1]),
            "ess": float(chain.shape[0] * chain.shape[1] / np.max(tau))}
    lat = {"X": np.asarray(latents["X"])[:, :T], "I": np.asarray(latents["I"])[:T], **sd}
    cl = "couple" in styles
    loglik = None
    if [f for f, _ in free] == ["emotion"]:  # the density over the emotion alone is exact
        lsty = (E, statics["int_factors"], statics["dyn_factors"], free)
        loglik = lambda W: np.asarray(_loglik_at_coords(jnp.asarray(W), *lsty))
    info["ood"] = ood
    info["effective_frames"], info["evidence_calibrated"] = n_eff
    label_p = None
    if emotion_starts == "vertices":
        prior_k = _largest_prior(conc["emotion"])
        eta = evidence_power(T, n_eff[0])
        p_in = level_posterior(levels_info["level_log_evidence"], np.log(prior_k), eta)
        w = in_distribution_weight(ood)
        label_p = w * p_in + (1.0 - w) * prior_k
        info.update(evidence_power=eta, probabilities_in_distribution=p_in.tolist(),
                    in_distribution_weight=w, level_prior=prior_k.tolist())
    stage("levels")
    info["seconds"] = time.perf_counter() - t0
    if ood["out_of_distribution"]:
        warn(_ood_message(ood, info.get("in_distribution_weight")), OutOfDistributionWarning)
    if unseen:
        warn(_unseen_message(model, unseen, fixed_coords), UnseenStyleWarning)
    return EmotionPosterior(tuple(model.levels["emotion"]), styles["emotion"], lat,
                            np.swapaxes(lp, 0, 1),
                            tuple(model.levels["couple"]) if cl else None,
                            styles.get("couple"), info, loglik, np.asarray(conc["emotion"]),
                            out_of_distribution=bool(ood["out_of_distribution"]),
                            label_probabilities=label_p)


def _ood_message(ood: dict, weight) -> str:
    """What the out-of-distribution warning says: the statistic that tripped it first."""
    frames = [n for n in STATISTICS if n in ood and ood[n]["median"] > ood[n]["threshold"]]
    if "unknown_group" in ood:
        u = ood["unknown_group"]
        why = (f"its {u['label']} {u['group']!r} is none of the training trials' "
               f"{u['training_groups']}, so the poses have no reference of their own and were "
               f"read relative to the mean over all training frames")
    elif frames:
        worst = worst_statistic({n: ood[n] for n in frames})
        what = (f"negative log predictive density per output of the {worst[:-8]} layer"
                if worst.endswith("_density") else f"standardised {worst}-layer residual")
        why = (f"its median frame's {what} is {ood[worst]['median']:.3g}, above the "
               f"{ood[worst]['threshold']:.3g} that 99% of held-out training frames stay under")
    else:
        rec = ood["recording"]
        why = (f"as a recording it is {rec['ratio']:.2f} times as far from its nearest training "
               f"recording as the most isolated training recording is from the others")
    then = ("its emotion probabilities are the model's nearest explanation, not evidence"
            if weight is None else f"its emotion probabilities are shrunk towards the prior "
                                   f"(weight {weight:.2f} on the evidence)")
    return (f"the clip lies outside the training data: {why} (EmotionPosterior.info['ood']); "
            f"{then}")


def _distance_from_training(model, P, params, fixed, Ys, T) -> dict:
    """:func:`bayesmotion.emotion.ood.assess` of the projected clip; the training reference is
    cached with a fitted model's own predictor."""
    if P is model.predictor() or model.spec.inducing is not None:
        # a sparse model's reference needs its training rows, which its predictors (inducing
        # inputs only) do not hold: its MAP's reference serves every draw
        if "ood_reference" not in model._cache:
            sparse = (None if model.spec.inducing is None else sparse_layers(
                model.spec, model.data, {k: jnp.asarray(v) for k, v in model.params.items()},
                model.diagnostics.get("jitter", 1e-8)))
            model._cache["ood_reference"] = training_reference(
                model.predictor(), model.data.trial_of_frame, model.spec.order, sparse,
                model.data.loops)
        reference = model._cache["ood_reference"]
    else:  # a posterior draw's predictor
        reference = training_reference(P, model.data.trial_of_frame, model.spec.order,
                                       loops=model.data.loops)
    dyn = styles_from(params, fixed, tuple(model.spec.dynamics_factors), P.level_vectors)
    z2 = clip_z2(P, np.asarray(params["X"])[:, :T], np.asarray(params["I"])[:T], Ys, dyn)
    # a clip shorter than the typical training recording is compared with stretches of its
    # own length
    window = T if T < np.median(model.data.lengths) else None
    key = ("recording_reference", window)
    if key not in model._cache:
        model._cache[key] = recording_reference(model.data.Y, model.data.trial_of_frame, window)
    ref = model._cache[key]
    return assess(reference, z2, None if ref is None else recording_distance(ref, Ys))


def _vertex_choice(model, P, Ys, B, T, args, statics, max_iter, inferred, conc,
                   n_starts=1, seed=0, jitter=START_JITTER, staged=False):
    """The emotion level with the largest posterior probability under the Laplace evidence of
    each level (bayesmotion.emotion.projection.project_levels) and the prior probability that the
    level
    is the largest coordinate; its projection, with the free emotion set just inside its
    vertex (the style sampler starts from the styles' mode at these latents)."""
    out = project_levels(model, P, Ys, B, T, args, statics, max_iter, inferred, conc,
                         n_starts, seed, jitter, staged)
    log_ev = np.array([o[2] for o in out])
    logp = log_ev + np.log(_largest_prior(conc["emotion"]))
    prob = np.exp(logp - logp.max())
    k = int(np.argmax(logp))
    K = log_ev.size
    v = np.full(K, 0.03 / max(K - 1, 1))
    v[k] = 0.97
    params = {**out[k][0], STYLE_PREFIX + "emotion": simplex_to_style(jnp.asarray(v)[None])[0]}
    info = {"level_log_evidence": log_ev.tolist(),
            "level_probabilities": (prob / prob.sum()).tolist(),
            "level_objectives": [float(o[1].fun) for o in out],
            "level_iterations": [int(o[1].nit) for o in out],
            "level_laplace": [o[3] for o in out]}
    return params, out[k][1], [(o[0], o[1]) for o in out], info


def _largest_prior(conc, n: int = 20000) -> np.ndarray:
    """(K,) prior probability under Dirichlet(conc) that each coordinate is the largest (1/K
    each for a symmetric prior; else a seeded Monte-Carlo estimate, floored at 1/n)."""
    conc = np.asarray(conc, dtype=np.float64)
    K = conc.size
    if np.all(conc == conc[0]):
        return np.full(K, 1.0 / K)
    draws = np.random.default_rng(0).dirichlet(conc, n)
    p = np.bincount(np.argmax(draws, 1), minlength=K) / n
    return np.maximum(p, 1.0 / n) / np.maximum(p, 1.0 / n).sum()


def _style_mode(x0, sty) -> np.ndarray:
    """The mode of the free styles' log-density (expansion ``sty``, latents fixed) by L-BFGS
    from ``x0``; ``x0`` itself if that fails to improve on it."""
    def f(x):
        v, g = _style_neg_vg(jnp.asarray(x), *sty)
        return float(v), np.asarray(g, np.float64)

    v0 = f(x0)[0]
    res = scipy.optimize.minimize(f, np.asarray(x0, float), jac=True, method="L-BFGS-B",
                                  options={"maxiter": 200})
    return res.x if np.isfinite(res.fun) and res.fun <= v0 else np.asarray(x0, float)


def infer_online(model, clip, *, start: int | None = None, step: int = 5, **kwargs):
    """Yield an EmotionPosterior for growing prefixes of the clip (frames arriving online):
    the first ``start`` frames (default order + 3), then ``step`` more at a time, frames counted
    at the model's frame rate (the clip is resampled to it first). Every prefix is padded as
    the whole clip is (``pad_to``, unless given in ``kwargs``), so the prefixes share one
    compilation; ``kwargs`` are :func:`infer_emotion`'s."""
    if int(step) != step or step < 1:
        raise BayesmotionError(f"step must be a positive number of frames, got {step!r}")
    fitted = model.model if isinstance(model, Posterior) else model
    styles = kwargs.get("styles")
    if styles is not None and not isinstance(styles, dict):
        raise BayesmotionError(f"styles must be a dict factor -> label or coordinates, got "
                               f"{type(styles).__name__}")
    n = encode_clip(fitted, clip, _relative_group(fitted, styles)[1])[0][0].shape[0]
    k = start or (fitted.spec.order + 3)
    kwargs.setdefault("pad_to", n)  # every prefix one compilation (infer_emotion's pad_to)
    while True:
        k = min(k, n)
        yield infer_emotion(model, clip, frames=slice(0, k), **kwargs)
        if k == n:
            return
        k += step
