"""Relative emotion strength (Ho et al. 2017): keyframes, PCA and a RankSVM ranking function.

The pipeline, per clip:

1. **Keyframes by curve simplification** (Lim & Thalmann; Lowe's recursive split): the pose
   trajectory ``Y: (T, D)`` is approximated by the polyline through its keyframes, starting with
   the first and last frame and splitting a segment at the frame farthest (Euclidean) from the
   segment's linear interpolation, until every frame is within ``tol`` or ``n_keys`` keyframes
   exist. The keyframe sequence is then resampled to a fixed ``n_keys`` entries.
2. **Features**: the keyframe poses (18 semantic joints, root-relative, facing +Z, in leg lengths
   L; :func:`~bayesmotion.features.body_frame_pose`) and every joint's world speed (L/s) at the
   keyframes, concatenated: ``n_keys · (54 + 18)`` numbers.
3. **PCA** by SVD of the centred training features.
4. **Ranking function** ``r(x) = wᵀ x`` learned with the relative-attributes objective of Parikh
   & Grauman (2011), squared hinge as in Chapelle (2007)::

       min_w ½‖w‖² + C Σ_{(i,j)∈O} max(0, 1 - wᵀ(x_i - x_j))² + C Σ_{(i,j)∈S} (wᵀ(x_i - x_j))²

   where O holds ordered pairs (i stronger than j, e.g. happy > neutral) and S similar pairs
   (same label). It is minimised in the primal by Newton's method: on the current set of
   violated ordered pairs the objective is quadratic, with gradient
   ``g = w - 2C D_svᵀ(1 - D_sv w) + 2C D_Sᵀ D_S w`` and Hessian ``H = I + 2C (D_svᵀ D_sv +
   D_Sᵀ D_S)``; the step ``-H⁻¹ g`` is taken with a backtracking line search.

The default order is happy > neutral > sad and angry > neutral (with its transitive closure:
happy > sad, angry > sad). Bandai calls neutral ``"normal"``: pass ``neutral="normal"``.

:class:`StrengthClassifier` turns relative strength into an emotion classifier (the evaluation
harness's baseline): one ranking function per emotion, each ordering that emotion's clips above
every other emotion's, as Ho et al. learn one relative attribute per emotion.
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError
from bayesmotion.features import JointMap, body_frame_pose
from bayesmotion.features.joint_map import Names
from bayesmotion.features.movement import leg_length
from bayesmotion.features.pose import semantic_positions

DEFAULT_ORDER = (("happy", "neutral"), ("neutral", "sad"), ("angry", "neutral"))


# ----------------------------------------------------------------------- keyframes
def _segment_error(Y: np.ndarray, i: int, j: int) -> tuple[float, int]:
    """Max distance of frames i+1..j-1 from the chord Y[i] -> Y[j], and where it occurs."""
    if j - i < 2:
        return 0.0, -1
    u = (np.arange(i + 1, j) - i)[:, None] / (j - i)
    err = np.linalg.norm(Y[i + 1:j] - ((1 - u) * Y[i] + u * Y[j]), axis=1)
    k = int(np.argmax(err))
    return float(err[k]), i + 1 + k


def simplify_curve(Y: np.ndarray, tol: float | None = None,
                   n_keys: int | None = None) -> np.ndarray:
    """Keyframe indices of a trajectory by recursive splitting at the worst frame.

    Args:
        Y: (T, D) trajectory.
        tol: split until every frame is closer than ``tol`` to the keyframe polyline.
        n_keys: instead, split the worst segment first until there are ``n_keys`` keyframes.

    Returns:
        (K,) sorted int frame indices, always including 0 and T-1.
    """
    Y = np.asarray(Y, dtype=np.float64).reshape(len(Y), -1)
    T = Y.shape[0]
    if (tol is None) == (n_keys is None):
        raise BayesmotionError("simplify_curve: give exactly one of tol and n_keys")
    if n_keys is not None and not 2 <= n_keys <= T:
        raise BayesmotionError(f"simplify_curve: n_keys must be in [2, {T}] for {T} frames, "
                               f"got {n_keys}")
    keys = {0, T - 1}
    heap = [(-e, k, 0, T - 1) for e, k in [_segment_error(Y, 0, T - 1)] if k >= 0]
    while heap:
        err, k, i, j = heapq.heappop(heap)
        if (tol is not None and -err < tol) or (n_keys is not None and len(keys) >= n_keys):
            break
        keys.add(k)
        for a, b in ((i, k), (k, j)):
            e, m = _segment_error(Y, a, b)
            if m >= 0:
                heapq.heappush(heap, (-e, m, a, b))
    return np.array(sorted(keys))


def resample_rows(X: np.ndarray, n: int) -> np.ndarray:
    """(K, D) -> (n, D), linear in the row index (K == n: unchanged)."""
    s = np.linspace(0, len(X) - 1, n)
    return np.stack([np.interp(s, np.arange(len(X)), col) for col in X.T], axis=1)


def keyframe_features_from_positions(positions: np.ndarray, names: Names, fps: float,
                                     n_keys: int = 8, tol: float | None = None,
                                     joint_map: JointMap | None = None) -> np.ndarray:
    """(n_keys · 72,) keyframe poses and joint speeds (module docstring, steps 1-2).

    Args:
        positions: (T, J, 3) world positions; names: the skeleton or its joint names.
        fps: frames per second.
        n_keys: keyframes kept (the sequence is resampled to this many).
        tol: when given, keyframes come from this tolerance (in L) instead of the count.
    """
    Y = body_frame_pose(positions, names, joint_map)                       # (T, 18, 3) in L
    p = semantic_positions(positions, names, joint_map)
    P = np.stack(list(p.values()), axis=1) / leg_length(p)                # (T, 18, 3)
    speed = np.linalg.norm(np.gradient(P, axis=0), axis=-1) * fps if len(P) > 1 else \
        np.zeros(P.shape[:2])
    flat = Y.reshape(len(Y), -1)
    keys = simplify_curve(flat, tol=tol) if tol is not None else \
        simplify_curve(flat, n_keys=min(n_keys, len(flat)))
    rows = np.concatenate([flat[keys], speed[keys]], axis=1)
    return resample_rows(rows, n_keys).ravel()


def keyframe_features(motion: Motion, n_keys: int = 8, tol: float | None = None,
                      joint_map: JointMap | None = None) -> np.ndarray:
    """:func:`keyframe_features_from_positions` of a motion's FK positions."""
    return keyframe_features_from_positions(motion.positions(), motion.skeleton, motion.fps,
                                            n_keys, tol, joint_map)


