"""The label posterior with a recording effect (bayesmotion.emotion.evidence): the power on the
evidence, its calibration from held-out recordings, and coverage on a synthetic population with
a known between-recording spread."""

import numpy as np
import pytest

from bayesmotion.emotion.evidence import (
    calibrate_effective_frames,
    calibrate_evidence,
    evidence_power,
    level_posterior,
)
from bayesmotion.emotion.result import top_level
from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.calibration import label_calibration


def test_power_is_the_random_effect_shrinkage():
    assert evidence_power(10, np.inf) == 1.0
    assert evidence_power(30, 10.0) == pytest.approx(0.25)
    assert evidence_power(1, 1e9) == pytest.approx(1.0)
    with pytest.raises(BayesmotionError, match="must be > 0"):
        evidence_power(10, 0.0)
    with pytest.raises(BayesmotionError, match="must be > 0"):
        evidence_power(10, float("nan"))


def test_level_posterior_is_a_tempered_softmax():
    L = np.array([-10.0, -12.0, -20.0])
    lp = np.log([0.5, 0.25, 0.25])
    p = level_posterior(L, lp, 0.5)
    want = np.exp(0.5 * L + lp)
    np.testing.assert_allclose(p, want / want.sum())
    with pytest.raises(BayesmotionError, match="finite"):
        level_posterior([0.0, np.inf], [0.0, 0.0])


def _population(rng, n, T, mu, tau, sigma):
    """n recordings of T frames: level k, recording mean mu_k + N(0, tau^2), frames around it
    with sd sigma; returns the fixed-style model's evidence (n, K) and the levels."""
    K = len(mu)
    k = rng.integers(0, K, n)
    m = mu[k] + rng.normal(0, tau, n)
    ybar = m + rng.normal(0, sigma / np.sqrt(T), n)  # the frames enter through their mean
    # sum_t log N(y_t | mu_j, sigma^2) = -T (ybar - mu_j)^2 / (2 sigma^2) + (terms alike in j)
    L = -T * (ybar[:, None] - mu[None]) ** 2 / (2 * sigma**2)
    return L, k, ybar


def test_synthetic_recording_effect_is_recovered_and_label_sets_cover():
    """Between-recording sd tau = 0.5, within sd sigma = 2: n_eff = sigma^2 / tau^2 = 16 frames.
    The fixed-style evidence of 200-frame recordings is decisive and often wrong; the calibrated
    one matches the exact hierarchical posterior and its 90% label sets cover at their rate."""
    rng = np.random.default_rng(0)
    mu = np.array([0.0, 0.6, 1.2])
    tau, sigma, T = 0.5, 2.0, 200
    L, k, _ = _population(rng, 400, T, mu, tau, sigma)
    cal = calibrate_effective_frames(L, np.full(400, T), k)
    # the grid's step is 10^0.05; the log score is flat near its optimum: within a factor 2
    assert 8.0 <= cal["n_eff"] <= 32.0
    assert cal["log_score"] > cal["log_score_plain"] + 1.0
    # fresh recordings
    L2, k2, ybar = _population(rng, 4000, T, mu, tau, sigma)
    plain = np.array([level_posterior(l, np.zeros(3)) for l in L2])
    eta = evidence_power(T, cal["n_eff"])
    weighed = np.array([level_posterior(l, np.zeros(3), eta) for l in L2])
    exact = np.exp(-(ybar[:, None] - mu[None]) ** 2 / (2 * (tau**2 + sigma**2 / T)))
    exact /= exact.sum(1, keepdims=True)
    assert np.max(np.abs(weighed - exact)) < 0.1
    good, bad = label_calibration(weighed, k2), label_calibration(plain, k2)
    assert good["accuracy"] == bad["accuracy"]  # the power never changes the label
    assert good["ece"] < 0.03 < 0.15 < bad["ece"]
    # 4,000 recordings: the Monte-Carlo sd of a coverage near 0.9 is 0.005
    exact_cal = label_calibration(exact, k2)
    assert good["label_set_coverage"] == pytest.approx(exact_cal["label_set_coverage"], abs=0.02)
    assert good["label_set_coverage"] >= 0.88
    assert bad["confident_wrong"] > 0.1 and good["confident_wrong"] < 0.02


def test_no_recording_effect_keeps_the_plain_evidence():
    """tau = 0: the fixed-style model is right, and the calibration keeps (nearly) eta = 1."""
    rng = np.random.default_rng(1)
    mu = np.array([0.0, 0.3])
    L, k, _ = _population(rng, 600, 20, mu, 0.0, 2.0)
    cal = calibrate_effective_frames(L, np.full(600, 20), k)
    assert evidence_power(20, cal["n_eff"]) > 0.7
    assert cal["log_score"] >= cal["log_score_plain"] - 0.5 / 600


