"""benchmarks/projection_budget.py's summary, on stored folds built by hand: each budget's
answers are those of its own level evidences, and the share of folds that agree with the
largest budget is counted against that budget's answers."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import projection_budget  # noqa: E402
import run_all  # noqa: E402

LEVELS = ["neutral", "happy"]


def _fold(true: str, early, late, seconds=(1.0, 3.0)) -> dict:
    return {"trial": true, "true": true, "budgets": {
        "100": {"log_evidence": early, "objectives": [0.0, 0.0], "seconds": seconds[0]},
        "400": {"log_evidence": late, "objectives": [0.0, 0.0], "seconds": seconds[1]}}}


def test_each_budget_is_scored_on_its_own_evidence():
    # fold 1: neutral, read happy at 100 and neutral at 400 (by 50 nats: P ~ 1);
    # fold 2: happy, read happy at both; fold 3: happy, read neutral at both
    rows = [_fold("neutral", [0.0, 30.0], [50.0, 0.0]),
            _fold("happy", [0.0, 40.0], [0.0, 40.0], (2.0, 5.0)),
            _fold("happy", [10.0, 0.0], [60.0, 0.0], (3.0, 4.0))]
    out = projection_budget.summarize(rows, LEVELS, (100, 400))
    early, late = out["by_budget"]
    assert early["max_iter"] == 100 and late["max_iter"] == 400
    assert early["accuracy"] == pytest.approx(1 / 3)
    assert late["accuracy"] == pytest.approx(2 / 3)
    assert early["same_answer_as_largest"] == pytest.approx(2 / 3)
    assert late["same_answer_as_largest"] == 1.0
    assert early["seconds"] == 2.0 and late["seconds"] == 4.0
    # fold 3 at 400 is wrong with P = 1 - e^-60
    assert late["confident_wrong"] == pytest.approx(1 / 3)
    assert len(out["headline"]) == 2
    assert "same answer as at 400 in 2/3" in out["headline"][0]["note"]


def test_the_benchmark_is_in_the_suite():
    assert "projection_budget" in run_all.BENCHMARKS