# ----------------------------------------------------------------------------- PCA
@dataclass(frozen=True, eq=False)
class PCA:
    """Principal components by SVD. mean: (F,), components: (k, F) orthonormal rows."""

    mean: np.ndarray
    components: np.ndarray
    explained_variance: np.ndarray

    @classmethod
    def fit(cls, X: np.ndarray, n_components: int | float = 0.95) -> PCA:
        """Keep ``n_components`` axes, or the fewest explaining that fraction if a float < 1."""
        X = np.asarray(X, dtype=np.float64)
        mean = X.mean(axis=0)
        _, s, Vt = np.linalg.svd(X - mean, full_matrices=False)
        var = s**2 / max(len(X) - 1, 1)
        if isinstance(n_components, float) and n_components < 1:
            frac = np.cumsum(var) / max(var.sum(), 1e-300)
            k = int(np.searchsorted(frac, n_components) + 1)
        else:
            k = int(n_components)
        k = min(k, len(s))
        return cls(mean, Vt[:k], var[:k])

    def transform(self, X: np.ndarray) -> np.ndarray:
        """(N, F) -> (N, k) scores."""
        return (np.atleast_2d(X) - self.mean) @ self.components.T


# ------------------------------------------------------------------------- RankSVM
def ranksvm_objective(w: np.ndarray, D_o: np.ndarray, D_s: np.ndarray, C: float):
    """Objective of the module docstring and its gradient.

    Args:
        w: (F,) weights. D_o: (P, F) differences x_i - x_j of ordered pairs (i stronger).
        D_s: (S, F) differences of similar pairs. C: pair-loss weight.
    """
    m = np.maximum(0.0, 1.0 - D_o @ w)
    s = D_s @ w
    f = 0.5 * w @ w + C * (m @ m + s @ s)
    return f, w - 2 * C * (D_o.T @ m) + 2 * C * (D_s.T @ s)


