"""Relative emotion strength: curve simplification, PCA, RankSVM Newton vs SciPy."""

import numpy as np
import pytest
from scipy.optimize import minimize

import bayesmotion as bm
from bayesmotion.baselines.strength import (
    PCA,
    StrengthClassifier,
    fit_strength_features,
    keyframe_features_from_positions,
    ordered_pairs,
    ranking_accuracy,
    ranksvm_newton,
    ranksvm_objective,
    resample_rows,
    similar_pairs,
    simplify_curve,
)
from bayesmotion.features import SEMANTIC_JOINTS, JointMap


def polyline_error(Y, keys):
    """Distance of every frame from the linear interpolation through the keyframes."""
    interp = np.stack([np.interp(np.arange(len(Y)), keys, Y[keys, d]) for d in range(Y.shape[1])],
                      axis=1)
    return np.linalg.norm(Y - interp, axis=1)


def recursive_reference(Y, tol, i=0, j=None):
    """Lowe's recursion written plainly: split at the worst frame while its error >= tol."""
    j = len(Y) - 1 if j is None else j
    worst, at = -1.0, None
    for k in range(i + 1, j):
        u = (k - i) / (j - i)
        e = np.linalg.norm(Y[k] - ((1 - u) * Y[i] + u * Y[j]))
        if e > worst:
            worst, at = e, k
    if at is None or worst < tol:
        return {i, j}
    return recursive_reference(Y, tol, i, at) | recursive_reference(Y, tol, at, j)


def test_corners_of_a_polyline_are_found():
    t = np.arange(40.0)
    Y = np.stack([t, np.interp(t, [0, 10, 25, 39], [0, 8, -4, 3])], axis=1)   # corners 10, 25
    np.testing.assert_array_equal(simplify_curve(Y, tol=1e-9), [0, 10, 25, 39])
    assert list(simplify_curve(Y, n_keys=2)) == [0, 39]
    assert set(simplify_curve(Y, n_keys=3)) < {0, 10, 25, 39}


def test_tolerance_mode_keeps_endpoints_bounds_error_and_matches_recursion():
    rng = np.random.default_rng(0)
    Y = np.cumsum(rng.normal(size=(120, 3)), axis=0)
    for tol in (0.5, 2.0, 8.0):
        keys = simplify_curve(Y, tol=tol)
        assert keys[0] == 0 and keys[-1] == 119 and np.all(np.diff(keys) > 0)
        assert polyline_error(Y, keys).max() < tol
        assert set(keys.tolist()) == recursive_reference(Y, tol)
    k7 = simplify_curve(Y, n_keys=7)
    assert len(k7) == 7 and {0, 119} <= set(k7.tolist())


def test_simplify_errors():
    with pytest.raises(bm.BayesmotionError, match="exactly one of tol and n_keys"):
        simplify_curve(np.zeros((5, 2)))
    with pytest.raises(bm.BayesmotionError, match=r"n_keys must be in \[2, 5\]"):
        simplify_curve(np.zeros((5, 2)), n_keys=6)


def test_resample_rows_is_linear_in_the_index():
    X = np.array([[0.0, 10.0], [1.0, 20.0], [4.0, 30.0]])
    np.testing.assert_allclose(resample_rows(X, 5), [[0, 10], [0.5, 15], [1, 20], [2.5, 25],
                                                     [4, 30]])
    np.testing.assert_array_equal(resample_rows(X, 3), X)


def test_pca_matches_the_covariance_eigendecomposition():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(200, 4)) @ np.diag([5.0, 2.0, 1.0, 0.1]) @ np.linalg.qr(
        rng.normal(size=(4, 4)))[0]
    pca = PCA.fit(X, 4)
    evals, evecs = np.linalg.eigh(np.cov(X.T))
    np.testing.assert_allclose(pca.explained_variance, evals[::-1], rtol=1e-10)
    np.testing.assert_allclose(np.abs(pca.components @ evecs[:, ::-1]), np.eye(4), atol=1e-8)
    assert PCA.fit(X, 0.9).components.shape[0] == np.searchsorted(
        np.cumsum(evals[::-1]) / evals.sum(), 0.9) + 1


def test_pairs_follow_the_order_and_its_closure():
    labels = ["happy", "neutral", "sad", "angry", "happy"]
    order = [("happy", "neutral"), ("neutral", "sad"), ("angry", "neutral")]
    got = {tuple(p) for p in ordered_pairs(labels, order)}
    assert got == {(0, 1), (4, 1), (1, 2), (3, 1), (0, 2), (4, 2), (3, 2)}
    assert {tuple(p) for p in ordered_pairs(labels, order, transitive=False)} == \
        {(0, 1), (4, 1), (1, 2), (3, 1)}
    groups = ["walk", "walk", "run", "walk", "run"]
    assert {tuple(p) for p in ordered_pairs(labels, order, groups)} == {(0, 1), (3, 1), (4, 2)}
    assert similar_pairs(labels).tolist() == [[0, 4]]
    assert similar_pairs(labels, groups).tolist() == []


def test_objective_gradient_matches_finite_differences():
    rng = np.random.default_rng(2)
    D_o, D_s, w = rng.normal(size=(15, 4)), rng.normal(size=(6, 4)), 0.4 * rng.normal(size=4)
    _, g = ranksvm_objective(w, D_o, D_s, 0.8)
    h = 1e-6
    fd = [(ranksvm_objective(w + h * e, D_o, D_s, 0.8)[0]
           - ranksvm_objective(w - h * e, D_o, D_s, 0.8)[0]) / (2 * h) for e in np.eye(4)]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-8)