def test_all_right_answers_stop_at_the_supported_confidence():
    """Perfect separation has no finite maximum; the answer is the cautious end of the
    likelihood-ratio interval, and so finite."""
    L = np.array([[0.0, -50.0], [-60.0, 0.0], [0.0, -40.0]])
    cal = calibrate_effective_frames(L, np.array([10, 10, 10]), np.array([0, 1, 0]))
    assert cal["n_eff"] < 1e7
    total = cal["log_score"] * 3
    assert total >= cal["log_score_best"] * 3 - 0.5 - 1e-9


@pytest.mark.parametrize("args, match", [
    (([[0.0, 1.0]], [5], [0]), "n clips >= 2"),
    (([[0.0, 1.0], [0.0, np.nan]], [5, 5], [0, 1]), "finite"),
    (([[0.0, 1.0], [0.0, 1.0]], [5, 0], [0, 1]), "positive frame counts"),
    (([[0.0, 1.0], [0.0, 1.0]], [5, 5], [0, 2]), "level indices"),
])
def test_bad_calibration_input_is_named(args, match):
    with pytest.raises(BayesmotionError, match=match):
        calibrate_effective_frames(*args)


# ---------------------------------------------------------------- through infer_emotion


def test_infinite_effective_frames_is_the_fixed_style_model(tiny_model):
    """n_eff = inf (an uncalibrated model) answers with the plain Laplace evidence of the
    levels: the fixed-style model's probabilities; a finite n_eff keeps the label and softens
    the answer exactly as the power says."""
    import bayesmotion as bm

    from .conftest import make_tiny_dataset

    trial = make_tiny_dataset().trials[0]
    plain = bm.infer_emotion(tiny_model, trial, n_steps=60)
    assert plain.info["evidence_power"] == 1.0 and not plain.info["evidence_calibrated"]
    w = plain.info["in_distribution_weight"]
    prior = np.asarray(plain.info["level_prior"])
    np.testing.assert_allclose(plain.probabilities,
                               w * np.asarray(plain.info["level_probabilities"])
                               + (1 - w) * prior, atol=1e-12)
    soft = bm.infer_emotion(tiny_model, trial, n_steps=60, effective_frames=0.05)
    T = soft.info["n_frames"]
    eta = 0.05 / (0.05 + T)
    assert soft.info["evidence_power"] == pytest.approx(eta)
    want = w * level_posterior(soft.info["level_log_evidence"], np.log(prior), eta) \
        + (1 - w) * prior
    np.testing.assert_allclose(soft.probabilities, want, atol=1e-12)
    assert soft.label == plain.label
    assert soft.entropy > plain.entropy
    with pytest.raises(BayesmotionError, match="effective_frames"):
        bm.infer_emotion(tiny_model, trial, effective_frames=-1.0)


@pytest.mark.slow
def test_calibrated_model_keeps_its_effective_frames_in_its_file(tiny_model, tmp_path):
    import bayesmotion as bm
    from bayesmotion.evaluation.evaluate import leave_one_out

    from .conftest import make_tiny_dataset

    data = make_tiny_dataset()
    res = leave_one_out(data, tiny_model, refit_iter=10, n_steps=60, calibrate=True,
                        baselines=False)
    ev = res["evidence"]
    assert len(ev["label_calibration"]["reliability"]) >= 1
    assert 0 <= res["label_calibration"]["ece"] <= 1
    for r in res["trials"]:  # cross-fitted: each trial's n_eff from the others alone
        assert r["evidence_calibrated"]["n_eff"] > 0
        assert sum(r["evidence_calibrated"]["probabilities"]) == pytest.approx(1.0)
    model = calibrate_evidence(tiny_model, res)
    assert model.calibration["effective_frames"] == ev["n_eff_all_trials"]
    assert tiny_model.calibration == {}  # the original is unchanged
    model.save(tmp_path / "m.npz")
    again = bm.load(tmp_path / "m.npz")
    assert again.calibration == model.calibration
    ep = bm.infer_emotion(again, data.trials[0], n_steps=60)
    assert ep.info["evidence_calibrated"]
    assert ep.info["effective_frames"] == model.calibration["effective_frames"]
    with pytest.raises(BayesmotionError, match="level evidence"):
        calibrate_evidence(tiny_model, {"trials": [{"level_log_evidence": None}]})


