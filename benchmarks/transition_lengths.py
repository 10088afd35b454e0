"""Emotion transitions inside one walk rollout, side by side over the transition's length.

    python benchmarks/transition_lengths.py [--quick]

The synthesis benchmark's walk model (:func:`synthesis.fit_group`: one one-actor H-GPDM on the
shared Bandai walks, periodic, ``synthesis.Settings``) generates ``transition_frames``-frame
mean rollouts whose emotion changes from neutral to each other emotion along a smoothstep
(:class:`bayesmotion.Transition`) of each length in ``LENGTHS`` frames (0: a switch at one
frame), with the look-ahead of ``synthesis.Settings.lookahead`` and, at the synthesis
benchmark's length, without it; and matched transitions
(``Transition(..., match=True)``, :mod:`bayesmotion.model.transition`: the target continues
from its training frame that best matches the source's last poses, the difference blended
out) over each blend length in ``MATCHED_LENGTHS``, with the look-ahead, switching at the
centre and with the switch searched over the ``MATCHED_WITHIN`` frames after it
(``Transition(..., within=...)``: the frame whose last poses a target training frame matches
best; measured where it switched). Each rollout is
measured by :func:`synthesis.transition_row`: the judge's (the affective-feature classifier
trained on every real clip of the synthesis benchmark's groups, as there) probability of the
target over sliding windows; the body-frame
jerk in the switch window over the jerk before the switch, after it and the jerkier of the two
(a faster emotion jerks more, so the jerkier side is the fair reference) and the switch
window's rank among every window of its width wholly on the jerkier side (their jerk varies
from window to window: a typical window of that side ranks about 0.5); the largest latent step
in the switch window over the median step elsewhere, and how far from the training latents
the rollout runs there. ``TARGETS``: #34's "no jump in jerk at the switch", read as a rank of
at most 0.9 for every emotion: the switch jerks no more than the jerkier side's 90th
percentile window; and the emotion changes: the judge's p(target) in the last window at least
0.5 for every emotion (a transition that never reaches its target cannot jump to it).
``run(quick)`` writes ``results/transition_lengths.json`` atomically; ``rescore()`` rewrites
its headlines from the stored runs (with ``rescored_utc``), measuring nothing again.
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
    machine_info,
    show_headlines,
    standalone_main,
    write_json,
)

from bayesmotion.baselines import LogisticRegression  # noqa: E402
from bayesmotion.features import clip_features  # noqa: E402

NAME = "transition_lengths"
LENGTHS = (0, 10, 20, 40, 80)  # smoothstep lengths in frames (10 fps)
MATCHED_LENGTHS = (0, 5, 10, 20)  # blend lengths of the matched transitions
# frames after the centre a searched matched switch may come at: one gait cycle at 10 fps
# (study_interpolation.STRIDE_SECONDS, 1.2 s)
MATCHED_WITHIN = 12
TARGETS = synthesis.TRANSITION_TARGETS


def _headline(r: dict) -> dict:
    """One run's row (:func:`synthesis.transition_headline`)."""
    what = synthesis.transition_name(r["length"], r["matched"], r.get("within", 0))
    return synthesis.transition_headline(r["summary"], f"{what}, look-ahead {r['lookahead']:g}")


def rescore(path: str | Path | None = None) -> dict:
    """Rewrite a stored result's targets and headlines from its runs (nothing measured again),
    atomically, with ``rescored_utc``."""
    import json
    from datetime import UTC, datetime

    path = Path(path) if path is not None else RESULTS / f"{NAME}.json"
    stored = json.loads(path.read_text())
    stored["targets"] = TARGETS
    stored["headline"] = [_headline(r) for r in stored["runs"]
                          if "worst" in r["summary"]["jerk_switch_rank"]]
    stored["rescored_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
    write_json(path, stored)
    return stored


def run(quick: bool, root: str | Path | None = None, out: str | Path | None = None) -> dict:
    cfg = synthesis.QUICK if quick else synthesis.Settings()  # its groups: the judge's clips
    lengths = (0, cfg.transition_length) if quick else LENGTHS
    within = 4 if quick else MATCHED_WITHIN
    root = Path(root) if root is not None else BANDAI_ROOT
    out = Path(out) if out is not None else RESULTS / f"{NAME}.json"
    base = {"name": NAME, "mode": "quick" if quick else "full",
            "settings": {"contents": list(cfg.groups["walks"]), "fps": cfg.fps,
                         "max_iter": cfg.max_iter, "seed": cfg.seed,
                         "periodic": "walks" in cfg.periodic, "lookahead": cfg.lookahead,
                         "transition_frames": cfg.transition_frames, "window": cfg.window,
                         "lengths": list(lengths),
                         "matched_lengths": list((0, cfg.transition_length) if quick
                                                 else MATCHED_LENGTHS),
                         "synthesis_length": cfg.transition_length,
                         "matched_within": within},
            "targets": TARGETS}
    if not bandai_present(root):
        return bandai_skip(base, root, out)
    t0 = time.perf_counter()
    data = synthesis.load_clips(root, cfg)
    judge = LogisticRegression().fit(np.stack([clip_features(t.actors[0]) for t in data]),
                                     [t.labels["emotion"] for t in data])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        _, model, fit_s = synthesis.fit_group("walks", data, cfg.groups["walks"], cfg)
    runs = []
    matched = (0, cfg.transition_length) if quick else MATCHED_LENGTHS
    for lookahead, length, match, w in ([(cfg.lookahead, n, False, 0) for n in lengths]
                                        + [(0.0, cfg.transition_length, False, 0)]
                                        + [(cfg.lookahead, n, True, 0) for n in matched]
                                        + [(cfg.lookahead, n, True, within) for n in matched]):
        block = synthesis.transition_block(model, judge, cfg, length, lookahead, match, w)
        runs.append({"length": length, "lookahead": lookahead, "matched": match, "within": w,
                     "emotions": block, "summary": synthesis.transition_summary(block)})
        print(f"[{NAME}] length {length}, look-ahead {lookahead}, matched {match}, within {w}:"
              f" done", file=sys.stderr, flush=True)
    head = [_headline(r) for r in runs if "worst" in r["summary"]["jerk_switch_rank"]]
    result = {**base, "fit": {"seconds": fit_s, "iterations": model.diagnostics["iterations"],
                              "converged": model.diagnostics["converged"]},
              "runs": runs, "headline": head, "status": "ok",
              "timing_s": {"total": time.perf_counter() - t0}, "machine": machine_info()}
    write_json(out, result)
    return result


def main() -> int:
    return standalone_main(NAME, run, __doc__, "two walk contents, few iterations, two lengths",
                           show_headlines)


if __name__ == "__main__":
    sys.exit(main())
