"""Feature classifiers: hand-solved logistic regression, gradients, separable data, LOO."""

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import expit

import bayesmotion as bm
from bayesmotion.baselines.classifier import (
    GroupCentred,
    LogisticRegression,
    NearestNeighbour,
    accuracy,
    leave_one_out_predictions,
    mean_pose_features,
    trial_features,
)
from bayesmotion.features import JointMap


def blobs(rng, n=30, F=5, K=3, sep=6.0):
    centres = sep * rng.normal(size=(K, F))
    y = np.repeat(np.arange(K), n)
    return centres[y] + rng.normal(size=(K * n, F)), np.array(["a", "b", "c"])[y]


def test_two_points_match_the_hand_solved_optimum():
    # z = ±1 after standardising; with W = (-d/2, d/2) the loss is 2 log(1 + e^-d) + l2 d²/4,
    # stationary where σ(-d) = l2 d / 4.
    clf = LogisticRegression(l2=1.0).fit([[-3.0], [5.0]], ["neg", "pos"])
    d = brentq(lambda d: expit(-d) - d / 4, 0.0, 10.0)
    np.testing.assert_allclose(clf.predict_proba([[5.0], [-3.0]]),
                               [[expit(-d), expit(d)], [expit(d), expit(-d)]], rtol=1e-6)
    np.testing.assert_allclose(clf.W[0], [-d / 2, d / 2], rtol=1e-6)
    assert clf.classes == ("neg", "pos") and list(clf.predict([[4.0]])) == ["pos"]


def test_objective_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    Z, Y = rng.normal(size=(12, 4)), np.eye(3)[rng.integers(0, 3, 12)]
    clf, theta = LogisticRegression(l2=0.7), rng.normal(size=4 * 3 + 3)
    _, g = clf.objective(theta, Z, Y)
    h = 1e-6
    fd = [(clf.objective(theta + h * e, Z, Y)[0] - clf.objective(theta - h * e, Z, Y)[0]) / (2 * h)
          for e in np.eye(theta.size)]
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-8)


def test_fit_reaches_a_stationary_point_and_is_immutable():
    rng = np.random.default_rng(1)
    X, y = blobs(rng, sep=1.0)
    base = LogisticRegression(l2=0.5)
    clf = base.fit(X, y)
    assert base.W is None and clf is not base
    Z, Y = (X - clf.mean) / clf.scale, np.eye(3)[np.unique(y, return_inverse=True)[1]]
    _, g = clf.objective(np.concatenate([clf.W.ravel(), clf.b]), Z, Y)
    assert np.max(np.abs(g)) < 1e-6


@pytest.mark.parametrize("make", [lambda: LogisticRegression(l2=0.1), lambda: NearestNeighbour()])
def test_separable_labels_are_recovered(make):
    rng = np.random.default_rng(2)
    X, y = blobs(rng)
    Xt, yt = blobs(np.random.default_rng(2), n=30)        # same centres, fresh noise below
    Xt = Xt + 0.3 * rng.normal(size=Xt.shape)
    clf = make().fit(X, y)
    assert accuracy(clf.predict(X), y) == 1.0 and accuracy(clf.predict(Xt), yt) == 1.0
    np.testing.assert_allclose(clf.predict_proba(Xt).sum(1), 1.0)


def test_nearest_neighbour_hand_case():
    # standardised: x -> (x - 1) / 1 for x in {0, 1, 2}; query 1.4 is nearest to 1
    clf = NearestNeighbour().fit([[0.0], [1.0], [2.0]], ["x", "y", "z"])
    assert list(clf.predict([[1.4], [-5.0], [1.6]])) == ["y", "x", "z"]
    vote3 = NearestNeighbour(k=3).fit([[0.0], [0.2], [3.0]], ["p", "p", "q"])
    assert list(vote3.predict([[2.9]])) == ["p"]                # 2 of 3 votes beat the nearest


def test_errors_name_the_problem():
    with pytest.raises(bm.BayesmotionError, match="not fitted"):
        LogisticRegression().predict([[1.0]])
    with pytest.raises(bm.BayesmotionError, match=r"expected X \(N, F\)"):
        LogisticRegression().fit([1.0, 2.0], ["a", "b"])
    with pytest.raises(bm.BayesmotionError, match="fitted on 1 features, got 2"):
        NearestNeighbour().fit([[0.0], [1.0]], ["a", "b"]).predict([[0.0, 1.0]])


def one_joint_dataset(rng, n_per=6):
    sk = bm.Skeleton(["root"], [-1], [[0, 0, 0]], [("Xposition", "Yposition", "Zposition")])
    centres = {"happy": [5.0, 0, 0], "sad": [0, 5.0, 0], "angry": [0, 0, 5.0]}
    trials = [bm.Trial(bm.Motion(sk, np.add(c, rng.normal(size=(10, 3))), 30.0),
                       {"emotion": e}, f"{e}{i}")
              for e, c in centres.items() for i in range(n_per)]
    return bm.MotionDataset(trials)


