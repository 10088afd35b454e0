"""Exact rotations of the style vectors along their likelihood-flat orbits.

The likelihood sees a factor's style vectors only through their inner products (the kernels'
``prod_f s_f^T s_f'``, :func:`bayesmotion.gp.kernels.style_gram`), i.e. through the Gram matrix
``S S^T`` of the level vectors ``S: (K, K)`` (one row per level, on the simplex). Every
orthogonal ``Q`` with ``Q 1 = 1`` maps rows on the simplex's plane to rows on it and leaves
``S Q Q^T S^T = S S^T``: the likelihood is constant along these rotations, and only the Dirichlet
prior tells the points of an orbit apart. For K = 4 levels that is a 3-dimensional ridge, which
differential-evolution moves cross slowly: their proposals are differences of other walkers'
positions, which lie anywhere on the ridge.

:class:`StyleRotations` follows each step of an inner move (DE by default) with Metropolis
steps along the orbits: ``S -> S Q``, ``Q = B R B^T + 1 1^T / K`` with ``B`` an orthonormal basis
of the plane orthogonal to ``1`` and ``R`` the Cayley transform of a random skew-symmetric
matrix (``R`` and ``R^-1`` equally likely). The map is linear and volume-preserving on the
simplex's plane, so the acceptance ratio is the ratio of the posterior densities in simplex
coordinates, which here is the ratio of the Dirichlet priors (the likelihood cancels). The new
log-density is the old one plus the change of the style prior and of the stick-breaking
Jacobian: no GP is evaluated. A last sub-step proposes a reflection instead (``det Q = -1``),
so the orientation of the vectors in the plane is not fixed by the rotations. Detailed balance
holds for each sub-step, so the composition with the inner move leaves the posterior invariant
(tested against an exact Dirichlet target).
"""

from __future__ import annotations

import emcee
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from bayesmotion.model.params import (
    STYLE_PREFIX,
    log_dirichlet,
    simplex_to_style,
    style_log_jacobian,
    style_to_simplex,
)

# over walkers, compiled once per shape (not per sampler)
TO_SIMPLEX = jax.jit(jax.vmap(style_to_simplex))


TO_STICKS = jax.jit(jax.vmap(simplex_to_style))


STICK_LOG_JACOBIAN = jax.jit(jax.vmap(style_log_jacobian))


# (W, K, K) style matrices, (K, K) concentrations -> (W,) Dirichlet log-priors summed over levels
LOG_PRIOR_ROWS = jax.jit(lambda S, conc: jnp.sum(log_dirichlet(S, conc), -1))


def style_slices(unravel, x0) -> dict[str, np.ndarray]:
    """factor -> flat indices (K * (K - 1),) of its unconstrained style block, in C order."""
    tree = unravel(jnp.asarray(x0))
    out = {}
    for key in tree:
        if key.startswith(STYLE_PREFIX):
            marked = {k: (jnp.arange(v.size, dtype=float).reshape(v.shape) + 1 if k == key
                          else jnp.zeros_like(v)) for k, v in tree.items()}
            flat, _ = ravel_pytree(marked)
            flat = np.asarray(flat)
            idx = np.flatnonzero(flat)
            out[key[len(STYLE_PREFIX):]] = idx[np.argsort(flat[idx])]
    return out


def plane_basis(K: int) -> np.ndarray:
    """(K, K-1) orthonormal basis of the plane orthogonal to the ones vector."""
    w, V = np.linalg.eigh(np.eye(K) - np.ones((K, K)) / K)
    return V[:, w > 0.5]


def plane_rotations(G: np.ndarray) -> np.ndarray:
    """(..., K-1, K-1) generators -> (..., K, K) rotations Q with Q Q^T = I and Q 1 = 1: the
    Cayley transform R of the skew part of G (det 1; -G gives R^-1), acting on the plane
    orthogonal to the ones vector."""
    k = G.shape[-1]
    B = plane_basis(k + 1)
    eye = np.eye(k)
    A = 0.5 * (G - np.swapaxes(G, -1, -2))
    R = np.linalg.solve(eye - 0.5 * A, eye + 0.5 * A)
    return B @ R @ B.T + 1.0 / (k + 1)


