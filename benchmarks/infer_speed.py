"""Seconds per clip of emotion inference, and where they go.

    python benchmarks/infer_speed.py [--quick]

The model is the demo's: ``HGPDM()`` fitted by MAP on the built-in handshakes at 10 fps without
its four held-out trials (one per emotion). ``infer_emotion`` then reads each held-out trial
(17 frames, both actors, couple given) with its default settings (64 walkers, 150 steps, a
third discarded). The first call includes JAX compilation and is reported apart; the others
are timed one by one, with the effective sample size of the emotion posterior (samples kept /
the largest integrated autocorrelation time) and the split of each call into encoding, MAP
projection of the latents, their Laplace sd, the style expansion with the walkers' Laplace
start, and emcee sampling. Both projections are timed: ``emotion_starts="nearest"`` (one start
from the nearest frames) and the default, ``"vertices"`` (one projection per emotion level,
Laplace evidence, then a joint refinement). The issue's target: under 2 s per clip for a
posterior with ESS >= 400.

Each mode also reads clips generated between two emotions (couple c1, 20 frames, emotion
(1 - s) a + s b for s in 0, .25, .5, .75, 1; neutral to happy and sad to angry): the mean
absolute error of the inferred coordinate of b against s, "interpolate the emotion, not just
the motion", measured; and so does ``"vertices"`` with its level projections started from
jittered copies of the nearest-frame latents (``start_jitter=0.02``), and with three starts per
level (``level_starts=3``: the nearest-frame latents and two jittered copies, the best kept;
its seconds per clip beside, with ``latent_uncertainty=False`` as every interpolated clip).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import headline, standalone_main  # noqa: E402

NAME = "infer_speed"
TARGET_S = 2.0
FULL = {"fps": 10.0, "max_iter": 150, "repeats": 2, "interp_s": (0.0, 0.25, 0.5, 0.75, 1.0)}
QUICK = {"fps": 10.0, "max_iter": 20, "repeats": 1, "interp_s": (0.0, 1.0)}
# the default (the level evidence) first: its first call compiles everything it uses
MODES = ("vertices", "nearest")
JITTER = 0.02  # the jittered level starts measured beside the default's
PREVIOUS_MAX_ITER = 200  # infer_emotion's earlier default projection budget, timed beside today's


def run(quick: bool) -> dict:
    import numpy as np

    from bayesmotion.app.demo import _split
    from bayesmotion.datasets import load_handshakes
    from bayesmotion.emotion.infer import infer_emotion
    from bayesmotion.model.spec import HGPDM

    cfg = QUICK if quick else FULL
    train, held = _split(load_handshakes(fps=cfg["fps"]))
    t = time.perf_counter()
    model = HGPDM().fit(train, max_iter=cfg["max_iter"], progress=False)
    fit_s = time.perf_counter() - t

    def once(trial, seed, mode, **kw):
        t = time.perf_counter()
        ep = infer_emotion(model, trial, couple=trial.labels["couple"], seed=seed,
                           emotion_starts=mode, **kw)
        return time.perf_counter() - t, ep

    out, rows = {}, []
    for mode in MODES:
        first_s, _ = once(held[0], 0, mode)
        calls = []
        for r in range(cfg["repeats"]):
            for trial in held:
                s, ep = once(trial, r + 1, mode)
                calls.append({"trial": trial.name, "seconds": s, "ess": ep.info["ess"],
                              "label": ep.label, "true": trial.labels["emotion"],
                              "stage_seconds": ep.info["stage_seconds"],
                              "map_iterations": ep.info["map_iterations"],
                              "level_iterations": ep.info.get("level_iterations")})
        sec = np.array([c["seconds"] for c in calls])
        ess = np.array([c["ess"] for c in calls])
        stages = {k: float(np.median([c["stage_seconds"][k] for c in calls]))
                  for k in calls[0]["stage_seconds"]}
        worst = max(stages, key=stages.get)
        med = float(np.median(sec))
        right = sum(c["label"] == c["true"] for c in calls)
        name = ("infer_emotion (default, emotion_starts='vertices')" if mode == "vertices"
                else f"infer_emotion(emotion_starts={mode!r})")
        rows += [
            headline(f"{name}, seconds per clip (median of {len(calls)})", med, "s",
                     f"< {TARGET_S:g} s with ESS >= 400",
                     None if quick else bool(med < TARGET_S and ess.min() >= 400),
                     f"min ESS {ess.min():.0f}; largest part: {worst} {stages[worst]:.2f} s; "
                     f"labels right {right}/{len(calls)}"),
            headline("  first call on a model (incl. compilation)", first_s, "s"),
        ]
        interp = _interpolation(model, mode, cfg["interp_s"])
        mae = {k: v["mean_abs_error"] for k, v in interp.items()}
        rows.append(headline(f"  interpolated clips, mean |inferred - s| ({mode})",
                             float(np.mean(list(mae.values()))), "",
                             note="; ".join(f"{k} {v:.3f}" for k, v in mae.items())))
        out[mode] = {"first_call_seconds": first_s, "calls": calls,
                     "median_stage_seconds": stages, "interpolation": interp}
    calls = []
    for r in range(cfg["repeats"]):
        for trial in held:
            s, ep = once(trial, r + 1, "vertices", max_iter=PREVIOUS_MAX_ITER)
            calls.append({"trial": trial.name, "seconds": s, "label": ep.label,
                          "true": trial.labels["emotion"],
                          "level_iterations": ep.info["level_iterations"]})
    right = sum(c["label"] == c["true"] for c in calls)
    capped = sum(n >= PREVIOUS_MAX_ITER for c in calls for n in c["level_iterations"])
    n_levels = sum(len(c["level_iterations"]) for c in calls)
    rows.append(headline(f"  the same at max_iter={PREVIOUS_MAX_ITER} (the previous default)",
                         float(np.median([c["seconds"] for c in calls])), "s",
                         note=f"labels right {right}/{len(calls)}; level projections stopped "
                              f"at the limit: {capped}/{n_levels}"))
    out["vertices"]["previous_max_iter"] = {"max_iter": PREVIOUS_MAX_ITER, "calls": calls}
    interp = _interpolation(model, "vertices", cfg["interp_s"], start_jitter=JITTER)
    mae = {k: v["mean_abs_error"] for k, v in interp.items()}
    rows.append(headline(f"  interpolated clips, mean |inferred - s| (vertices, start_jitter="
                         f"{JITTER:g})", float(np.mean(list(mae.values()))), "",
                         note="; ".join(f"{k} {v:.3f}" for k, v in mae.items())))
    out["vertices"]["interpolation_jittered_starts"] = interp
    interp = _interpolation(model, "vertices", cfg["interp_s"], start_jitter=JITTER,
                            level_starts=3)
    mae = {k: v["mean_abs_error"] for k, v in interp.items()}
    sec = float(np.median([r["seconds"] for v in interp.values() for r in v["series"]]))
    rows.append(headline(f"  interpolated clips, mean |inferred - s| (vertices, level_starts=3, "
                         f"start_jitter={JITTER:g})", float(np.mean(list(mae.values()))), "",
                         note="; ".join(f"{k} {v:.3f}" for k, v in mae.items())
                         + f"; {sec:.2f} s per clip (median, latent_uncertainty=False)"))
    out["vertices"]["interpolation_three_starts"] = interp
    return {"settings": {**cfg, "n_train_trials": len(train), "n_frames": held[0].n_frames},
            "fit_seconds": fit_s, "modes": out, "headline": rows}


def _interpolation(model, mode: str, s_values, start_jitter: float = 0.0,
                   level_starts: int = 1) -> dict:
    import numpy as np

    from bayesmotion.emotion.infer import infer_emotion

    levels = list(model.levels["emotion"])
    out = {}
    for a, b in (("neutral", "happy"), ("sad", "angry")):
        rows = []
        for s in s_values:
            c = np.zeros(len(levels))
            c[levels.index(a)], c[levels.index(b)] = 1 - s, s
            clip = model.generate(emotion=c, couple="c1", n_frames=20).Y
            t = time.perf_counter()
            ep = infer_emotion(model, clip, couple="c1", emotion_starts=mode,
                               latent_uncertainty=False, start_jitter=start_jitter,
                               level_starts=level_starts)
            rows.append({"s": float(s), "inferred": float(ep.mean[levels.index(b)]),
                         "label": ep.label, "seconds": time.perf_counter() - t})
        out[f"{a}->{b}"] = {"series": rows, "mean_abs_error": float(
            np.mean([abs(r["inferred"] - r["s"]) for r in rows]))}
    return out


def main() -> int:
    return standalone_main(NAME, run, __doc__, "a barely fitted model, one repeat",
                           lambda r: "\n".join(map(str, r["headline"])))


if __name__ == "__main__":
    sys.exit(main())