def test_leave_one_out_matches_a_manual_loop():
    rng = np.random.default_rng(3)
    ds = one_joint_dataset(rng)
    feat = lambda m: m.values.mean(0)
    X = trial_features(ds, feat)
    y = np.array(ds.labels("emotion"))
    pred = leave_one_out_predictions(ds, "emotion", NearestNeighbour(), feat)
    manual = [NearestNeighbour().fit(np.delete(X, i, 0), np.delete(y, i)).predict(X[i:i + 1])[0]
              for i in range(len(y))]
    assert pred == manual and accuracy(pred, y) == 1.0
    assert leave_one_out_predictions(ds, "emotion", features=X) == list(y)


def test_mean_pose_of_a_static_figure():
    # root at the origin, hips ±1 on X, shoulders ±1 on X: faces +Z; legs 2 + 2 long
    names = ("root", "spine", "neck", "head", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow",
             "l_hand", "r_hand", "l_hip", "r_hip", "l_knee", "r_knee", "l_foot", "r_foot",
             "l_toe", "r_toe")
    pose = np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0], [0, 3, 0], [1, 2, 0], [-1, 2, 0],
                     [2, 2, 0], [-2, 2, 0], [3, 2, 0], [-3, 2, 0], [1, 0, 0], [-1, 0, 0],
                     [1, -2, 0], [-1, -2, 0], [1, -4, 0], [-1, -4, 0], [1, -4, 1], [-1, -4, 1]],
                    float)
    sk = bm.Skeleton(names, [-1] + [0] * 17, pose, [("Xposition", "Yposition", "Zposition")]
                     + [()] * 17)
    motion = bm.Motion(sk, np.tile([7.0, 1.0, -3.0], (4, 1)), 30.0)
    jm = JointMap(**{k: k for k in names})
    np.testing.assert_allclose(mean_pose_features(motion, jm), (pose / 4.0).ravel(), atol=1e-12)


def grouped_blobs(rng, groups=6, per=4, F=4, offset=20.0, effect=2.0):
    """Every group holds every class once per repeat; each group is shifted by a large
    random offset, each class by a small fixed effect common to all groups."""
    classes = np.array(["a", "b", "c", "d"])
    effects = effect * rng.normal(size=(len(classes), F))
    offsets = offset * rng.normal(size=(groups, F))
    g = np.repeat(np.arange(groups), len(classes) * per)
    y = np.tile(np.arange(len(classes)), groups * per)
    X = offsets[g] + effects[y] + 0.3 * rng.normal(size=(len(y), F))
    return X, classes[y], np.array([f"g{i}" for i in g])


def test_group_centred_is_the_classifier_on_centred_features():
    rng = np.random.default_rng(5)
    X, y, g = grouped_blobs(rng)
    rel = GroupCentred().fit(X, y, g)
    means = np.stack([X[g == k].mean(0) for k in rel.groups])
    np.testing.assert_allclose(rel.means, means, rtol=1e-12)
    centred = X - means[[rel.groups.index(k) for k in g]]
    plain = LogisticRegression().fit(centred, y)
    np.testing.assert_allclose(rel.predict_proba(X, g), plain.predict_proba(centred), rtol=1e-9)
    assert rel.classes == plain.classes
    with pytest.raises(bm.BayesmotionError, match=r"groups \['g9'\] are not among"):
        rel.predict(X[:1], ["g9"])
    with pytest.raises(bm.BayesmotionError, match="one group per row"):
        rel.predict(X[:2], ["g0"])
    with pytest.raises(bm.BayesmotionError, match="one group per row"):
        GroupCentred().fit(X, y, g[:-1])
    with pytest.raises(bm.BayesmotionError, match="not fitted"):
        GroupCentred().predict(X[:1], ["g0"])
    with pytest.raises(bm.BayesmotionError, match="fitted on 4 features"):
        rel.predict(X[:1, :1], ["g0"])
    with pytest.raises(bm.BayesmotionError, match="None found"):
        GroupCentred().fit(X, y, [None] * len(y))
    # groups are names: integer groups and their text are one group
    ints = GroupCentred().fit(X, y, [int(k[1:]) for k in g])
    np.testing.assert_allclose(ints.predict_proba(X[:3], ["0", 0, "0"]),
                               rel.predict_proba(X[:3], g[:3]), rtol=1e-12)


def test_group_centred_finds_a_class_effect_that_group_offsets_hide():
    """Leave one row out: with group offsets ten times the class effect, the raw features tell
    the groups apart and the classes poorly; relative to its group the effect is plain."""
    rng = np.random.default_rng(11)
    X, y, g = grouped_blobs(rng, per=1)
    n = len(y)
    rel, raw = [], []
    for i in range(n):
        tr = np.arange(n) != i
        rel.append(GroupCentred().fit(X[tr], y[tr], g[tr]).predict(X[i:i + 1], g[i:i + 1])[0])
        raw.append(LogisticRegression().fit(X[tr], y[tr]).predict(X[i:i + 1])[0])
    assert accuracy(rel, y) >= 0.9
    assert accuracy(raw, y) <= 0.6