@pytest.mark.slow
def test_cli_evaluate_calibrates_and_saves_the_model(tmp_path, capsys):
    """``bayesmotion evaluate --calibrate --save-calibrated OUT`` prints the label
    probabilities' calibration and writes a model that infer then uses."""
    import bayesmotion as bm
    from bayesmotion.app.cli import main
    from bayesmotion.datasets.loaders import load_data

    from .conftest import make_tiny_dataset

    folder = tmp_path / "data"
    folder.mkdir()
    rows = ["file,emotion,couple,trial,actor"]
    for t in make_tiny_dataset():
        for a, m in enumerate(t.actors):
            bm.write_bvh(m, folder / f"{t.name}_{a}.bvh")
            rows.append(f"{t.name}_{a}.bvh,{t.labels['emotion']},c1,{t.name},{a}")
    (folder / "labels.csv").write_text("\n".join(rows) + "\n")
    data = load_data(str(folder), 5.0)
    bm.HGPDM(latent_dim=3, interaction_dim=3).fit(data, max_iter=40, progress=False).save(
        tmp_path / "m.npz")
    capsys.readouterr()
    # several level starts need a jitter: refused before any fold is refitted
    assert main(["evaluate", str(tmp_path / "m.npz"), str(folder), "--level-starts", "2"]) != 0
    assert "--level-starts > 1 needs --start-jitter > 0" in capsys.readouterr().err
    code = main(["evaluate", str(tmp_path / "m.npz"), str(folder), "--refit-iter", "5",
                 "--calibrate", "--save-calibrated", str(tmp_path / "c.npz")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "label probabilities: ECE" in out and "recording effect" in out
    model = bm.load(tmp_path / "c.npz")
    assert model.calibration["effective_frames"] > 0
    assert f"{model.calibration['effective_frames']:.3g}" in out


def test_minus_infinite_evidence_is_probability_zero():
    p = level_posterior([-np.inf, -3.0, -5.0], np.zeros(3), 0.5)
    assert p[0] == 0.0 and p[1:].sum() == pytest.approx(1.0)
    with pytest.raises(BayesmotionError, match="at least one finite"):
        level_posterior([-np.inf, -np.inf], np.zeros(2))


def test_a_flat_answer_keeps_the_label_the_evidence_favours():
    """A clip shrunk all the way to a flat prior ties every level; its label is not the first
    level but the one its evidence chose."""
    from bayesmotion.emotion.result import EmotionPosterior

    s = np.full((1, 4, 3), 1 / 3)
    ep = EmotionPosterior(("a", "b", "c"), s, {}, np.zeros((1, 4)),
                          info={"probabilities_in_distribution": [0.1, 0.2, 0.7]},
                          label_probabilities=np.full(3, 1 / 3))
    assert ep.label == "c" and ep.label_set(0.9) == ("a", "b", "c")


def test_stored_results_are_scored_as_answered():
    """score_labels summarises a leave-one-out result from its rows: a clip shrunk to the flat
    prior (weight 0) whose first level is the truth, but whose evidence (and so its reported
    label) favours another, counts as wrong, plain and with the recording effect."""
    from bayesmotion.evaluation.evaluate import score_labels

    levels = ["a", "b", "c"]
    rng = np.random.default_rng(0)
    rows = []
    for i in range(9):
        t = i % 3
        ev = rng.normal(0.0, 5.0, 3)
        ev[t] += 20.0
        rows.append({"true": levels[t], "level_log_evidence": ev.tolist(),
                     "level_prior": [1 / 3] * 3, "in_distribution_weight": 1.0,
                     "n_frames": 20})
    rows[0]["level_log_evidence"] = [0.0, -5.0, 30.0]  # truth "a"; the evidence says "c"
    rows[0]["in_distribution_weight"] = 0.0
    for r in rows:
        w = r["in_distribution_weight"]
        p = w * level_posterior(r["level_log_evidence"], np.log(r["level_prior"]), 1.0) \
            + (1 - w) * np.asarray(r["level_prior"])
        r["probabilities"] = p.tolist()
        r["pred"] = levels[top_level(p, r["level_log_evidence"])]
    assert rows[0]["pred"] == "c"
    res = {"levels": levels, "trials": rows, "credible_level": 0.9, "evidence": {}}
    out = score_labels(res)
    assert out["label_calibration"]["accuracy"] == pytest.approx(8 / 9)
    assert rows[0]["evidence_calibrated"]["label_index"] == 2
    assert out["evidence"]["label_calibration"]["accuracy"] == pytest.approx(8 / 9)
    assert "evidence" not in score_labels({k: v for k, v in res.items() if k != "evidence"})
