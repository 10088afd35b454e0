"""Canonical coordinates of the style vectors: their Gram matrix's factor and the rotation they
sit at (see :class:`CanonicalStyles`), and differential evolution (:class:`CanonicalDE`) and
independence Metropolis (:class:`CanonicalIndependence`) in them.

A factor's level vectors ``s_k`` (rows of ``S``, on the simplex) are, about the simplex's centre
``c = 1 / K``, the rows of ``V = (S - c) B`` in an orthonormal basis ``B`` of the simplex's plane
(``K`` rows, ``n = K - 1`` columns). The likelihood sees only ``V V^T`` (``S S^T = V V^T + 1 / K``),
and the style rotations move ``V -> V R``. The LQ decomposition ``V = T Q`` (``T`` lower
trapezoidal with a positive diagonal, ``Q`` orthogonal) splits ``V`` into what the likelihood
sees (``T``, with ``T T^T = V V^T``) and where on its orbit it sits (``Q``). In the sampled
coordinates the walkers sit at different points of their orbits, so a difference of two walkers'
style coordinates is mostly a difference of orientation; differences of their ``T`` are not.

The rotation kept is measured from the one that turns ``T``'s rows towards their vertices
(``align``): a walker's vectors then follow a new ``T`` towards where the prior keeps them, so
a step in ``T`` (DE's, or a fresh draw by the independence step) is refused by the prior less
often than at a fixed ``Q``. Measured in ``benchmarks/results/style_shear.json``.
"""

from __future__ import annotations

import emcee
import jax.numpy as jnp
import numpy as np

from bayesmotion.inference.moves.independence import IndependenceMove
from bayesmotion.inference.moves.rotations import (
    STICK_LOG_JACOBIAN,
    TO_SIMPLEX,
    TO_STICKS,
    plane_basis,
)


def _tri_index(K: int):
    """Rows, columns of ``T``'s free entries (lower trapezoidal, K x (K - 1)), and which of them
    are diagonal; as many entries as the Gram has free values, (K - 1)(K + 2) / 2."""
    n = K - 1
    rows, cols = np.tril_indices(K, 0, n)
    return rows, cols, rows == cols


def lq(V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., K, n) -> T (..., K, n) lower trapezoidal with positive diagonal, Q (..., n, n)
    orthogonal, with ``V = T Q`` (V of full column rank)."""
    Q1, R1 = np.linalg.qr(np.swapaxes(V, -1, -2))  # V^T = Q1 R1
    d = np.sign(np.diagonal(R1, axis1=-2, axis2=-1))
    d = np.where(d == 0, 1.0, d)
    T = np.swapaxes(R1, -1, -2) * d[..., None, :]
    Q = d[..., :, None] * np.swapaxes(Q1, -1, -2)
    return T, Q


def aligning_rotation(T: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(..., K, n), (K, n) -> (..., n, n): the orthogonal P that brings the rows of ``T P``
    closest to those of ``B`` (least squares: the orthogonal Procrustes solution)."""
    U, _, Wt = np.linalg.svd(np.swapaxes(T, -1, -2) @ B)
    return U @ Wt


def lq_log_jacobian(T: np.ndarray) -> np.ndarray:
    """log |d V / d(T, Q)| of ``V = T Q`` up to a constant (Q under the Haar measure):
    ``sum_i (n - 1 - i) log T_ii`` (i from 0), the QR decomposition's Jacobian transposed."""
    n = T.shape[-1]
    diag = np.diagonal(T, axis1=-2, axis2=-1)
    return np.sum((n - 1 - np.arange(n)) * np.log(diag), -1)


