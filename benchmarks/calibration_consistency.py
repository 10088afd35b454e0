"""The emotion benchmarks' ECE against what a calibrated posterior would score on the same clips.

    python benchmarks/run_all.py --only calibration_consistency

Reads the per-clip label probabilities that ``bandai_inference`` (16 walks; and with
``--level-starts 3 --start-jitter 0.02``), ``bandai_inference --all-contents`` (40 clips, when
its result exists) and
``handshake_inference`` (24 built-in trials) stored in ``results/``, plain and with the
recording effect, and runs ``bayesmotion.evaluation.calibration.calibration_consistency`` on
each, every clip scored as the label it answered (consistency resampling, Broecker and Smith
2007: the answers held, each clip's answer drawn right with its stated probability, 20,000
replicates, seed 0). A calibrated posterior's
ECE on 16-40 clips is far from 0, because each reliability bin holds a handful of clips; the
observed ECE is read against that distribution. No model is fitted: the result is a function
of the stored results, and changes when they are rerun.

Target (issue: honest inference): ECE <= 0.05. The rows say where that target lies within
the ECE a calibrated posterior shows with the same answers.

Current result (``results/calibration_consistency.json``): see ``["headline"]`` and
``docs/results.md``.
"""

from __future__ import annotations

import json

import numpy as np
from _common import RESULTS, headline

SOURCES = {"bandai_inference": "16 Bandai walks",
           "bandai_inference_starts3": "16 Bandai walks, level_starts=3",
           "bandai_inference_all": "40 Bandai clips",
           "handshake_inference": "24 built-in handshakes"}
N_DRAWS = 20000


def _answers(result: dict, key: str | None):
    """(probabilities, truth, answered levels) of the stored clips; a clip is scored as
    answered (an answer shrunk to a flat prior counts as the label it reports)."""
    levels = result["levels"]
    rows = [t for t in result["trials"]
            if (t if key is None else t.get(key) or {}).get("probabilities") is not None]
    p = np.array([t["probabilities"] if key is None else t[key]["probabilities"] for t in rows])
    truth = np.array([levels.index(t["true"]) for t in rows])
    answered = np.array([levels.index(t["pred"]) if key is None else _evidence_answer(t[key], t)
                         for t in rows], dtype=int)
    return p / p.sum(1, keepdims=True), truth, answered


def _evidence_answer(cal: dict, row: dict) -> int:
    """The recording effect's answered level: stored, or (a result stored before the rows
    held it) recomputed from the row's evidence at its stored n_eff."""
    from bayesmotion.evaluation.evaluate import recording_effect_answer

    if "label_index" in cal:
        return int(cal["label_index"])
    return recording_effect_answer(row, cal["n_eff"])[1]


def run(quick: bool) -> dict:
    from bayesmotion.evaluation.calibration import calibration_consistency

    out = {"settings": {"n_draws": N_DRAWS, "seed": 0, "level": 0.9, "n_bins": 10,
                        "target_ece": 0.05},
           "sources": {}, "headline": []}
    for name, what in SOURCES.items():
        path = RESULTS / f"{name}.json"
        if not path.exists():
            out["sources"][name] = {"skipped": f"no {path.name}"}
            continue
        stored = json.loads(path.read_text())
        result = stored.get("result", {})
        if "trials" not in result:
            out["sources"][name] = {"skipped": f"{path.name} holds no per-clip answers"}
            continue
        rows = {"date_utc": stored.get("machine", {}).get("date_utc")}
        for label, key in (("plain", None), ("recording_effect", "evidence_calibrated")):
            p, truth, answered = _answers(result, key)
            if not len(p):
                continue
            c = calibration_consistency(p, truth, n_draws=N_DRAWS, seed=0, labels=answered)
            rows[label] = {"n": int(len(p)), "accuracy": float(np.mean(answered == truth)),
                           **c}
            mean, (lo, hi) = c["ece_if_calibrated"]["mean"], c["ece_if_calibrated"]["interval"]
            out["headline"].append(headline(
                f"ECE, {what}, {label.replace('_', ' ')}", c["ece"], "", "<= 0.05",
                c["ece"] <= 0.05,
                f"a calibrated posterior with these answers: mean {mean:.3f}, 90% "
                f"[{lo:.3f}, {hi:.3f}]; p = {c['p_value']:.2g} (n = {len(p)})"))
        out["sources"][name] = rows
    return out
