"""Foot sliding of generated motion before and after the foot-skate clean-up, side by side.

    python benchmarks/foot_contacts.py [--quick]

The generated clips of ``benchmarks/synthesis.py`` (same groups, fits, rollouts and judges:
one one-actor H-GPDM per content group on the shared Bandai clips, each real clip's mean
rollout and ``n_samples`` sampled rollouts from its first frames) are scored raw and after
:func:`bayesmotion.features.contacts.pin_feet` (``Rollout.pin_feet``) in the same run:

* the naturalness ratios against the group's real clips as captured (jerk, foot sliding,
  joint-limit violations; :mod:`bayesmotion.evaluation.naturalness`), mean rollouts and samples
  pooled as in ``synthesis.json`` and also each apart;
* the held-out judge's rate (the clean-up changes the root path, which the clip features see);
* the real clips themselves after the clean-up, against the same real clips as captured: what
  the clean-up does to motion that does not glide.

The clean-up pins what the sliding measure counts as contact, so a ratio after it reads the
residual sliding of the pinned motion (double support, steps at a contact's edges), not the
generator's own: the raw row is the model's number. ``TARGETS`` are #34's naturalness
targets. ``run(quick)`` writes ``results/foot_contacts.json`` atomically.
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

import synthesis  # noqa: E402
from _common import (  # noqa: E402
    BANDAI_ROOT,
    RESULTS,
    bandai_present,
    bandai_skip,
    headline,
    machine_info,
    show_headlines,
    standalone_main,
    write_json,
)

from bayesmotion.baselines import LogisticRegression  # noqa: E402
from bayesmotion.errors import BayesmotionError  # noqa: E402
from bayesmotion.evaluation.naturalness import NaturalnessReference, naturalness  # noqa: E402
from bayesmotion.features import clip_features  # noqa: E402
from bayesmotion.features.contacts import SMOOTH, SPEED_SCALE, pin_feet  # noqa: E402

NAME = "foot_contacts"
TARGETS = {"jerk_ratio_max": synthesis.TARGETS["jerk_ratio_max"],
           "foot_sliding_ratio_max": synthesis.TARGETS["foot_sliding_ratio_max"]}
KEYS = ("foot_sliding_ratio", "jerk_ratio", "joint_limit_violations", "joint_limit_exceedance")
VARIANTS = ("raw", "pinned", "legs")  # generated, root clean-up, root and legs (legs=True)


def scores(motions, reference) -> dict:
    """Mean naturalness ratios (``KEYS``) of ``motions`` against ``reference``."""
    rows = [naturalness(m, reference) for m in motions]
    return {k: float(np.mean([r[k] for r in rows])) for k in KEYS} | {"n": len(rows)}


def judged(judge: LogisticRegression, motions, emotion: str) -> list[bool]:
    return [lab == emotion for lab in judge.predict(np.stack([clip_features(m)
                                                              for m in motions]))]


def group_run(name: str, data, contents: tuple, judges: dict, cfg) -> dict:
    group, model, fit_s = synthesis.fit_group(name, data, contents, cfg)
    real = [t.actors[0] for t in group]
    reference = NaturalnessReference.from_motions(real, cfg.fps)
    kinds = ("mean", "sampled")
    made = {v: {k: [] for k in kinds} for v in VARIANTS}
    hits = {v: {k: [] for k in kinds} for v in VARIANTS}
    errors = []
    for _, t, roll in synthesis.generated(model, list(group), cfg):
        if isinstance(roll, BayesmotionError):
            errors.append({"clip": t.name, "error": str(roll)})
            continue
        for variant, r in (("raw", roll), ("pinned", roll.pin_feet()),
                           ("legs", roll.pin_feet(legs=True))):
            for kind, ms in synthesis.rollout_motions(r, cfg.n_samples).items():
                made[variant][kind] += ms
                hits[variant][kind] += judged(judges[t.name], ms, t.labels["emotion"])
    out = {"contents": list(contents), "fit_seconds": fit_s,
           "fit_iterations": model.diagnostics["iterations"],
           "converged": model.diagnostics["converged"], "errors": errors,
           "real_pinned": scores([pin_feet(m) for m in real], reference),
           "real_legs": scores([pin_feet(m, legs=True) for m in real], reference)}
    for variant in VARIANTS:
        ms = made[variant]
        out[variant] = {"pooled": scores(ms["mean"] + ms["sampled"], reference),
                        **{k: scores(ms[k], reference) for k in kinds},
                        "judge_rate": {k: float(np.mean(hits[variant][k])) for k in kinds}}
    return out


def run(quick: bool, root: str | Path | None = None, out: str | Path | None = None) -> dict:
    cfg = synthesis.QUICK if quick else synthesis.Settings()
    root = Path(root) if root is not None else BANDAI_ROOT
    out = Path(out) if out is not None else RESULTS / f"{NAME}.json"
    base = {"name": NAME, "mode": "quick" if quick else "full",
            "settings": {"groups": {k: list(v) for k, v in cfg.groups.items()},
                         "fps": cfg.fps, "max_iter": cfg.max_iter, "n_samples": cfg.n_samples,
                         "seed": cfg.seed, "periodic": list(cfg.periodic),
                         "lookahead": cfg.lookahead, "speed_scale": SPEED_SCALE,
                         "smooth": SMOOTH},
            "targets": TARGETS}
    if not bandai_present(root):
        return bandai_skip(base, root, out)
    t0 = time.perf_counter()
    data = synthesis.load_clips(root, cfg)
    features = np.stack([clip_features(t.actors[0]) for t in data])
    judges = dict(zip([t.name for t in data],
                      synthesis.held_out_judges(features, [t.labels["emotion"] for t in data]),
                      strict=True))
    groups, rows = {}, []
    for name, cs in cfg.groups.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            g = group_run(name, data, tuple(cs), judges, cfg)
        groups[name] = g
        raw, pin, legs = (g[v]["pooled"] for v in VARIANTS)
        for what, after, real in (("the clean-up", pin, g["real_pinned"]),
                                  ("the clean-up with legs", legs, g["real_legs"])):
            variant = "pinned" if after is pin else "legs"
            rows.append(headline(
                f"{name}: foot sliding of generated clips after {what} / real",
                after["foot_sliding_ratio"], "", f"<= {TARGETS['foot_sliding_ratio_max']}",
                after["foot_sliding_ratio"] <= TARGETS["foot_sliding_ratio_max"],
                f"raw {raw['foot_sliding_ratio']:.2f}; jerk ratio raw {raw['jerk_ratio']:.2f}, "
                f"after {after['jerk_ratio']:.2f}; joint-limit violations raw "
                f"{raw['joint_limit_violations']:.2f}, after "
                f"{after['joint_limit_violations']:.2f} (largest "
                f"{after['joint_limit_exceedance']:.2f} deg); judge's rate (mean rollouts) raw "
                f"{g['raw']['judge_rate']['mean']:.2f}, after "
                f"{g[variant]['judge_rate']['mean']:.2f}; real clips after {what}: sliding "
                f"{real['foot_sliding_ratio']:.2f}, jerk {real['jerk_ratio']:.2f}, joint-limit "
                f"violations {real['joint_limit_violations']:.2f}"))
        print(f"[{NAME}] {name} done", file=sys.stderr, flush=True)
    result = {**base, "groups": groups, "headline": rows, "status": "ok",
              "timing_s": {"total": time.perf_counter() - t0}, "machine": machine_info()}
    write_json(out, result)
    return result


def main() -> int:
    return standalone_main(NAME, run, __doc__, "one group of two walk contents, few iterations",
                           show_headlines)


if __name__ == "__main__":
    sys.exit(main())
