"""Label-probability calibration metrics: ECE, reliability bins, label sets, confident errors,
and what a calibrated posterior would score on the same clips."""

import numpy as np
import pytest
from scipy import stats

from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.calibration import (
    calibration_consistency,
    expected_calibration_error,
    label_calibration,
    reliability,
)

P4 = np.array([[0.9, 0.1], [0.62, 0.38], [0.8, 0.2], [0.55, 0.45]])
T4 = np.array([0, 1, 0, 0])


def test_ece_hand_computed():
    # one clip per bin: |accuracy - confidence| = .1, .62, .2, .45
    assert expected_calibration_error(P4, T4) == pytest.approx((0.1 + 0.62 + 0.2 + 0.45) / 4)
    bins = reliability(P4, T4)
    assert [b["count"] for b in bins] == [1, 1, 1, 1]
    assert [b["lower"] for b in bins] == pytest.approx([0.5, 0.6, 0.8, 0.9])


def test_ece_pools_within_a_bin():
    # two clips in the 0.9 bin, one right: accuracy .5 against confidence .925
    p = np.array([[0.9, 0.1], [0.05, 0.95]])
    assert expected_calibration_error(p, np.array([0, 0])) == pytest.approx(0.425)
    # a confidence of exactly 1 lands in the top bin
    assert reliability(np.array([[1.0, 0.0]]), np.array([1]))[0]["upper"] == 1.0


def test_calibrated_probabilities_score_near_zero_and_overconfident_ones_do_not():
    rng = np.random.default_rng(0)
    n, K = 20000, 4
    p = rng.dirichlet(np.ones(K) * 0.7, n)
    truth = np.array([rng.choice(K, p=row) for row in p])  # drawn from the probabilities
    cal = label_calibration(p, truth)
    # the Monte-Carlo error of ECE with 10 bins and 20,000 clips is ~0.01
    assert cal["ece"] < 0.02
    # label sets are discrete: they cover at the mean probability they hold (>= 0.9)
    order = np.sort(p, 1)[:, ::-1].cumsum(1)
    held = order[np.arange(n), np.argmax(order >= 0.9, 1)].mean()
    assert held >= 0.9
    assert cal["label_set_coverage"] == pytest.approx(held, abs=0.01)
    sharp = np.eye(K)[np.argmax(p, 1)]  # the same answers, every one with P = 1
    bad = label_calibration(sharp, truth)
    assert bad["accuracy"] == cal["accuracy"]
    assert bad["ece"] == pytest.approx(1 - cal["accuracy"])
    assert bad["confident_wrong"] == pytest.approx(1 - cal["accuracy"])
    assert bad["label_set_coverage"] == pytest.approx(cal["accuracy"])


def test_label_sets_brier_and_log_score():
    p = np.array([[0.5, 0.45, 0.05], [0.2, 0.3, 0.5]])
    cal = label_calibration(p, np.array([1, 0]), q=0.9)
    # sets: {0, 1} (0.95) and {2, 1, 0}: both hold the truth
    assert cal["label_set_coverage"] == 1.0
    assert cal["label_set_mean_size"] == 2.5
    assert cal["accuracy"] == 0.0
    assert cal["log_score"] == pytest.approx(np.mean(np.log([0.45, 0.2])))
    assert cal["brier"] == pytest.approx(np.mean([0.25 + 0.55**2 + 0.0025,
                                                  0.64 + 0.09 + 0.25]))


@pytest.mark.parametrize("p, t, match", [
    (np.array([0.5, 0.5]), np.array([0]), "n clips"),
    (np.array([[0.5, 0.6]]), np.array([0]), "sum to 1"),
    (np.array([[0.5, 0.5]]), np.array([2]), "level indices"),
    (np.array([[0.5, 0.5]]), np.array([0.0]), "level indices"),
])
def test_bad_input_is_named(p, t, match):
    with pytest.raises(BayesmotionError, match=match):
        label_calibration(p, t)


def test_a_calibrated_ece_on_one_bin_is_the_binomial_deviation():
    # 16 clips, all at confidence 0.9 (one bin): a calibrated posterior gets X ~ Bin(16, 0.9)
    # right, so its ECE is |X / 16 - 0.9| and the bin's accuracy is X / 16
    p = np.tile([0.9, 0.1], (16, 1))
    truth = np.zeros(16, int)
    truth[:2] = 1  # 14 of 16 right: accuracy 0.875
    c = calibration_consistency(p, truth, n_draws=20000, level=0.9, seed=3)
    x = np.arange(17)
    dev, w = np.abs(x / 16 - 0.9), stats.binom.pmf(x, 16, 0.9)
    assert c["ece"] == pytest.approx(0.025)
    # the mean's Monte-Carlo sd with 20,000 replicates is ~0.0003
    assert c["ece_if_calibrated"]["mean"] == pytest.approx(np.sum(w * dev), abs=0.0015)
    assert c["p_value"] == pytest.approx(np.sum(w[dev >= 0.025 - 1e-12]), abs=0.01)
    assert c["p_value"] > 0  # (1 + count) / (1 + draws): never 0
    lo, hi = stats.binom.ppf([0.05, 0.95], 16, 0.9) / 16
    assert c["bins"][0]["accuracy_interval"] == pytest.approx([lo, hi])
    assert c["bins"][0]["count"] == 16 and c["bins"][0]["accuracy"] == 0.875