def ranksvm_newton(D_o: np.ndarray, D_s: np.ndarray | None = None, C: float = 1.0,
                   tol: float = 1e-10, max_iter: int = 100) -> np.ndarray:
    """Minimise :func:`ranksvm_objective` by primal Newton steps (Chapelle 2007).

    Returns:
        (F,) optimal weights. Raises a BayesmotionError if ``max_iter`` steps do not bring the
        gradient norm under ``tol · max(1, ‖w‖)``.
    """
    D_o = np.asarray(D_o, dtype=np.float64)
    D_s = np.zeros((0, D_o.shape[1])) if D_s is None else np.asarray(D_s, dtype=np.float64)
    F = D_o.shape[1]
    w = np.zeros(F)
    f, g = ranksvm_objective(w, D_o, D_s, C)
    H_s = 2 * C * D_s.T @ D_s
    for _ in range(max_iter):
        if np.linalg.norm(g) <= tol * max(1.0, np.linalg.norm(w)):
            return w
        sv = D_o @ w < 1.0                                 # violated ordered pairs
        H = np.eye(F) + 2 * C * D_o[sv].T @ D_o[sv] + H_s
        step = np.linalg.solve(H, g)
        t = 1.0
        while True:                                        # backtracking (Armijo) line search
            f_new, g_new = ranksvm_objective(w - t * step, D_o, D_s, C)
            if f_new <= f - 1e-4 * t * (g @ step) or t < 1e-12:
                break
            t *= 0.5
        w, f, g = w - t * step, f_new, g_new
    raise BayesmotionError(f"RankSVM Newton did not converge in {max_iter} steps "
                           f"(gradient norm {np.linalg.norm(g):.3g})")


def _closure(order: Sequence[tuple[str, str]]) -> set[tuple[str, str]]:
    rel = set(map(tuple, order))
    while True:
        more = {(a, d) for a, b in rel for c, d in rel if b == c} - rel
        if not more:
            return rel
        rel |= more


def default_order(neutral: str = "neutral") -> tuple[tuple[str, str], ...]:
    """``DEFAULT_ORDER`` with the neutral level renamed (Bandai: ``"normal"``)."""
    return tuple((neutral if a == "neutral" else a, neutral if b == "neutral" else b)
                 for a, b in DEFAULT_ORDER)


def ordered_pairs(labels: Sequence[str], order: Sequence[tuple[str, str]],
                  groups: Sequence | None = None, transitive: bool = True) -> np.ndarray:
    """(P, 2) index pairs (i, j) with labels[i] ranked above labels[j] by ``order``.

    With ``groups`` (e.g. the action), only pairs inside one group are formed.
    """
    rel = _closure(order) if transitive else set(map(tuple, order))
    g = list(groups) if groups is not None else [0] * len(labels)
    return np.array([(i, j) for i, a in enumerate(labels) for j, b in enumerate(labels)
                     if (a, b) in rel and g[i] == g[j]], dtype=int).reshape(-1, 2)


def similar_pairs(labels: Sequence[str], groups: Sequence | None = None) -> np.ndarray:
    """(S, 2) pairs i < j with the same label (and the same group, if given)."""
    g = list(groups) if groups is not None else [0] * len(labels)
    n = len(labels)
    return np.array([(i, j) for i in range(n) for j in range(i + 1, n)
                     if labels[i] == labels[j] and g[i] == g[j]], dtype=int).reshape(-1, 2)


# --------------------------------------------------------------------------- model
@dataclass(frozen=True, eq=False)
class StrengthModel:
    """A fitted ranking function r(motion) = wᵀ PCA(keyframe_features(motion))."""

    pca: PCA
    w: np.ndarray
    n_keys: int = 8
    tol: float | None = None
    joint_map: JointMap | None = None

    def score_features(self, X: np.ndarray) -> np.ndarray:
        """(N, F) keyframe features -> (N,) strengths."""
        return self.pca.transform(X) @ self.w

    def score(self, motion: Motion) -> float:
        """Relative strength of one motion (only differences between motions are meaningful)."""
        x = keyframe_features(motion, self.n_keys, self.tol, self.joint_map)
        return float(self.score_features(x[None])[0])


def fit_strength_features(X: np.ndarray, labels: Sequence[str], *, order=None,
                          neutral: str = "neutral", groups: Sequence | None = None,
                          n_components: int | float = 0.95, C: float = 1.0,
                          n_keys: int = 8, tol: float | None = None,
                          joint_map: JointMap | None = None) -> StrengthModel:
    """Fit from precomputed (N, F) keyframe features (see :func:`fit_strength`)."""
    order = default_order(neutral) if order is None else order
    O, S = ordered_pairs(labels, order, groups), similar_pairs(labels, groups)
    if len(O) == 0:
        raise BayesmotionError(f"no ordered pair among labels {sorted(set(labels))} for order "
                               f"{list(order)}; is neutral={neutral!r} right?")
    pca = PCA.fit(X, n_components)
    Z = pca.transform(X)
    D_o = Z[O[:, 0]] - Z[O[:, 1]]
    D_s = Z[S[:, 0]] - Z[S[:, 1]] if len(S) else None
    return StrengthModel(pca, ranksvm_newton(D_o, D_s, C), n_keys, tol, joint_map)