class CanonicalStyles:
    """The map between sampled coordinates ``x`` and canonical ones ``w`` (module docstring).

    ``w`` is ``x`` (or, with ``shear``, the shear's coordinates ``y = shear.forward(x)``) with each
    factor's style block (``K (K - 1)`` stick-breaking coordinates) replaced by the free entries
    of ``T``, diagonal entries as logs, and zeros in the block's last ``(K - 1)(K - 2) / 2`` slots;
    ``Q`` (or, with ``align``, ``R``) is kept apart. ``log_volume(w)`` is ``log |d x / d w|`` at
    fixed ``Q`` (``R``), up to a constant: a move symmetric in ``w`` that keeps ``Q`` (``R``)
    accepts with the density ratio times ``exp(log_volume(w') - log_volume(w))``.

    Args:
        slices: factor -> flat indices of its style block (``style_slices``); factors with
            fewer than 3 levels are left as they are (their orbits are two points).
        shear: a :class:`bayesmotion.inference.moves.StyleShear` or None.
        align: keep, instead of ``Q``, the rotation ``R = P(T)^T Q`` left over after the
            orthogonal ``P(T)`` that turns ``T``'s rows towards their levels' vertices
            (:func:`aligning_rotation`): a move of ``T`` at fixed ``R`` turns the vectors with
            it, so they stay where the prior keeps them (each near its own vertex). For a
            fixed ``T``, ``R -> Q`` is a left multiplication, which keeps the Haar measure, so
            ``log_volume`` is the same.
    """

    def __init__(self, slices: dict, shear=None, align: bool = True):
        self.align = bool(align)
        self.blocks = []
        self.factors = []
        for f, idx in slices.items():
            idx = np.asarray(idx, dtype=int)
            K = int(round((1 + np.sqrt(1 + 4 * idx.size)) / 2))  # idx holds K (K - 1) entries
            if K >= 3:
                self.blocks.append((idx, K, plane_basis(K), _tri_index(K)))
                self.factors.append(f)
        self.shear = shear

    def slots(self) -> np.ndarray:
        """Flat indices of ``w`` that hold the factors' ``T`` entries (the rest of each style
        block is zero in ``w``)."""
        return np.concatenate([idx[:rows.size] for idx, _, _, (rows, *_) in self.blocks]
                              ) if self.blocks else np.zeros(0, dtype=int)

    def slot_names(self) -> list[str]:
        """Names of :meth:`slots`, e.g. ``log T:emotion[0, 0]``, ``T:emotion[1, 0]``."""
        return [f"{'log ' if r == c else ''}T:{f}[{r}, {c}]"
                for f, (_, _, _, (rows, cols, _)) in zip(self.factors, self.blocks, strict=True)
                for r, c in zip(rows, cols, strict=True)]

    def styles(self) -> np.ndarray:
        """Flat indices of the factors' whole style blocks."""
        return (np.concatenate([idx for idx, *_ in self.blocks]) if self.blocks
                else np.zeros(0, dtype=int))

    def change(self, w, x, w_new, x_new) -> np.ndarray:
        """``log |d x / d w|`` at the new rows minus at the old: what a move symmetric in ``w``
        at fixed ``Q`` (or ``R``) adds to its log acceptance ratio."""
        with np.errstate(over="ignore", invalid="ignore"):  # rows outside: refused anyway
            return (self.log_volume(w_new) + self.log_stick(x_new)
                    - self.log_volume(w) - self.log_stick(x))

    def split(self, x) -> tuple[np.ndarray, list[np.ndarray]]:
        """Flat model coordinates (m, d) -> (w (m, d), [Q, or with ``align`` R, of each factor:
        (m, K-1, K-1)])."""
        x = np.asarray(x, dtype=np.float64)
        w = (np.array(x) if self.shear is None
             else np.array(self.shear.forward(jnp.asarray(x)), dtype=np.float64))
        qs = []
        for idx, K, B, (rows, cols, diag) in self.blocks:
            u = jnp.asarray(w[:, idx].reshape(-1, K, K - 1))
            S = np.asarray(TO_SIMPLEX(u), dtype=np.float64)
            T, Q = lq((S - 1.0 / K) @ B)
            vals = T[:, rows, cols]
            vals[:, diag] = np.log(vals[:, diag])
            if self.align:  # Q = P(T) R: keep R, the rotation away from the aligned one; P
                # from T as merge rebuilds it, so both sides pick the same P
                P = aligning_rotation(self._factor(vals, K, rows, cols, diag), B)
                Q = np.swapaxes(P, -1, -2) @ Q
            w[:, idx] = 0.0
            w[:, idx[:vals.shape[1]]] = vals
            qs.append(Q)
        return w, qs

    def merge(self, w, qs) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`split`: (x (m, d), inside (m,) bool). A row whose style vectors
        leave the simplex is marked outside, its style block set to the simplex's centre."""
        w = np.asarray(w, dtype=np.float64)
        y = np.array(w)
        inside = np.ones(len(w), dtype=bool)
        for (idx, K, B, (rows, cols, diag)), Q in zip(self.blocks, qs, strict=True):
            T = self._factor(w[:, idx[:rows.size]], K, rows, cols, diag)
            finite = np.all(np.isfinite(T), axis=(1, 2))  # an overflowing proposal is outside
            T = np.where(finite[:, None, None], T, 0.0)
            if self.align:
                Q = aligning_rotation(T, B) @ Q
            S = (T @ Q) @ B.T + 1.0 / K
            ok = finite & np.all(S > 0, axis=(1, 2))
            S = np.where(ok[:, None, None], S, 1.0 / K)
            y[:, idx] = np.asarray(TO_STICKS(jnp.asarray(S)), dtype=np.float64).reshape(len(w), -1)
            inside &= ok
        x = y if self.shear is None else np.array(self.shear.inverse(jnp.asarray(y)),
                                                  dtype=np.float64)
        return x, inside

    @staticmethod
    def _factor(vals, K, rows, cols, diag) -> np.ndarray:
        """(m, K, K - 1) T from its free entries (diagonal as logs)."""
        vals = np.array(vals, dtype=np.float64)
        with np.errstate(over="ignore"):
            vals[:, diag] = np.exp(vals[:, diag])
        T = np.zeros((len(vals), K, K - 1))
        T[:, rows, cols] = vals
        return T

    def log_volume(self, w) -> np.ndarray:
        """log |d x / d w| at fixed Q (or R), up to a constant, at rows ``w`` of canonical
        coordinates whose style vectors are inside the simplex."""
        w = np.asarray(w, dtype=np.float64)
        out = np.zeros(len(w))
        for idx, K, _, (rows, cols, diag) in self.blocks:
            logdiag = w[:, idx[:rows.size]][:, diag]
            T = self._factor(w[:, idx[:rows.size]], K, rows, cols, diag)
            # d V / d(T, Q), d T / d log-diagonal; then d u / d S (stick-breaking, inverted)
            out += lq_log_jacobian(T) + logdiag.sum(1)
        return out

    def log_stick(self, x) -> np.ndarray:
        """Minus the stick-breaking log-Jacobians of the factors' blocks at model coordinates
        ``x``: the last part of ``log |d x / d w|``."""
        x = np.asarray(x, dtype=np.float64)
        out = np.zeros(len(x))
        for idx, K, *_ in self.blocks:
            out -= np.asarray(STICK_LOG_JACOBIAN(jnp.asarray(x[:, idx].reshape(-1, K, K - 1))))
        return out


