"""benchmarks/demo_quick.py: the main job timed as a whole command, judged against the quick
demo's budget and its posterior targets (the command itself is run by test_cli)."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import demo_quick  # noqa: E402


def _fake(wall, rhat, ess):
    def run_demo(out, cache):
        calls.append((out.name, cache))
        return {"wall_seconds": wall, "seconds_total": wall - 3,
                "stage_seconds": {"fit": 2.0, "posterior": 40.0}, "cache_files": 0,
                "posterior": {"max_rhat": rhat, "min_ess_bulk": ess, "min_ess_tail": ess,
                              "max_tau": 2.5, "n_steps": 200, "n_walkers": 26,
                              "n_coordinates": 12, "style_vectors": "held at the MAP",
                              "seconds": 40.0}}
    calls = []
    return run_demo, calls


def test_two_runs_share_one_cache_and_are_judged(monkeypatch):
    run_demo, calls = _fake(120.0, 1.02, 1500.0)
    monkeypatch.setattr(demo_quick, "run_demo", run_demo)
    res = demo_quick.run(quick=False)
    assert [c[0] for c in calls] == ["empty_cache", "filled_cache"]
    assert calls[0][1] == calls[1][1]  # the second run reads what the first compiled
    met = [row["met"] for row in res["headline"]]
    assert met == [True, True, True]
    assert "fit 2 s, posterior 40 s" in res["headline"][0]["note"]


def test_a_slow_run_or_an_unconverged_posterior_is_not_met(monkeypatch):
    run_demo, calls = _fake(200.0, 1.08, 300.0)
    monkeypatch.setattr(demo_quick, "run_demo", run_demo)
    res = demo_quick.run(quick=True)
    assert [c[0] for c in calls] == ["empty_cache"]
    assert [row["met"] for row in res["headline"]] == [False, False]
    assert "both met: False" in res["headline"][-1]["note"]
