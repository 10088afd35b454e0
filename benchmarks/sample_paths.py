"""Sampled rollouts drawn step by step against sampled rollouts conditioned on their own path.

    python benchmarks/sample_paths.py [--quick]

``generate(n_samples=S)`` draws every step of a sampled rollout from the dynamics GP's
predictive given the training data. With ``sample_memory=W`` each step is also conditioned on
the last W steps of its own path, as if they were training data, so the drawn function stays
one function along the path (:func:`bayesmotion.model.generate._path_sampled_rollout`). This
benchmark fits the synthesis benchmark's one-actor models (``HGPDM(rest_frames=True,
canonical_side=True)``, emotion as the style factor, 10 fps, ``max_iter`` iterations) on the
shared Bandai walks, run/dash and the gestures bye/bow, and for each memory in ``MEMORIES``
(0: the step-by-step draws) measures, side by side on the same models and seeds:

* the jerk and foot-sliding ratios of ``n_samples`` sampled rollouts per real clip, as long as
  the clip and started from its first frames (:mod:`bayesmotion.evaluation.naturalness`,
  against the group's real clips);
* over ``long_frames``-frame sampled rollouts (two per emotion), the largest |I| over the
  training latents' range and the limb motion of the last 200 frames over the first 200;
* seconds per ``generate`` call of ``timed_frames`` frames with ``n_samples`` samples, timed
  after one untimed call of the same size (compilation excluded).

Nothing is tuned to a target; the issue's naturalness targets (ratios <= 1.2) are printed
beside the numbers.
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

from _common import BANDAI_ROOT, bandai_present, headline, standalone_main  # noqa: E402
from synthesis import joint_speed  # noqa: E402

NAME = "sample_paths"
MEMORIES = (0, 16, 64)
FULL = {"groups": {"walks": ("walk", "walk-back", "walk-left", "walk-right"),
                   "run": ("run", "dash"), "gesture": ("bye", "bow")},
        "fps": 10.0, "max_iter": 1000, "n_samples": 3, "long_frames": 1000, "long_samples": 2,
        "timed_frames": 200}
QUICK = {"groups": {"gesture": ("bye",)}, "fps": 10.0, "max_iter": 60, "n_samples": 2,
         "long_frames": 300, "long_samples": 1, "timed_frames": 50}


def _span(per_memory: dict) -> str:
    """min-max of the long samples' limb motion ratios over emotions and samples."""
    v = [x for e in per_memory["long"].values() for x in e["limb_motion_last_over_first"]]
    return f"{min(v):.2f}-{max(v):.2f}"


def run(quick: bool, root: str | Path | None = None) -> dict:
    from bayesmotion.data.motion import MotionDataset
    from bayesmotion.datasets.bandai import load_bandai
    from bayesmotion.evaluation.naturalness import NaturalnessReference, naturalness
    from bayesmotion.model.generate import generate
    from bayesmotion.model.spec import HGPDM

    cfg = QUICK if quick else FULL
    root = Path(root) if root is not None else BANDAI_ROOT
    settings = {**cfg, "memories": list(MEMORIES),
                "groups": {k: list(v) for k, v in cfg["groups"].items()}}
    if not bandai_present(root):
        return {"settings": settings, "skipped": f"Bandai data not found at {root}",
                "headline": []}
    groups, rows = {}, []
    for name, contents in cfg["groups"].items():
        data = load_bandai(root, content=contents, fps=cfg["fps"])
        trials = list(data)
        group = MotionDataset(tuple(trials), {"emotion": data.levels["emotion"]}, name=name)
        spec = HGPDM(rest_frames=True, canonical_side=True, interaction_factors=("emotion",),
                     dynamics_factors=("emotion",))
        t0 = time.perf_counter()
        model = spec.fit(group, max_iter=cfg["max_iter"], seed=0, progress=False)
        fit_s = time.perf_counter() - t0
        ref = NaturalnessReference.from_motions([t.actors[0] for t in trials], cfg["fps"])
        I_range = float(np.abs(np.asarray(model.params["I"])).max())
        per = {}
        for mem in MEMORIES:
            nat, secs = [], []
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                for r, t in enumerate(trials):
                    roll = generate(model, emotion=t.labels["emotion"], n_frames=t.n_frames,
                                    n_samples=cfg["n_samples"], start=r, seed=r,
                                    sample_memory=mem)
                    nat += [naturalness(roll.to_motion(s)[0], ref)
                            for s in range(cfg["n_samples"])]
                for _ in range(2):  # the first call compiles
                    t1 = time.perf_counter()
                    generate(model, emotion=trials[0].labels["emotion"],
                             n_frames=cfg["timed_frames"], n_samples=cfg["n_samples"],
                             seed=0, sample_memory=mem)
                    secs.append(time.perf_counter() - t1)
                long = {}
                for e in model.levels["emotion"]:
                    roll = generate(model, emotion=e, n_frames=cfg["long_frames"],
                                    n_samples=cfg["long_samples"], seed=0, sample_memory=mem)
                    sp = [joint_speed(roll.to_motion(s)[0].values)
                          for s in range(cfg["long_samples"])]
                    long[e] = {"latent_range": float(np.abs(roll.samples["I"]).max() / I_range),
                               "limb_motion_last_over_first": [
                                   float(v[-200:].mean() / v[:200].mean()) for v in sp]}
            per[str(mem)] = {
                "jerk_ratio": float(np.mean([n["jerk_ratio"] for n in nat])),
                "jerk_ratio_median": float(np.median([n["jerk_ratio"] for n in nat])),
                "foot_sliding_ratio": float(np.mean([n["foot_sliding_ratio"] for n in nat])),
                "joint_limit_violations": float(np.mean([n["joint_limit_violations"]
                                                         for n in nat])),
                "seconds_per_generate": secs[-1],
                "long": long,
                "long_latent_range_max": max(v["latent_range"] for v in long.values())}
            print(f"[{NAME}] {name} memory {mem}: jerk {per[str(mem)]['jerk_ratio']:.2f}",
                  file=sys.stderr, flush=True)
        groups[name] = {"contents": list(contents), "fit_seconds": fit_s,
                        "fit_converged": bool(model.diagnostics.get("converged")),
                        "memories": per}
        base, best = per["0"], per[str(MEMORIES[-1])]
        rows.append(headline(
            f"{name}: sampled rollouts' jerk ratio, memory {MEMORIES[-1]} (independent steps: "
            f"{base['jerk_ratio']:.2f})", best["jerk_ratio"], "x real", "<= 1.2",
            best["jerk_ratio"] <= 1.2,
            f"foot sliding {best['foot_sliding_ratio']:.2f} (independent "
            f"{base['foot_sliding_ratio']:.2f}); {cfg['long_frames']}-frame samples: latent "
            f"range <= {best['long_latent_range_max']:.2f}x (independent "
            f"{base['long_latent_range_max']:.2f}x), limb motion last/first 200 frames "
            f"{_span(best)} (independent {_span(base)}); "
            + "; ".join(f"memory {m}: jerk {per[str(m)]['jerk_ratio']:.2f}"
                        for m in MEMORIES[1:-1])
            + f"; {cfg['timed_frames']} frames with {cfg['n_samples']} samples in "
            f"{best['seconds_per_generate']:.2f} s (independent "
            f"{base['seconds_per_generate']:.2f} s)"))
    return {"settings": settings, "groups": groups, "headline": rows}


def main() -> int:
    return standalone_main(NAME, run, __doc__, "one gesture, a barely fitted model",
                           lambda r: "\n".join(map(str, r["headline"])))


if __name__ == "__main__":
    sys.exit(main())