class CanonicalDE(emcee.moves.DEMove):
    """emcee's differential-evolution move in the canonical coordinates of
    :class:`CanonicalStyles`: the differences of two walkers' style blocks are differences of
    what the likelihood sees, not of their orbit positions, and each walker keeps its own
    rotation (``Q``, or ``R`` with ``align``; so, mostly, its orientation, which the reflections
    of :class:`bayesmotion.inference.moves.StyleRotations` change). The acceptance ratio carries
    the map's volume change. Other arguments as :class:`emcee.moves.DEMove`."""

    def __init__(self, canonical: CanonicalStyles, **kwargs):
        super().__init__(**kwargs)
        self.canonical = canonical

    def get_proposal(self, s, c, random):
        can = self.canonical
        ws, qs = can.split(s)
        wc = [can.split(ci)[0] for ci in c]
        qw, factors = super().get_proposal(ws, wc, random)
        s = np.asarray(s, dtype=np.float64)
        q, inside = can.merge(qw, qs)
        change = can.change(ws, s, qw, q)
        q[~inside] = s[~inside]  # rejected below; its density is the current one's, finite
        return q, np.where(inside, factors + change, -np.inf)


class CanonicalIndependence(IndependenceMove):
    """:class:`bayesmotion.inference.moves.IndependenceMove` in the canonical coordinates ``w``
    of :class:`CanonicalStyles`: ``block`` (indices of ``w``) may hold the factors' ``T``
    entries (:meth:`CanonicalStyles.slots`) beside the hyperparameters, so an accepted proposal
    is a fresh draw of what the likelihood sees of the rotated style vectors too. Each walker
    keeps its rotation (``Q`` or ``R``); the ratio carries the map's volume change (as
    :class:`CanonicalDE`), and a proposal whose style vectors leave the simplex is rejected.
    ``mean`` and ``cov`` are in ``w``; other arguments as :class:`IndependenceMove` (its
    ``shear`` is the canonical map's).
    """

    def __init__(self, canonical: CanonicalStyles, block, mean, cov, df: float = 20.0,
                 weights=None, marginal=None):
        block = np.asarray(block, dtype=int).ravel()
        spare = np.setdiff1d(canonical.styles(), canonical.slots())
        if np.intersect1d(block, spare).size:
            raise ValueError("the block holds style slots that are always zero in canonical "
                             "coordinates")
        super().__init__(block, mean, cov, df=df, weights=weights, marginal=marginal)
        self.canonical = canonical

    def _propose(self, coords, random):
        can = self.canonical
        x = np.asarray(coords, dtype=np.float64)
        w, qs = can.split(x)
        w_new = w.copy()
        w_new[:, self.block], log_ratio = self.draw(w[:, self.block], random)
        q, inside = can.merge(w_new, qs)
        change = can.change(w, x, w_new, q)
        q[~inside] = x[~inside]  # rejected below; its density is the current one's, finite
        return q, np.where(inside, log_ratio + change, -np.inf)