def fit_strength(motions: Sequence[Motion], labels: Sequence[str], **options) -> StrengthModel:
    """Learn a relative emotion-strength function from labelled clips.

    Args:
        motions: (N,) clips. labels: (N,) emotion of each.
        **options: ``order`` (pairs (stronger, weaker); default happy > neutral > sad, angry >
            neutral), ``neutral`` (name of the neutral level), ``groups`` (pair clips only
            within a group, e.g. the action), ``n_components`` (PCA: count or variance
            fraction), ``C``, ``n_keys``, ``tol``, ``joint_map``.
    """
    kf = {k: options[k] for k in ("n_keys", "tol", "joint_map") if k in options}
    X = np.stack([keyframe_features(m, **kf) for m in motions])
    return fit_strength_features(X, labels, **options)


def ranking_accuracy(model: StrengthModel, motions: Sequence[Motion] | np.ndarray,
                     labels: Sequence[str], order=None, neutral: str = "neutral",
                     groups: Sequence | None = None) -> float:
    """Fraction of ordered pairs among ``motions`` (or their (N, F) features) ranked right."""
    order = default_order(neutral) if order is None else order
    if isinstance(motions, np.ndarray):
        r = model.score_features(motions)
    else:
        r = np.array([model.score(m) for m in motions])
    O = ordered_pairs(labels, order, groups)
    if len(O) == 0:
        raise BayesmotionError("no ordered pair to evaluate among these labels")
    return float(np.mean(r[O[:, 0]] > r[O[:, 1]]))


@dataclass(frozen=True, eq=False)
class StrengthClassifier:
    """Ho et al.'s relative strength as a classifier: the emotion whose strength is largest.

    ``fit`` learns one ranking function per emotion k (:func:`fit_strength_features` with the
    order "k above every other emotion", similar pairs within each emotion: the relative
    attribute "how k is this clip"). Each function's scale is arbitrary, so its scores are
    standardised by their mean and standard deviation over the training clips; a clip gets
    the emotion of its largest standardised strength. Immutable: ``fit`` returns a new
    classifier; works on precomputed (N, F) keyframe features (:func:`keyframe_features`).
    """

    n_components: int | float = 0.95
    C: float = 1.0
    classes: tuple = ()
    models: tuple = ()
    mean: np.ndarray | None = None
    scale: np.ndarray | None = None

    def fit(self, X, y) -> StrengthClassifier:
        X = np.asarray(X, dtype=np.float64)
        y = [str(v) for v in y]
        if X.ndim != 2 or X.shape[0] != len(y):
            raise BayesmotionError(f"X must be (N, F) with one label per row; got {X.shape} "
                                   f"and {len(y)} labels")
        classes = tuple(sorted(set(y)))
        if len(classes) < 2:
            raise BayesmotionError(f"need at least two emotions to rank, got {list(classes)}")
        models = tuple(fit_strength_features(X, y, order=[(k, o) for o in classes if o != k],
                                             n_components=self.n_components, C=self.C)
                       for k in classes)
        S = np.stack([m.score_features(X) for m in models], axis=1)
        sd = S.std(axis=0)
        return replace(self, classes=classes, models=models, mean=S.mean(axis=0),
                       scale=np.where(sd > 0, sd, 1.0))

    def strengths(self, X) -> np.ndarray:
        """(N, K) standardised strength of each emotion (``classes`` order)."""
        if not self.models:
            raise BayesmotionError("StrengthClassifier is not fitted: call fit(X, y) first")
        X = np.atleast_2d(np.asarray(X, dtype=np.float64))
        width = self.models[0].pca.mean.size
        if X.ndim != 2 or X.shape[1] != width:
            raise BayesmotionError(f"X must be (N, {width}) keyframe features like the training "
                                   f"ones; got {X.shape}")
        S = np.stack([m.score_features(X) for m in self.models], axis=1)
        return (S - self.mean) / self.scale

    def predict(self, X) -> np.ndarray:
        """(N,) emotion of the largest standardised strength."""
        return np.asarray(self.classes)[np.argmax(self.strengths(X), axis=1)]
