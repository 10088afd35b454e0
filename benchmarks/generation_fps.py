"""Generated frames per second, with and without predictive variance, and where the time goes.

Models: the built-in handshakes (24 trials, N = 816 training frames) and, in the full run,
the same with 4 repetitions (32 trials, N = 1088, the ~1000-frame size). Generation cost does
not depend on how far the MAP fit went, so the models are fitted with a few L-BFGS iterations
only (said in the JSON).

Timed after warm-up (median of repeats), each producing ``n_frames`` frames of both actors:

* ``generate_public``: ``fitted.generate(emotion=..., n_frames=T, n_samples=0)`` -- mean rollout
  with the one-step variance carried to latent, pose, angle and joint-position space; the
  conditioned layers (Cholesky of the training kernels) are cached on the model by its first
  call, as for any user;
* ``generate_with_conditioning``: the same with the conditioned layers dropped before each call
  (what the first call on a freshly loaded model costs, compilation excluded: the jitted
  conditioning function stays cached);
* ``generate_public_16_samples``: ``n_samples=16`` (frames/s counted per mean frame and per
  generated frame, 17 T);
* ``mean_only``: dynamics mean rollout + top-down mean mapping + decoding + FK, no variance
  at any layer (Taubert et al.'s mean prediction);
* ``dynamics_rollout_core``: the jitted ``lax.scan`` core alone (latent frames), mean and 16
  vmapped sampled rollouts;
* the rows below ``generate_*`` use the predictor as ``generate`` does:
  restricted to the style cells the rollout's styles see (``restrict_to_styles``, exact; one
  of the 8 built-in cells for a rollout at one emotion);
* a profile of the public call's parts: conditioning, dynamics rollout, top-down mapping,
  decoding to channels, FK, positions with their variance (analytic FK Jacobian).
"""

from __future__ import annotations

import time

import numpy as np

TARGET_FPS = 10_000.0
REALTIME_FPS = 120.0


MODELS_FULL = {"builtin": {}, "n_repetitions_4": {"n_repetitions": 4}}
MODELS_QUICK = {"builtin": {}}


def fit_model(max_iter: int, **dataset_kwargs):
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.model.spec import HGPDM

    ds = load_handshakes(**dataset_kwargs)
    return HGPDM().fit(ds, max_iter=max_iter, progress=False)


def _inputs(model, T: int, emotion: str = "happy"):
    import jax.numpy as jnp

    from bayesmotion.model.generate import _start_trial, resolve_style
    from bayesmotion.model.predict import style_vectors

    values = {"emotion": emotion, "couple": model.levels["couple"][0]}
    coords = {f: resolve_style(model, f, values[f], T) for f in model.spec.factors}
    o = model.spec.order
    r = _start_trial(model, coords, None)
    I0 = jnp.asarray(model.latents(r)["I"][:o])
    P = model.predictor()
    dyn_f, int_f = model.spec.dynamics_factors, model.spec.interaction_factors
    dyn_s = tuple(style_vectors(P, dyn_f, [coords[f][o:] for f in dyn_f]))
    int_s = tuple(style_vectors(P, int_f, [coords[f] for f in int_f]))
    return r, I0, dyn_s, int_s


def profile_parts(model, P, T: int, repeats: int) -> dict:
    """Seconds of each stage of one ``generate(n_samples=0)`` call."""
    import jax
    import jax.numpy as jnp
    from _common import block, timeit

    from bayesmotion.model.generate import (
        _positions,
        _positions_with_var,
        decode_actor,
        dynamics_rollout,
        map_down,
    )
    from bayesmotion.model.predict import condition

    r, I0, dyn_s, int_s = _inputs(model, T)
    o, A = model.spec.order, model.n_actors
    key = jax.random.PRNGKey(0)
    I_gen, _ = dynamics_rollout(P, I0, dyn_s, key, T - o, False)
    I = jnp.concatenate([I0, I_gen])
    outs, _ = map_down(P, I, int_s, A)
    Y = [np.asarray(l[1]) for l in outs]
    Yv = [np.asarray(l[2]) for l in outs]
    dec = [decode_actor(model, a, Y[a], Yv[a], r) for a in range(A)]

    def fk_only():
        for v, _, sk, _ in dec:
            _positions(sk, v)

    stages = {
        "condition (Cholesky of all training kernels)": lambda: block(condition(model)),
        "dynamics_rollout (lax.scan, mean + one-step var)":
            lambda: block(dynamics_rollout(P, I0, dyn_s, key, T - o, False)),
        "map_down (interaction + bottom mean/var)": lambda: block(map_down(P, I, int_s, A)),
        "decode Y -> channels (NumPy)":
            lambda: [decode_actor(model, a, Y[a], Yv[a], r) for a in range(A)],
        "forward kinematics": fk_only,
        "positions + variance (analytic FK Jacobian)":
            lambda: [_positions_with_var(sk, v, var) for _, _, _, (v, var, sk) in dec],
    }
    return {name: timeit(fn, repeats=repeats, warmup=1)["median_s"]
            for name, fn in stages.items()}


