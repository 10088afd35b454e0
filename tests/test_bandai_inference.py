"""The real-clip inference benchmark (benchmarks/bandai_inference.py) at reduced size."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import bandai_inference  # noqa: E402
from _common import write_json  # noqa: E402


def test_missing_data_is_a_skip_record(tmp_path):
    res = bandai_inference.run(True, root=tmp_path / "absent")
    assert "skipped" in res and res["headline"] == []


@pytest.mark.slow
def test_quick_leave_one_clip_out_on_real_walks(bandai_root, tmp_path):
    res = bandai_inference.run(True, root=bandai_root)
    write_json(tmp_path / "r.json", res)
    saved = json.loads((tmp_path / "r.json").read_text())  # strict JSON
    r = saved["result"]
    assert len(r["trials"]) == len(saved["clips"]) == 8  # quick: two walk contents
    # canonical side, from positions alone: exactly the four walks to the right are mirrored
    assert sorted(saved["mirrored"]) == sorted(c for c in saved["clips"] if "walk-right" in c)
    levels = r["levels"]
    assert sorted(levels) == ["angry", "happy", "neutral", "sad"]
    C = np.asarray(r["confusion_percent"])
    np.testing.assert_allclose(C.sum(0), 100.0)  # intended emotions in columns
    true = [t["true"] for t in r["trials"]]
    pred = [t["pred"] for t in r["trials"]]
    hit = [a == b for a, b in zip(true, pred, strict=True)]
    assert r["accuracy"] == pytest.approx(np.mean(hit))
    # the quick folds (walk-left and walk-right, each the other's mirror image once the codec
    # puts both on one side) read 8 of 8 right; far above chance (2 of 8) either way
    assert r["accuracy"] >= 0.75
    for t in r["trials"]:
        assert t["pred"] in levels and len(t["probabilities"]) == 4
    # the diagonal: the share of each intended emotion inferred correctly
    hits = [np.mean([p == t for t, p in zip(true, pred, strict=True) if t == e]) for e in levels]
    np.testing.assert_allclose(np.diag(C), 100 * np.asarray(hits))
    # the coverages are the per-clip flags averaged
    assert r["coverage"] == pytest.approx(np.mean([t["covered"] for t in r["trials"]]))
    assert r["label_set_coverage"] == pytest.approx(
        np.mean([t["true"] in t["label_set"] for t in r["trials"]]))
    assert r["interval_coverage"] == pytest.approx(
        np.mean([t["intervals_cover"] for t in r["trials"]]))
    assert set(r["baselines"]) == {"affective_features", "affective_features_by_content",
                                   "relative_strength", "mean_pose_nn"}
    assert [h["metric"].strip()[:6] for h in saved["headline"]] == \
        ["H-GPDM", "label ", "label ", "coordi", "affect", "affect", "relati", "mean-p",
         "second", "other "]
    fo = saved["foreign_actions"]  # quick: the four clips of one other action
    assert fo["n"] == 4 and len(fo["clips"]) == 4
    assert fo["flagged"] == pytest.approx(np.mean([c["flagged"] for c in fo["clips"]]))
    # the label metrics are those of the trials' probabilities
    idx = np.array([levels.index(t) for t in true])
    P = np.array([t["probabilities"] for t in r["trials"]])
    assert r["label_calibration"]["accuracy"] == pytest.approx(r["accuracy"])
    assert r["label_calibration"]["confident_wrong"] == pytest.approx(
        np.mean((np.argmax(P, 1) != idx) & (P.max(1) >= 0.99)))
    # the recording effect softens the answers but never changes a label
    Q = np.array([t["evidence_calibrated"]["probabilities"] for t in r["trials"]])
    np.testing.assert_array_equal(np.argmax(Q, 1), np.argmax(P, 1))
    assert r["evidence"]["label_calibration"]["accuracy"] == pytest.approx(r["accuracy"])
    assert saved["headline"][2]["value"] == pytest.approx(
        r["evidence"]["label_calibration"]["ece"])
    assert r["baseline_label_calibration"]["affective_features"]["accuracy"] == pytest.approx(
        r["baselines"]["affective_features"])
    cal = r["calibrated"]
    assert "error" not in cal  # the quick folds reach the coverage at some likelihood power
    assert cal["coverage"] == pytest.approx(np.mean([t["calibrated"]["covered"]
                                                     for t in r["trials"]]))


@pytest.fixture(scope="module")
def all_contents_quick(bandai_root):
    """The quick all-contents run of the exact model, shared by the two tests that read it."""
    return bandai_inference.run(True, root=bandai_root, all_contents=True)


@pytest.mark.slow
def test_quick_all_contents_run_pools_the_contents(all_contents_quick):
    res = all_contents_quick
    r = res["result"]
    assert res["name"] == "bandai_inference_all"
    assert {c.split("_")[1] for c in res["clips"]} == {"walk-left", "bow"}
    assert len(r["trials"]) == 8 and "calibrated" not in r  # the labels' calibration only
    assert r["true_level_unseen_rate"] == 0.0  # no content factor: every emotion was seen
    assert [h["metric"].strip()[:6] for h in res["headline"]] == \
        ["H-GPDM", "label ", "label ", "affect", "affect", "relati", "mean-p", "second"]


@pytest.mark.slow
def test_quick_sparse_relative_run_fits_that_model(bandai_root, all_contents_quick):
    res = bandai_inference.run(True, root=bandai_root, all_contents=True, inducing=6,
                               relative_to="content")
    assert res["name"] == "bandai_inference_all_sparse6_relative"
    assert res["settings"]["inducing"] == 6 and res["spec"]["inducing"] == 6
    assert res["settings"]["relative_to"] == res["spec"]["relative_to"] == "content"
    assert len(res["result"]["trials"]) == 8
    # every held-out clip's content is in its fold: answered from the evidence, not the prior
    assert not all(np.allclose(t["probabilities"], 0.25) for t in res["result"]["trials"])
    exact = all_contents_quick
    assert exact["spec"]["inducing"] is None and exact["settings"]["inducing"] is None
    assert exact["spec"]["relative_to"] is None
    # the same folds, a different model: the answers' probabilities differ
    P = [t["probabilities"] for t in res["result"]["trials"]]
    Q = [t["probabilities"] for t in exact["result"]["trials"]]
    assert not np.allclose(P, Q)


@pytest.mark.slow
def test_quick_content_factor_run_flags_every_held_out_emotion(bandai_root):
    res = bandai_inference.run(True, root=bandai_root, all_contents=True, inducing=6,
                               content_factor=True, fit_iter=8, refit_iter=4)
    assert res["name"] == "bandai_inference_all_sparse6_content_factor_fit8_4"
    assert (res["settings"]["max_iter"], res["settings"]["refit_iter"]) == (8, 4)
    # below the quick settings' own 20 and 5: the lengths given are the ones run
    assert res["full_fit"]["iterations"] <= 8 and res["result"]["refit_iter"] == 4
    assert res["spec"]["interaction_factors"] == res["spec"]["dynamics_factors"] == \
        ["content", "emotion"]
    r = res["result"]
    # leave-one-clip-out takes the held-out clip's (content, emotion) cell out of training
    assert r["true_level_unseen_rate"] == 1.0
    for t in r["trials"]:
        assert t["unseen_levels"][t["true"]] == ["interaction", "dynamics"]


def test_result_names_say_the_options():
    assert bandai_inference.result_name() == "bandai_inference"
    assert bandai_inference.result_name(True, 0.02, 3, 100) == \
        "bandai_inference_all_sparse100_starts3"
    assert bandai_inference.result_name(inducing=100) == "bandai_inference_sparse100"
    assert bandai_inference.result_name(True, inducing=100, projection_iter=400,
                                        relative_to="content") == \
        "bandai_inference_all_sparse100_iter400_relative"
    assert bandai_inference.result_name(True, inducing=100, projection_iter=400,
                                        content_factor=True) == \
        "bandai_inference_all_sparse100_iter400_content_factor"
    # the fit lengths: the one not given keeps the full settings' (300 full, 100 per fold),
    # and those two name no file of their own
    assert bandai_inference.result_name(True, inducing=100, projection_iter=400,
                                        relative_to="content", fit_iter=1500,
                                        refit_iter=300) == \
        "bandai_inference_all_sparse100_iter400_relative_fit1500_300"
    assert bandai_inference.result_name(fit_iter=600) == "bandai_inference_fit600_100"
    assert bandai_inference.result_name(refit_iter=50) == "bandai_inference_fit300_50"
    assert bandai_inference.result_name(fit_iter=300) == "bandai_inference"
    assert bandai_inference.result_name(True, fit_iter=300, refit_iter=100) == \
        "bandai_inference_all"


def test_result_names_say_the_crop():
    # the mode's own crop (60 frames of the walks, 40 of the 40 clips) names no file of its own
    assert bandai_inference.result_name(model_frames=60) == "bandai_inference"
    assert bandai_inference.result_name(True, model_frames=40) == "bandai_inference_all"
    assert bandai_inference.result_name(True, model_frames=60) == "bandai_inference_all_frames60"
    assert bandai_inference.result_name(True, inducing=100, projection_iter=400,
                                        relative_to="content", model_frames=0) == \
        "bandai_inference_all_sparse100_iter400_relative_frameswhole"


def test_crops_below_four_frames_are_refused(capsys):
    for value in ("-1", "1", "3"):
        with pytest.raises(SystemExit):
            bandai_inference.main(["--model-frames", value])
        assert f"--model-frames must be 0 (whole clips) or at least 4, got {value}" in \
            capsys.readouterr().err


def test_whole_clips_keep_every_frame(bandai_root):
    from bayesmotion.datasets.bandai import load_bandai

    cfg = dict(bandai_inference.ALL, contents=("bow",))
    cropped = bandai_inference._clips(cfg, bandai_root, "clips")
    whole = bandai_inference._clips({**cfg, "model_frames": None}, bandai_root, "clips")
    raw = load_bandai(bandai_root, content=("bow",), fps=cfg["fps"])
    assert [t.n_frames for t in whole] == [t.n_frames for t in raw]
    assert [t.n_frames for t in cropped] == [min(t.n_frames, 40) for t in raw]
    assert max(t.n_frames for t in whole) > 40  # the crop shortens at least one bow
    assert whole.levels["emotion"] == cropped.levels["emotion"]


def test_fit_lengths_below_one_are_refused(capsys):
    for flag in ("--fit-iter", "--refit-iter"):
        with pytest.raises(SystemExit):
            bandai_inference.main([flag, "0"])
        assert f"{flag} must be at least 1, got 0" in capsys.readouterr().err


def test_inducing_below_two_is_refused(capsys):
    with pytest.raises(SystemExit):
        bandai_inference.main(["--inducing", "1"])
    assert "--inducing must be at least 2" in capsys.readouterr().err
    for argv in (["--content-factor"], ["--all-contents", "--content-factor", "--relative-to",
                                        "content"]):
        with pytest.raises(SystemExit):
            bandai_inference.main(argv)
        assert "--content-factor needs --all-contents" in capsys.readouterr().err


def test_baselines_alone_on_both_sets_of_folds(bandai_root):
    from bayesmotion.baselines.classifier import GroupCentred, trial_features

    res = bandai_inference.baselines_only(bandai_root)
    assert res["name"] == "bandai_baselines"
    assert len(res["walks"]["clips"]) == 16 and len(res["all"]["clips"]) == 40
    clips = bandai_inference._clips(bandai_inference.FULL, bandai_root, "walks")
    X = trial_features(clips)
    y = np.array(clips.labels("emotion"))
    g = np.array([t.labels["content"] for t in clips])
    manual = [GroupCentred().fit(np.delete(X, i, 0), np.delete(y, i), np.delete(g, i))
              .predict(X[i:i + 1], g[i:i + 1])[0] for i in range(len(y))]
    walks = res["walks"]
    assert walks["predictions"]["affective_features_by_content"] == manual
    for part in (walks, res["all"]):
        truth = [c.split("_")[2] for c in part["clips"]]  # dataset-1_<content>_<style>_001
        truth = [{"normal": "neutral"}.get(s, s) for s in truth]
        for k, pred in part["predictions"].items():
            assert part["accuracy"][k] == pytest.approx(
                np.mean([p == t for p, t in zip(pred, truth, strict=True)]))
        assert part["label_calibration"]["affective_features_by_content"]["accuracy"] == \
            pytest.approx(part["accuracy"]["affective_features_by_content"])
    assert [h["value"] for h in res["headline"]] == pytest.approx(
        [100 * walks["accuracy"]["affective_features_by_content"],
         100 * res["all"]["accuracy"]["affective_features_by_content"]])
