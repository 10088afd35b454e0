"""benchmarks/projection_starts.py's summary, on stored folds built by hand: which starts each
row compares, and that a row's numbers are the answers those starts give."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import projection_starts  # noqa: E402

LEVELS = ["neutral", "happy"]


def _row(true: str, evidences, objectives) -> dict:
    return {"trial": true, "true": true, "seconds": 1.0,
            "start_log_evidence": evidences, "start_objectives": objectives}


def _rows():
    # two levels, three starts: column 0 the unjittered start, columns 1 and 2 jittered.
    # Fold 1: the unjittered start reads happy, both jittered ones neutral (the truth).
    # Fold 2: the unjittered and jittered start 1 read happy (the truth); jittered start 2,
    # which has the best objective of level neutral, reads neutral.
    return [
        _row("neutral", [[0.0, 50.0, 40.0], [10.0, 10.0, 10.0]],
             [[5.0, 1.0, 2.0], [3.0, 3.0, 3.0]]),
        _row("happy", [[0.0, 0.0, 60.0], [20.0, 20.0, 20.0]],
             [[5.0, 4.0, 1.0], [3.0, 3.0, 3.0]]),
    ]


def test_each_row_compares_the_starts_it_names():
    out = projection_starts.summarize(_rows(), LEVELS, 3)
    # the unjittered start alone: fold 1 wrong, fold 2 right
    assert out["unjittered_start"]["accuracy"] == pytest.approx(0.5)
    alone = {a["start"]: a["accuracy"] for a in out["each_start_alone"]}
    assert alone == {0: pytest.approx(0.5), 1: pytest.approx(1.0), 2: pytest.approx(0.5)}
    # one jittered start: the mean over starts 1 and 2, with their range
    one = out["by_starts"][0]
    assert one["starts"] == 1 and one["subsets"] == 2
    assert one["accuracy"]["mean"] == pytest.approx(0.75)
    assert (one["accuracy"]["min"], one["accuracy"]["max"]) == (pytest.approx(0.5), 1.0)
    # best of both jittered starts, by objective: fold 1 start 1 (neutral, right), fold 2
    # start 2 for level neutral (60 > 20: neutral, wrong)
    two = out["by_starts"][1]
    assert two["subsets"] == 1 and two["accuracy"]["mean"] == pytest.approx(0.5)
    # with the unjittered start: k = 1 is that start alone, k = 3 every start
    assert out["with_unjittered"][0]["accuracy"]["mean"] == pytest.approx(0.5)
    assert out["with_unjittered"][2]["accuracy"]["mean"] == pytest.approx(
        out["best_of_starts"]["accuracy"]) == pytest.approx(0.5)
    # jittered starts with a better objective than the unjittered one, per fold-level
    assert out["jittered_starts_beating_the_first"] == [2, 0, 2]
    assert out["evidence_spread"]["max"] == pytest.approx(60.0)
    assert out["label_changes"] == 2  # both folds: happy (unjittered) -> neutral (best of 3)
    assert np.isfinite([h["value"] for h in out["headline"]]).all()
