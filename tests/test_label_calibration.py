"""Label-probability calibration metrics: ECE, reliability bins, label sets, confident errors."""

import numpy as np
import pytest

from bayesmotion.errors import BayesmotionError
from bayesmotion.evaluation.calibration import (
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
