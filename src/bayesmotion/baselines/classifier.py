"""Emotion classifiers on clip features: logistic regression and nearest neighbour.

Both standardise the features with the training set's mean and standard deviation, are
immutable, and ``fit`` returns a new fitted classifier (``clf = LogisticRegression().fit(X, y)``).

* :class:`LogisticRegression`: multinomial, L2 penalty on the weights (not the biases),
  minimising ``Σ_n -log softmax(W x_n + b)[y_n] + l2/2 ‖W‖²`` with L-BFGS and the exact
  gradient ``∂/∂W = Σ_n x_n (p_n - e_{y_n})ᵀ + l2 W``.
* :class:`NearestNeighbour`: k-nearest neighbours, Euclidean in standardised features; used on
  :func:`mean_pose_features` it is the nearest-mean-pose baseline.
* :class:`GroupCentred`: either of them on features taken relative to each clip's group (its
  action, e.g. the Bandai content): every clip minus the mean features of the training clips of
  its group, fitted without the labels being predicted. An emotion that raises the speed of a
  walk and of a bow alike is then one direction across actions, where raw features mostly tell
  the actions apart.

:func:`leave_one_out_predictions` runs the first two on a :class:`~bayesmotion.MotionDataset`;
``bayesmotion.evaluation.evaluate.leave_one_out`` runs :class:`GroupCentred` on its folds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize
from scipy.special import log_softmax, softmax

from bayesmotion.data.motion import Motion, MotionDataset
from bayesmotion.errors import BayesmotionError
from bayesmotion.features import JointMap, body_frame_pose, clip_features


def _check_xy(X, y) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=np.float64)
    y = np.asarray(y)
    if X.ndim != 2 or y.shape != (X.shape[0],):
        raise BayesmotionError(f"expected X (N, F) and y (N,), got {X.shape} and {y.shape}")
    if not np.all(np.isfinite(X)):
        raise BayesmotionError("features contain NaN or infinity")
    return X, y


@dataclass(frozen=True, eq=False)
class _Standardised:
    """Shared state: classes and the training mean/scale (``None`` until fitted)."""

    classes: tuple | None = None
    mean: np.ndarray | None = None
    scale: np.ndarray | None = None

    def _standardise_fit(self, X):
        sd = X.std(axis=0)
        return X.mean(axis=0), np.where(sd > 0, sd, 1.0)

    def _z(self, X) -> np.ndarray:
        if self.classes is None:
            raise BayesmotionError(f"{type(self).__name__} is not fitted; call .fit(X, y) first")
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        if X.shape[1] != self.mean.shape[0]:
            raise BayesmotionError(f"fitted on {self.mean.shape[0]} features, got {X.shape[1]}")
        return (X - self.mean) / self.scale

    def predict(self, X) -> np.ndarray:
        """(N,) most probable class of each row of ``X: (N, F)``."""
        return np.asarray(self.classes)[np.argmax(self.predict_proba(X), axis=1)]


@dataclass(frozen=True, eq=False)
class LogisticRegression(_Standardised):
    """Multinomial logistic regression (module docstring).

    Attributes:
        l2: penalty on the (F, K) weights of the standardised features.
        W: (F, K) weights, b: (K,) biases, once fitted.
    """

    l2: float = 1.0
    W: np.ndarray | None = None
    b: np.ndarray | None = None

    def objective(self, theta: np.ndarray, Z: np.ndarray, Y: np.ndarray):
        """Penalised negative log-likelihood and its gradient; theta = [W.ravel(), b]."""
        F, K = Z.shape[1], Y.shape[1]
        W, b = theta[: F * K].reshape(F, K), theta[F * K:]
        logits = Z @ W + b
        nll = -np.sum(Y * log_softmax(logits, axis=1))
        R = softmax(logits, axis=1) - Y                           # p_n - e_{y_n}
        gW, gb = Z.T @ R + self.l2 * W, R.sum(axis=0)
        return nll + 0.5 * self.l2 * np.sum(W**2), np.concatenate([gW.ravel(), gb])

    def fit(self, X, y) -> LogisticRegression:
        X, y = _check_xy(X, y)
        classes, yi = np.unique(y, return_inverse=True)
        mean, scale = self._standardise_fit(X)
        Z, Y = (X - mean) / scale, np.eye(len(classes))[yi]
        F, K = Z.shape[1], len(classes)
        res = minimize(self.objective, np.zeros(F * K + K), args=(Z, Y), jac=True,
                       method="L-BFGS-B", options={"maxiter": 5000, "ftol": 1e-15, "gtol": 1e-9})
        return replace(self, classes=tuple(classes.tolist()), mean=mean, scale=scale,
                       W=res.x[: F * K].reshape(F, K), b=res.x[F * K:])

    def predict_proba(self, X) -> np.ndarray:
        """(N, K) class probabilities, columns ordered as ``classes``."""
        return softmax(self._z(X) @ self.W + self.b, axis=1)


@dataclass(frozen=True, eq=False)
class NearestNeighbour(_Standardised):
    """k-nearest-neighbour vote in standardised features (ties: the nearest class wins)."""

    k: int = 1
    Z: np.ndarray | None = None
    y: np.ndarray | None = None

    def fit(self, X, y) -> NearestNeighbour:
        X, y = _check_xy(X, y)
        mean, scale = self._standardise_fit(X)
        return replace(self, classes=tuple(np.unique(y).tolist()), mean=mean, scale=scale,
                       Z=(X - mean) / scale, y=y)

    def predict_proba(self, X) -> np.ndarray:
        """(N, K) fraction of the k nearest training rows in each class (+ a tie-breaker)."""
        d = np.linalg.norm(self._z(X)[:, None] - self.Z[None], axis=-1)       # (N, M)
        order = np.argsort(d, axis=1, kind="stable")[:, : self.k]
        votes = np.stack([(self.y[order] == c).sum(1) for c in self.classes], axis=1)
        nearest = np.stack([self.y[order[:, 0]] == c for c in self.classes], axis=1)
        return (votes + 1e-3 * nearest) / (self.k + 1e-3)


def _group_names(groups, n: int) -> list[str]:
    """One group name per row, as text (so 1 and "1" are one group); None is refused."""
    groups = list(np.atleast_1d(np.asarray(groups, dtype=object)))
    if len(groups) != n:
        raise BayesmotionError(f"expected one group per row: {n} rows, {len(groups)} groups")
    if any(g is None for g in groups):
        raise BayesmotionError("every row needs a group (None found)")
    return [str(g) for g in groups]


@dataclass(frozen=True, eq=False)
class GroupCentred:
    """A classifier on features relative to each clip's group (module docstring).

    ``fit(X, y, groups)`` takes each group's mean over its training rows and fits
    ``classifier`` on every row minus its group's mean; ``predict_proba(X, groups)`` centres
    new rows on the fitted means, and refuses a group the training rows lack.

    Attributes:
        classifier: the unfitted classifier (default :class:`LogisticRegression`); once
            fitted, the fitted one.
        groups: the training groups' names (as text: 1 and "1" are one group), in order;
            ``means``: (G, F) their mean features.
    """

    classifier: _Standardised | None = None
    groups: tuple | None = None
    means: np.ndarray | None = None

    @property
    def classes(self):
        return None if self.groups is None else self.classifier.classes

    def _centred(self, X, groups) -> np.ndarray:
        if self.groups is None:
            raise BayesmotionError("GroupCentred is not fitted; call .fit(X, y, groups) first")
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        if X.ndim != 2 or X.shape[1] != self.means.shape[1]:
            raise BayesmotionError(f"fitted on {self.means.shape[1]} features, got an array of "
                                   f"shape {X.shape}")
        names = _group_names(groups, X.shape[0])
        unknown = sorted(set(names) - set(self.groups))
        if unknown:
            raise BayesmotionError(f"groups {unknown} are not among the training groups "
                                   f"{list(self.groups)}: no reference mean for them")
        return X - self.means[[self.groups.index(g) for g in names]]

    def fit(self, X, y, groups) -> GroupCentred:
        X, y = _check_xy(X, y)
        names = np.array(_group_names(groups, X.shape[0]), dtype=object)
        levels = tuple(sorted(set(names)))
        means = np.stack([X[names == g].mean(axis=0) for g in levels])
        fitted = replace(self, groups=levels, means=means)
        clf = self.classifier if self.classifier is not None else LogisticRegression()
        return replace(fitted, classifier=clf.fit(fitted._centred(X, groups), y))

    def predict_proba(self, X, groups) -> np.ndarray:
        """(N, K) class probabilities, columns ordered as ``classes``."""
        centred = self._centred(X, groups)  # refuses an unfitted classifier first
        return self.classifier.predict_proba(centred)

    def predict(self, X, groups) -> np.ndarray:
        """(N,) most probable class of each row."""
        return np.asarray(self.classes)[np.argmax(self.predict_proba(X, groups), axis=1)]


def mean_pose_features(motion: Motion, joint_map: JointMap | None = None) -> np.ndarray:
    """(54,) clip-mean of :func:`~bayesmotion.features.body_frame_pose` (18 joints x 3)."""
    return body_frame_pose(motion.positions(), motion.skeleton, joint_map).mean(0).ravel()


FeatureFn = Callable[[Motion], np.ndarray]


def trial_features(dataset: MotionDataset, features: FeatureFn = clip_features) -> np.ndarray:
    """(N, F·A) features of every trial, the A actors' vectors concatenated."""
    return np.stack([np.concatenate([features(a) for a in t.actors]) for t in dataset])


def leave_one_out_predictions(dataset: MotionDataset, factor: str, classifier=None,
                              features: FeatureFn | np.ndarray = clip_features) -> list:
    """Predict each trial's ``factor`` level with a classifier fitted on all the other trials.

    Args:
        dataset: the trials; every one must carry a label for ``factor``.
        factor: e.g. ``"emotion"``.
        classifier: an unfitted classifier (default ``LogisticRegression()``).
        features: a function motion -> (F,) vector, or precomputed (N, F) features.

    Returns:
        (N,) predicted levels, in trial order.
    """
    y = dataset.labels(factor)
    if any(v is None for v in y):
        raise BayesmotionError(f"some trials have no {factor!r} label")
    X = features if isinstance(features, np.ndarray) else trial_features(dataset, features)
    clf = classifier if classifier is not None else LogisticRegression()
    keep = ~np.eye(len(y), dtype=bool)
    return [clf.fit(X[keep[i]], np.asarray(y)[keep[i]]).predict(X[i:i + 1])[0]
            for i in range(len(y))]


def accuracy(predicted: Sequence, truth: Sequence) -> float:
    """Fraction of equal entries."""
    return float(np.mean(np.asarray(predicted) == np.asarray(truth)))