class StyleRotations(emcee.moves.Move):
    """Wraps an emcee move: after each of its steps, ``n_rotations`` Metropolis steps along the
    style vectors' rotation orbits (see the module docstring), for every factor with >= 3 levels,
    then (``reflect``) one Metropolis step through a reflection.

    The rotations have determinant 1, so they keep the orientation of the vectors in the plane
    (the sign of the determinant of their first K - 1 rows); the reflection, ``S -> S H`` with
    ``H = B (I - 2 v v^T) B^T + 1 1^T / K`` and ``v`` uniform on the plane's unit sphere, is its
    own inverse and keeps the likelihood too (its acceptance ratio is the prior ratio), and
    reaches the other orientation, which an inner move that keeps each walker's orientation
    (:class:`bayesmotion.inference.moves.CanonicalDE`) cannot.

    Args:
        inner: the emcee move doing the real work (e.g. ``emcee.moves.DEMove()``).
        slices: factor -> flat indices of its unconstrained style block (:func:`style_slices`).
        concentration: factor -> (K, K) Dirichlet concentrations of the style prior.
        n_rotations: Metropolis sub-steps per step.
        scale: sd of the skew-symmetric generator's entries (radians, roughly).
        reflect: add the reflection sub-step.

    ``acceptance`` holds the fraction of accepted rotation sub-steps so far,
    ``reflection_acceptance`` that of the reflections. The acceptance fraction emcee reports
    stays the inner move's.
    """

    def __init__(self, inner, slices: dict, concentration: dict, n_rotations: int = 10,
                 scale: float = 0.15, reflect: bool = True):
        self.inner = inner
        self.n_rotations = int(n_rotations)
        self.scale = float(scale)
        self.reflect = bool(reflect)
        self.blocks = [(np.asarray(slices[f]), np.asarray(concentration[f], dtype=float))
                       for f in slices if np.asarray(concentration[f]).shape[0] >= 3]
        self._tries = 0
        self._accepts = 0
        self._reflect_tries = 0
        self._reflect_accepts = 0

    @property
    def reflection_acceptance(self) -> float:
        return (self._reflect_accepts / self._reflect_tries if self._reflect_tries
                else float("nan"))

    @property
    def acceptance(self) -> float:
        return self._accepts / self._tries if self._tries else float("nan")

    def propose(self, model, state):
        state, accepted = self.inner.propose(model, state)
        if not self.blocks:
            return state, accepted
        coords = np.array(state.coords, dtype=float)
        log_prob = np.array(state.log_prob, dtype=float)
        ok = np.isfinite(log_prob)
        for idx, conc in self.blocks:
            K = conc.shape[0]
            u = coords[ok][:, idx].reshape(-1, K, K - 1)
            if not len(u):
                continue
            S0 = np.asarray(TO_SIMPLEX(jnp.asarray(u)), dtype=float)
            S = self._rotate(S0, conc, model.random)
            moved = np.any(S != S0, axis=(1, 2))
            if not moved.any():
                continue
            u_new = np.asarray(TO_STICKS(jnp.asarray(S)), dtype=float)
            change = (_log_prior_rows(S, conc) - _log_prior_rows(S0, conc)
                      + np.asarray(STICK_LOG_JACOBIAN(jnp.asarray(u_new)))
                      - np.asarray(STICK_LOG_JACOBIAN(jnp.asarray(u))))
            rows = np.flatnonzero(ok)[moved]
            coords[np.ix_(rows, idx)] = u_new[moved].reshape(len(rows), -1)
            log_prob[rows] += change[moved]
        return emcee.State(coords, log_prob=log_prob, blobs=state.blobs,
                           random_state=state.random_state), accepted

    def _rotate(self, S, conc, random) -> np.ndarray:
        """``n_rotations`` Metropolis steps S -> S Q (vectorised over walkers)."""
        n, K, _ = S.shape
        logp = _log_prior_rows(S, conc)
        for _ in range(self.n_rotations):
            S_new = S @ plane_rotations(self.scale * random.randn(n, K - 1, K - 1))
            S, logp, take = _prior_step(S, S_new, logp, conc, random)
            self._tries += n
            self._accepts += int(take.sum())
        if self.reflect:
            v = random.randn(n, K - 1)
            v /= np.linalg.norm(v, axis=1, keepdims=True)
            B = plane_basis(K)
            H = B @ (np.eye(K - 1) - 2 * v[:, :, None] * v[:, None, :]) @ B.T + 1.0 / K
            S, logp, take = _prior_step(S, S @ H, logp, conc, random)
            self._reflect_tries += n
            self._reflect_accepts += int(take.sum())
        return S


def _prior_step(S, S_new, logp, conc, random):
    """One Metropolis step S -> S_new (W, K, K) of a likelihood-preserving proposal, accepted by
    the Dirichlet prior ratio (``logp``: the current (W,) log-priors); a proposal leaving the
    simplex is rejected. Returns (S, logp, accepted)."""
    inside = np.all(S_new > 0, axis=(1, 2))
    logp_new = np.where(inside, _log_prior_rows(np.where(inside[:, None, None], S_new, S),
                                                conc), -np.inf)
    take = logp_new - logp > np.log(random.rand(len(S)))
    return (np.where(take[:, None, None], S_new, S), np.where(take, logp_new, logp), take)


def _log_prior_rows(S, conc) -> np.ndarray:
    """(W, K, K) style matrices -> (W,) their Dirichlet log-prior, summed over levels."""
    return np.asarray(LOG_PRIOR_ROWS(jnp.asarray(S), jnp.asarray(conc)), dtype=np.float64)
