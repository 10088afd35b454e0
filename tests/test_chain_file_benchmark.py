"""benchmarks/chain_file.py on small chains: every backend saves every step it is given, and the
batched writer holds the steps while no commit is due."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import chain_file  # noqa: E402
import run_all  # noqa: E402


def test_it_is_in_the_suite():
    assert "chain_file" in run_all.BENCHMARKS


def test_a_small_run_times_every_backend(monkeypatch):
    from bayesmotion.inference import chainfile

    monkeypatch.setattr(chainfile, "COMMIT_RATIO", 1e6)  # batches: the first step, then all
    monkeypatch.setitem(chain_file.SETTINGS, "quick",
                        {"sizes": [[30, 4, 2], [2000, 54, 26]], "step_s": [0.0, 0.068],
                         "timed": 3})
    out = chain_file.run(quick=True)
    assert len(out["rows"]) == 4
    for row in out["rows"]:  # run() reads each file back: every step saved
        for name in ("emcee_in_place", "chainfile_batched", "chainfile_every_step"):
            assert row[name]["save_ms_per_step"] > 0
        assert row["chainfile_every_step"]["most_steps_held"] == 0
        assert row["chainfile_batched"]["most_steps_held"] == 2
    (h,) = out["headline"]
    assert h["unit"] == "%" and isinstance(h["met"], bool)