def measure_model(model, T: int, repeats: int) -> dict:
    import jax
    from _common import block, timeit

    from bayesmotion.model.generate import _map_and_decode, dynamics_rollout, generate
    from bayesmotion.model.predict import condition, restrict_to_styles

    P = block(condition(model))
    r, I0, dyn_s, int_s = _inputs(model, T)
    # what generate() runs on: the predictor without the style cells the rollout cannot see
    P = block(restrict_to_styles(P, dyn_s, int_s))
    o = model.spec.order
    key = jax.random.PRNGKey(0)
    keys = jax.random.split(key, 16)
    sampled = jax.jit(jax.vmap(lambda k: dynamics_rollout(P, I0, dyn_s, k, T - o, True)[0]))

    def mean_only():
        I_gen, _ = dynamics_rollout(P, I0, dyn_s, key, T - o, False, with_var=False)
        I = jax.numpy.concatenate([I0, I_gen])
        return _map_and_decode(model, P, I, int_s, r, with_var=False)

    cases = {
        "generate_public": (lambda: model.generate(emotion="happy", n_frames=T), T),
        "generate_with_conditioning":
            (lambda: (model._cache.pop("predictor", None),
                      generate(model, "happy", None, T, 0)), T),
        "generate_public_16_samples":
            (lambda: model.generate(emotion="happy", n_frames=T, n_samples=16), T),
        "mean_only": (mean_only, T),
        "dynamics_rollout_core_mean":
            (lambda: block(dynamics_rollout(P, I0, dyn_s, key, T - o, False)), T - o),
        "dynamics_rollout_core_16_samples": (lambda: block(sampled(keys)), 16 * (T - o)),
    }
    out = {}
    for name, (fn, frames) in cases.items():
        t = timeit(fn, repeats=repeats, warmup=1)
        out[name] = {"median_s": t["median_s"], "frames": frames,
                     "frames_per_s": frames / t["median_s"], "times_s": t["times_s"]}
    s16 = out["generate_public_16_samples"]
    s16["generated_frames_incl_samples"] = 17 * T
    s16["generated_frames_per_s_incl_samples"] = 17 * T / s16["median_s"]
    prof = profile_parts(model, P, T, repeats)
    total = out["generate_public"]["median_s"]
    out["profile_s"] = prof
    out["profile_fraction_of_generate_public"] = {k: v / total for k, v in prof.items()
                                                  if "_positions_with_var" not in k}
    return out


def run(quick: bool) -> dict:
    from _common import headline

    T = 200 if quick else 500
    repeats = 2 if quick else 7
    max_iter = 3 if quick else 30
    results, rows = {}, []
    models = MODELS_QUICK if quick else MODELS_FULL
    for label, kwargs in models.items():
        t0 = time.perf_counter()
        model = fit_model(max_iter, **kwargs)
        fit_s = time.perf_counter() - t0
        N = int(model.data.lengths.sum())
        res = measure_model(model, T, repeats)
        res["training_frames_N"] = N
        res["fit_seconds_max_iter"] = [fit_s, max_iter]
        results[label] = res
        pub = res["generate_public"]["frames_per_s"]
        prof = res["profile_fraction_of_generate_public"]
        top = max((k for k in prof if not k.startswith("condition")), key=prof.get)
        rows += [
            headline(f"generate with variance, N={N}, {T} frames", pub,
                     "frames/s", f">= {TARGET_FPS:,.0f}", pub >= TARGET_FPS,
                     f"largest part: {top} {prof[top]:.0%}"),
            headline("  same, incl. conditioning (first call on a model)",
                     res["generate_with_conditioning"]["frames_per_s"], "frames/s"),
            headline("  n_samples=16 (mean frames/s)",
                     res["generate_public_16_samples"]["frames_per_s"], "frames/s",
                     f">= {REALTIME_FPS:g} (real time)",
                     res["generate_public_16_samples"]["frames_per_s"] >= REALTIME_FPS),
            headline("  mean only, no variance", res["mean_only"]["frames_per_s"], "frames/s"),
            headline("  dynamics_rollout core (mean)",
                     res["dynamics_rollout_core_mean"]["frames_per_s"], "frames/s"),
        ]
    return {
        "settings": {"n_frames": T, "repeats": repeats, "fit_max_iter": max_iter,
                     "models": {k: f"load_handshakes(**{v})" for k, v in models.items()},
                     "emotion": "happy", "quick": quick,
                     "note": "models fitted with few iterations: generation cost depends on "
                             "the training size, not on convergence"},
        "results": results,
        "notes": _notes(results),
        "headline": rows,
    }


def _notes(results) -> list[str]:
    notes = []
    for label, res in results.items():
        prof = res["profile_s"]
        total = res["generate_public"]["median_s"]
        parts = ", ".join(f"{k}: {v * 1e3:.1f} ms" for k, v in prof.items())
        notes.append(f"{label} (N={res['training_frames_N']}): one generate() of "
                     f"{res['generate_public']['frames']} frames takes {total * 1e3:.1f} ms; "
                     f"{parts}")
    return notes