def test_newton_reaches_the_scipy_optimum():
    rng = np.random.default_rng(3)
    D_o, D_s, C = rng.normal(size=(40, 6)), rng.normal(size=(10, 6)), 0.3

    def plain(w):       # the objective written independently, pair by pair
        f = 0.5 * sum(x * x for x in w)
        f += C * sum(max(0.0, 1.0 - float(np.dot(w, d))) ** 2 for d in D_o)
        return f + C * sum(float(np.dot(w, d)) ** 2 for d in D_s)

    w = ranksvm_newton(D_o, D_s, C)
    ref = minimize(plain, np.zeros(6), method="BFGS", options={"gtol": 1e-9})
    assert plain(w) <= ref.fun + 1e-10
    np.testing.assert_allclose(w, ref.x, atol=1e-5)
    assert np.linalg.norm(ranksvm_objective(w, D_o, D_s, C)[1]) < 1e-9


def test_ranksvm_recovers_a_planted_ranking():
    rng = np.random.default_rng(4)
    w_true = rng.normal(size=5)
    X = rng.normal(size=(80, 5))
    s = X @ w_true
    i, j = np.nonzero(s[:, None] > s[None, :])                # every correctly ordered pair
    w = ranksvm_newton(X[i] - X[j], C=10.0)
    assert w @ w_true / np.linalg.norm(w) / np.linalg.norm(w_true) > 0.99


def test_fit_strength_ranks_held_out_clips_on_a_planted_axis():
    rng = np.random.default_rng(5)
    level = {"sad": -1.0, "neutral": 0.0, "happy": 1.0, "angry": 1.0}
    labels = [e for e in level for _ in range(8)]
    X = rng.normal(size=(len(labels), 30))
    X[:, 3] += 4.0 * np.array([level[e] for e in labels])     # strength lives on feature 3
    model = fit_strength_features(X[::2], labels[::2], n_components=10, C=1.0)
    assert ranking_accuracy(model, X[1::2], labels[1::2]) == 1.0
    with pytest.raises(bm.BayesmotionError, match="neutral='neutral' right"):
        fit_strength_features(X[:4], ["happy", "happy", "normal", "normal"])


def test_strength_classifier_reads_each_emotion_on_its_own_axis():
    # four emotions, each raising its own feature: one ranker per emotion finds its axis, so
    # held-out clips get their emotion; a single happy > neutral > sad axis could not tell
    # happy from angry (both rank above neutral)
    rng = np.random.default_rng(6)
    emotions = ("angry", "happy", "neutral", "sad")
    labels = [e for e in emotions for _ in range(10)]
    X = rng.normal(size=(len(labels), 20))
    for k, e in enumerate(emotions):
        X[:, 2 * k] += 3.0 * (np.array(labels) == e)
    clf = StrengthClassifier(n_components=12).fit(X[::2], labels[::2])
    assert clf.classes == emotions
    assert np.mean(clf.predict(X[1::2]) == np.array(labels[1::2])) >= 0.9
    S = clf.strengths(X[::2])  # standardised on the training clips
    np.testing.assert_allclose(S.mean(0), 0.0, atol=1e-9)
    np.testing.assert_allclose(S.std(0), 1.0, rtol=1e-9)
    for k, e in enumerate(emotions):  # each ranker puts its emotion's clips on top
        mine = np.array(labels[::2]) == e
        assert S[mine, k].mean() > 1.0 and S[~mine, k].mean() < 0.0
    with pytest.raises(bm.BayesmotionError, match="not fitted"):
        StrengthClassifier().predict(X[:1])
    with pytest.raises(bm.BayesmotionError, match=r"X must be \(N, 20\)"):
        clf.predict(X[:2, :5])
    with pytest.raises(bm.BayesmotionError, match="at least two emotions"):
        StrengthClassifier().fit(X[:4], ["sad"] * 4)


def test_keyframe_features_shape_and_scale_invariance():
    # a figure whose left hand swings: keyframes exist and features ignore the world scale
    pose = {k: np.zeros(3) for k in SEMANTIC_JOINTS}
    pose.update(spine=[0, 1, 0], neck=[0, 2, 0], head=[0, 3, 0], l_shoulder=[1, 2, 0],
                r_shoulder=[-1, 2, 0], l_elbow=[1, 1, 0], r_elbow=[-1, 1, 0], l_hand=[1, 0, 0],
                r_hand=[-1, 0, 0], l_hip=[1, 0, 0], r_hip=[-1, 0, 0], l_knee=[1, -2, 0],
                r_knee=[-1, -2, 0], l_foot=[1, -4, 0], r_foot=[-1, -4, 0], l_toe=[1, -4, 1],
                r_toe=[-1, -4, 1])
    P = np.repeat(np.array([pose[k] for k in SEMANTIC_JOINTS], float)[None], 50, axis=0)
    P[:, SEMANTIC_JOINTS.index("l_hand"), 2] = np.sin(np.linspace(0, 2 * np.pi, 50))
    jm = JointMap(**{k: k for k in SEMANTIC_JOINTS})
    f = keyframe_features_from_positions(P, SEMANTIC_JOINTS, 30.0, n_keys=6, joint_map=jm)
    assert f.shape == (6 * 72,)
    f3 = keyframe_features_from_positions(3 * P + 1, SEMANTIC_JOINTS, 30.0, n_keys=6, joint_map=jm)
    np.testing.assert_allclose(f3, f, atol=1e-12)
