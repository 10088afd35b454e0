"""The interpolation study (benchmarks/study_interpolation.py) at reduced size, and its helpers."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import study_interpolation as study  # noqa: E402

from bayesmotion.data.emotion import EmotionStyle  # noqa: E402


def test_spearman_matches_scipy_and_is_zero_for_constant_input():
    rng = np.random.default_rng(0)
    for _ in range(20):
        x, y = rng.standard_normal(6), rng.integers(0, 3, 6).astype(float)  # ties in y
        if np.ptp(y) == 0:
            continue
        np.testing.assert_allclose(study.spearman(x, y), spearmanr(x, y).statistic, rtol=1e-12)
    assert study.spearman([0, 0.5, 1], [2.0, 2.0, 2.0]) == 0.0


def test_scaled_style_runs_from_identity_to_the_fitted_style():
    style = EmotionStyle(speed=1.3, amplitude={"arms": 1.5, "legs": 0.8},
                         posture={"Spine": (4.0, -2.0, 0.0)})
    zero, one, half = (study.scaled_style(style, s) for s in (0.0, 1.0, 0.5))
    assert zero.speed == 1.0 and set(zero.amplitude.values()) == {1.0}
    assert zero.posture["Spine"] == (0.0, 0.0, 0.0)
    assert one.speed == pytest.approx(1.3) and one.amplitude["legs"] == pytest.approx(0.8)
    assert one.posture["Spine"] == pytest.approx((4.0, -2.0, 0.0))
    assert half.speed == pytest.approx(np.sqrt(1.3))          # ratios interpolate geometrically
    assert half.posture["Spine"] == pytest.approx((2.0, -1.0, 0.0))


def test_missing_data_writes_a_skip_record(tmp_path):
    out = tmp_path / "study.json"
    res = study.run(True, root=tmp_path / "absent", out=out)
    assert "skipped" in res
    assert json.loads(out.read_text())["skipped"] == res["skipped"]


def _finite(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and np.isfinite(x)


@pytest.mark.slow
def test_quick_study_scores_every_method_at_every_s(bandai_root, tmp_path):
    out = tmp_path / "study.json"
    res = study.run(True, root=bandai_root, out=out)
    saved = json.loads(out.read_text())                        # strict JSON (no NaN)
    assert saved["mode"] == "quick" and saved["methods"] == list(study.METHODS)
    assert saved["s_values"] == list(study.S_VALUES)
    (pair,) = saved["pairs"]
    assert set(pair["methods"]) == set(study.METHODS)
    for method, block in pair["methods"].items():
        assert [o["s"] for o in block["outputs"]] == list(study.S_VALUES), method
        for o in block["outputs"]:
            assert "error" not in o, (method, o)
            assert 0.0 <= o["classifier"]["p_target"] <= 1.0
            assert _finite(o["strength"]["raw"]) and _finite(o["strength"]["normalised"])
            for k in study.NATURALNESS_KEYS:
                assert _finite(o["naturalness"][k]), (method, o["s"], k)
            inf = o["infer_emotion"]
            assert inf in ("not available", "not run at this s") or _finite(inf["target_mean"])
        s = block["summary"]
        for k in ("strength_spearman", "strength_monotonicity", "strength_calibration_error",
                  "extrapolation_gain", "mean_jerk_ratio", "mean_foot_sliding_ratio"):
            assert _finite(s[k]), (method, k)
    # the H-GPDM extrapolates off the simplex only at s = 1.25
    flags = [o["extrapolated"] for o in pair["methods"]["hgpdm"]["outputs"]]
    assert flags == [s > 1 for s in study.S_VALUES]
    # Amaya at s = 0 is the identity transform: the real neutral clip's scores, strength 0
    amaya0, real0 = pair["methods"]["amaya"]["outputs"][0], pair["real"]["neutral"]
    assert amaya0["strength"]["normalised"] == pytest.approx(0.0, abs=1e-9)
    assert amaya0["classifier"]["p_target"] == pytest.approx(real0["classifier"]["p_target"])
    assert pair["real"]["emotion"]["strength"]["normalised"] == pytest.approx(1.0)
    # one pair: the summary is that pair's; the verdict follows the criteria
    c = study.CRITERIA
    for method in study.METHODS:
        agg, one = saved["summary"][method], pair["methods"][method]["summary"]
        assert agg["strength_spearman"] == pytest.approx(one["strength_spearman"])
        assert agg["interpolates_emotion"] == (
            agg["strength_spearman"] >= c["spearman_min"]
            and agg["strength_monotonicity"] >= c["monotonicity_min"]
            and agg["strength_calibration_error"] <= c["calibration_error_max"])
        assert method in saved["conclusion"]
    assert res["headline"] and len(res["headline"]) == len(study.METHODS)
    table = study.markdown_table(saved).splitlines()
    assert len(table) == 2 + len(study.METHODS) + 2  # header, rule, methods, blank, conclusion
    for method, row in zip(study.METHODS, table[2:], strict=False):
        verdict = "yes" if saved["summary"][method]["interpolates_emotion"] else "no"
        assert row.startswith(f"| {method} | 1 |") and row.endswith(f"| {verdict} |")


def test_the_readme_table_is_the_committed_full_study_output():
    """The results page's study table must be the one rendered from results/study_interpolation.json
    (python benchmarks/study_interpolation.py --table), not typed by hand."""
    root = Path(__file__).resolve().parents[1]
    path = root / "benchmarks" / "results" / "study_interpolation.json"
    if not path.exists():
        pytest.skip("no committed study result")
    result = json.loads(path.read_text())
    assert result["mode"] == "full", "the committed study result must come from a full run"
    assert study.markdown_table(result) in (root / "docs" / "results.md").read_text()
