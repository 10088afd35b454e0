"""Helpers of benchmarks/sample_paths.py, without fitting."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import sample_paths  # noqa: E402


def test_the_limb_motion_span_covers_every_emotion_and_sample():
    per = {"long": {"happy": {"limb_motion_last_over_first": [0.9, 1.4]},
                    "sad": {"limb_motion_last_over_first": [0.55, 1.0]}}}
    assert sample_paths._span(per) == "0.55-1.40"


def test_without_the_shared_data_the_run_says_so(tmp_path):
    res = sample_paths.run(True, root=tmp_path)
    assert res["headline"] == [] and "Bandai data not found" in res["skipped"]
    assert res["settings"]["memories"] == list(sample_paths.MEMORIES)
    assert 0 in sample_paths.MEMORIES  # the step-by-step draws are always the baseline
