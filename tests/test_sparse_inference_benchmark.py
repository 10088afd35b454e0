"""benchmarks/sparse_inference.py's summary, on stored folds built by hand: each model is scored
on its own level evidences, and the projections that stopped at the iteration limit are
counted against the budget the summary is given."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import run_all  # noqa: E402
import sparse_inference  # noqa: E402

LEVELS = ["neutral", "happy"]


def _fold(true: str, log_ev, its, seconds=1.0, cond=0.5) -> dict:
    return {"trial": true, "true": true, "log_evidence": log_ev, "level_iterations": its,
            "seconds": seconds, "condition_seconds": cond}


def test_each_model_is_scored_on_its_own_evidence():
    exact = {"inducing": None, "fit_seconds": 100.0, "folds": [
        _fold("neutral", [50.0, 0.0], [400, 120], 20.0, 3.0),
        _fold("happy", [0.0, 40.0], [400, 400], 22.0, 5.0)]}
    # the sparse model reads the happy walk as neutral with P = 1 - e^-60
    sparse = {"inducing": 100, "fit_seconds": 20.0, "folds": [
        _fold("neutral", [50.0, 0.0], [90, 80], 2.0, 1.0),
        _fold("happy", [60.0, 0.0], [400, 10], 4.0, 2.0)]}
    out = sparse_inference.summarize([exact, sparse], LEVELS, max_iter=400)
    e, s = out["by_model"]
    assert e["inducing"] is None and s["inducing"] == 100
    assert e["accuracy"] == 1.0 and s["accuracy"] == 0.5
    assert e["confident_wrong"] == 0.0 and s["confident_wrong"] == pytest.approx(0.5)
    assert e["seconds"] == 21.0 and s["seconds"] == 3.0
    assert e["condition_seconds"] == 4.0 and s["condition_seconds"] == 1.5
    assert (e["at_limit"], e["n_projections"]) == (3, 4)
    assert (s["at_limit"], s["n_projections"]) == (1, 4)
    assert "exact" in out["headline"][0]["metric"]
    assert "M = 100" in out["headline"][1]["metric"]
    assert "at the 400-iteration limit: 1/4" in out["headline"][1]["note"]


def test_the_limit_defaults_to_infer_emotions_budget():
    import inspect

    from bayesmotion.emotion.infer import infer_emotion

    default = inspect.signature(infer_emotion).parameters["max_iter"].default
    model = {"inducing": None, "fit_seconds": 1.0, "folds": [
        _fold("neutral", [1.0, 0.0], [default, default - 1])]}
    assert sparse_inference.summarize([model], LEVELS)["by_model"][0]["at_limit"] == 1


def test_the_benchmark_is_in_the_suite():
    assert "sparse_inference" in run_all.BENCHMARKS