def test_calibrated_answers_are_rarely_rejected_and_overconfident_ones_are():
    rng = np.random.default_rng(0)
    pvals = []
    for _ in range(200):  # data calibrated by construction: p-values about uniform
        p = rng.dirichlet(np.ones(4) * 0.5, 16)
        truth = np.array([rng.choice(4, p=row) for row in p])
        pvals.append(calibration_consistency(p, truth, n_draws=400, seed=1)["p_value"])
    # a discrete statistic: at most its nominal rate, within 3 binomial sd of 200 data sets
    assert np.mean(np.array(pvals) < 0.1) < 0.1 + 3 * np.sqrt(0.09 / 200)
    assert 0.3 < np.median(pvals) < 0.7
    # every answer given with P = 0.99 at accuracy 0.8 (40 clips)
    p = np.tile([0.99, 0.01 / 3, 0.01 / 3, 0.01 / 3], (40, 1))
    truth = np.r_[np.zeros(32, int), np.ones(8, int)]
    bad = calibration_consistency(p, truth, seed=2)
    assert bad["p_value"] < 0.01
    assert bad["ece"] > bad["ece_if_calibrated"]["interval"][1]
    assert bad["bins"][0]["accuracy"] < bad["bins"][0]["accuracy_interval"][0]


def test_label_calibration_reports_the_calibrated_ece_beside_the_observed():
    cal = label_calibration(P4, T4)
    c = calibration_consistency(P4, T4)
    assert cal["ece_if_calibrated"] == c["ece_if_calibrated"]
    assert cal["ece_p_value"] == c["p_value"]
    # four clips at confidence 0.55-0.9: a calibrated posterior's ECE is far from 0 there
    assert c["ece_if_calibrated"]["mean"] > 0.15


@pytest.mark.parametrize("kw, match", [({"n_draws": 0}, "n_draws"), ({"n_draws": 2.5}, "n_draws"),
                                       ({"level": 1.0}, "level")])
def test_consistency_names_bad_settings(kw, match):
    with pytest.raises(BayesmotionError, match=match):
        calibration_consistency(P4, T4, **kw)


def test_each_bin_gets_its_own_binomial_bar():
    # 10 clips at 0.95 and 6 at 0.65 (two bins): each bar is its own binomial's 5-95% range
    p = np.r_[np.tile([0.95, 0.05], (10, 1)), np.tile([0.65, 0.35], (6, 1))]
    truth = np.zeros(16, int)
    c = calibration_consistency(p, truth, n_draws=20000, seed=4)
    assert [b["count"] for b in c["bins"]] == [6, 10]  # ascending confidence
    for b, (n, q) in zip(c["bins"], [(6, 0.65), (10, 0.95)], strict=True):
        assert b["accuracy_interval"] == pytest.approx(stats.binom.ppf([0.05, 0.95], n, q) / n)
    # all right: observed ECE (6 * 0.35 + 10 * 0.05) / 16; its exact p-value by enumeration
    assert c["ece"] == pytest.approx((6 * 0.35 + 10 * 0.05) / 16)
    x1, x2 = np.meshgrid(np.arange(7), np.arange(11), indexing="ij")
    ece = (np.abs(x1 - 6 * 0.65) + np.abs(x2 - 10 * 0.95)) / 16
    w = stats.binom.pmf(x1, 6, 0.65) * stats.binom.pmf(x2, 10, 0.95)
    assert c["p_value"] == pytest.approx(w[ece >= c["ece"] - 1e-12].sum(), abs=0.01)


def test_label_calibration_can_leave_the_resampling_out():
    cal = label_calibration(P4, T4, n_draws=0)
    assert cal["ece_if_calibrated"] is None and cal["ece_p_value"] is None
    assert cal["ece"] == expected_calibration_error(P4, T4)


def test_a_flat_answer_is_scored_as_the_label_it_reports():
    # clip 0 is shrunk to the flat prior; its first tied level is the truth, but it answers
    # level 2 (the one its evidence favoured): scored as answered it is wrong at P = 1/3
    p = np.array([[1 / 3, 1 / 3, 1 / 3], [0.1, 0.8, 0.1]])
    truth = np.array([0, 1])
    first = label_calibration(p, truth, n_draws=0)
    answered = label_calibration(p, truth, n_draws=0, labels=np.array([2, 1]))
    assert first["accuracy"] == 1.0
    assert answered["accuracy"] == 0.5
    # bins: (1/3, wrong) and (0.8, right): |0 - 1/3| / 2 + |1 - 0.8| / 2
    assert answered["ece"] == pytest.approx((1 / 3 + 0.2) / 2)
    assert first["ece"] == pytest.approx((2 / 3 + 0.2) / 2)
    assert [b["accuracy"] for b in reliability(p, truth, labels=[2, 1])] == [0.0, 1.0]
    c = calibration_consistency(p, truth, n_draws=200, labels=np.array([2, 1]))
    assert c["ece"] == pytest.approx(answered["ece"])
    # the labels that equal the argmax change nothing
    same = label_calibration(P4, T4, n_draws=0, labels=np.argmax(P4, 1))
    assert same == label_calibration(P4, T4, n_draws=0)


@pytest.mark.parametrize("labels, match", [
    (np.array([1, 1, 0, 0]), "less probable level"),  # clip 0 answers its 0.1 level
    (np.array([0, 0, 0]), r"\(4,\) level indices"),
    (np.array([0, 2, 0, 0]), "level indices"),
    (np.array([0.0, 0.0, 0.0, 0.0]), "level indices"),
])
def test_answers_that_are_not_top_levels_are_refused(labels, match):
    with pytest.raises(BayesmotionError, match=match):
        label_calibration(P4, T4, n_draws=0, labels=labels)
