"""emcee moves for the hierarchical posterior: rotations along the style vectors' symmetry
(exact, and free of GP evaluations), ensemble-preconditioned HMC on a block of coordinates
(:class:`EnsembleHMC`) and independence Metropolis on a block (:class:`IndependenceMove`; see
their docstrings).

The likelihood sees a factor's style vectors only through their inner products (the kernels'
``prod_f s_f^T s_f'``, :func:`bayesmotion.kernels.style_gram`), i.e. through the Gram matrix
``S S^T`` of the level vectors ``S: (K, K)`` (one row per level, on the simplex). Every
orthogonal ``Q`` with ``Q 1 = 1`` maps rows on the simplex's plane to rows on it and leaves
``S Q Q^T S^T = S S^T``: the likelihood is constant along these rotations, and only the Dirichlet
prior tells the points of an orbit apart. For K = 4 levels that is a 3-dimensional ridge, which
differential-evolution moves cross slowly (at the demo size, after 7,000 steps of the DE move
alone, R-hat was 1.24 for the style coordinates and 1.06 for their Gram matrix;
``benchmarks/posterior_convergence.py``).

:class:`StyleRotations` follows each step of an inner move (DE by default) with Metropolis
steps along the orbits: ``S -> S Q``, ``Q = B R B^T + 1 1^T / K`` with ``B`` an orthonormal basis
of the plane orthogonal to ``1`` and ``R`` the Cayley transform of a random skew-symmetric
matrix (``R`` and ``R^-1`` equally likely). The map is linear and volume-preserving on the
simplex's plane, so the acceptance ratio is the ratio of the posterior densities in simplex
coordinates, which here is the ratio of the Dirichlet priors (the likelihood cancels). The new
log-density is the old one plus the change of the style prior and of the stick-breaking
Jacobian: no GP is evaluated. Detailed balance holds for each sub-step, so the composition
with the inner move leaves the posterior invariant (tested against an exact Dirichlet target).
"""

from __future__ import annotations

import emcee
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .params import STYLE_PREFIX, simplex_to_style, style_log_jacobian, style_to_simplex

__all__ = ["EnsembleHMC", "IndependenceMove", "Sequence", "StyleRotations", "plane_rotations",
           "style_slices"]

# over walkers, compiled once per shape (not per sampler)
_TO_S = jax.jit(jax.vmap(style_to_simplex))
_TO_U = jax.jit(jax.vmap(simplex_to_style))
_LOG_JAC = jax.jit(jax.vmap(style_log_jacobian))


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


def _plane_basis(K: int) -> np.ndarray:
    """(K, K-1) orthonormal basis of the plane orthogonal to the ones vector."""
    w, V = np.linalg.eigh(np.eye(K) - np.ones((K, K)) / K)
    return V[:, w > 0.5]


def plane_rotations(G: np.ndarray) -> np.ndarray:
    """(..., K-1, K-1) generators -> (..., K, K) rotations Q with Q Q^T = I and Q 1 = 1: the
    Cayley transform R of the skew part of G (det 1; -G gives R^-1), acting on the plane
    orthogonal to the ones vector."""
    k = G.shape[-1]
    B = _plane_basis(k + 1)
    eye = np.eye(k)
    A = 0.5 * (G - np.swapaxes(G, -1, -2))
    R = np.linalg.solve(eye - 0.5 * A, eye + 0.5 * A)
    return B @ R @ B.T + 1.0 / (k + 1)


class StyleRotations(emcee.moves.Move):
    """Wraps an emcee move: after each of its steps, ``n_rotations`` Metropolis steps along the
    style vectors' rotation orbits (see the module docstring), for every factor with >= 3 levels.

    Args:
        inner: the emcee move doing the real work (e.g. ``emcee.moves.DEMove()``).
        slices: factor -> flat indices of its unconstrained style block (:func:`style_slices`).
        concentration: factor -> (K, K) Dirichlet concentrations of the style prior.
        n_rotations: Metropolis sub-steps per step.
        scale: sd of the skew-symmetric generator's entries (radians, roughly).

    ``acceptance`` holds the fraction of accepted sub-steps so far. The acceptance fraction
    emcee reports stays the inner move's.
    """

    def __init__(self, inner, slices: dict, concentration: dict, n_rotations: int = 10,
                 scale: float = 0.15):
        self.inner = inner
        self.n_rotations = int(n_rotations)
        self.scale = float(scale)
        self.blocks = [(np.asarray(slices[f]), np.asarray(concentration[f], dtype=float))
                       for f in slices if np.asarray(concentration[f]).shape[0] >= 3]
        self._tries = 0
        self._accepts = 0

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
            S0 = np.asarray(_TO_S(jnp.asarray(u)), dtype=float)
            S = self._rotate(S0, conc, model.random)
            moved = np.any(S != S0, axis=(1, 2))
            if not moved.any():
                continue
            u_new = np.asarray(_TO_U(jnp.asarray(S)), dtype=float)
            change = (_log_dirichlet_kernel(S, conc) - _log_dirichlet_kernel(S0, conc)
                      + np.asarray(_LOG_JAC(jnp.asarray(u_new)))
                      - np.asarray(_LOG_JAC(jnp.asarray(u))))
            rows = np.flatnonzero(ok)[moved]
            coords[np.ix_(rows, idx)] = u_new[moved].reshape(len(rows), -1)
            log_prob[rows] += change[moved]
        return emcee.State(coords, log_prob=log_prob, blobs=state.blobs,
                           random_state=state.random_state), accepted

    def _rotate(self, S, conc, random) -> np.ndarray:
        """``n_rotations`` Metropolis steps S -> S Q (vectorised over walkers)."""
        n, K, _ = S.shape
        logp = _log_dirichlet_kernel(S, conc)
        for _ in range(self.n_rotations):
            S_new = S @ plane_rotations(self.scale * random.randn(n, K - 1, K - 1))
            inside = np.all(S_new > 0, axis=(1, 2))
            logp_new = np.where(inside, _log_dirichlet_kernel(np.where(inside[:, None, None],
                                                                       S_new, S), conc),
                                -np.inf)
            take = logp_new - logp > np.log(random.rand(n))
            S = np.where(take[:, None, None], S_new, S)
            logp = np.where(take, logp_new, logp)
            self._tries += n
            self._accepts += int(take.sum())
        return S


def _log_dirichlet_kernel(S, conc) -> np.ndarray:
    """sum over rows of (conc - 1) . log s: the Dirichlet log-density up to its constant."""
    return np.sum((conc - 1.0) * np.log(np.clip(S, 1e-300, None)), axis=(1, 2))


class EnsembleHMC(emcee.moves.Move):
    """Hamiltonian Monte Carlo on a block of coordinates, preconditioned by the ensemble.

    Each step splits the walkers at random into two halves. Every walker of one half takes one
    HMC trajectory in the ``block`` coordinates (the others held: a Gibbs block update), with
    the other half's sample covariance over the block, shrunk toward its diagonal, as the
    inverse mass matrix; then the halves swap. The preconditioner depends only on walkers that
    do not move during the update, so each half-step leaves the target invariant, as in emcee's
    red-blue moves. Trajectories take ``n_leapfrog`` leapfrog steps (an integer drawn from that
    inclusive range per half-step) of size ``step_size`` times a per-walker factor drawn from
    ``jitter``, in whitened units, where the target is roughly a standard normal; the factors
    break the periodic orbits of a fixed step, and a walker in a region narrower than the
    ensemble's average still takes small steps now and then. The random draws come from emcee's
    generator, so a run resumed from a backend continues the same chain.

    Why: at the demo size the differential-evolution move accepts 6% of its proposals and the
    hyperparameters' autocorrelation time reached 300 steps (the posterior is nearly Gaussian
    there, but strongly correlated, and the style coordinates' heavy tails spoil DE's joint
    proposals); HMC on the hyperparameter block brought it to 4-9 steps in a 250-step run.

    Args:
        logp: the log-density of one flat vector, a pure JAX function (e.g. ``Target._logp``).
        block: flat indices of the coordinates moved.
        step_size: leapfrog step in whitened units.
        n_leapfrog: (low, high) leapfrog steps per trajectory.
        jitter: (low, high) range of the per-walker factor on ``step_size``.
        shrinkage: weight of the diagonal in the preconditioner, (1 - w) S + w diag(S).

    ``acceptance`` holds the fraction of accepted trajectories so far.
    """

    def __init__(self, logp, block, step_size: float = 0.6, n_leapfrog=(2, 4),
                 jitter=(0.5, 1.1), shrinkage: float = 0.05):
        block = np.asarray(block, dtype=int).ravel()
        if not block.size:
            raise ValueError("EnsembleHMC needs a non-empty block of coordinates")
        lo, hi = (int(v) for v in n_leapfrog)
        if not 1 <= lo <= hi:
            raise ValueError(f"n_leapfrog must be (low, high) with 1 <= low <= high, "
                             f"got {n_leapfrog!r}")
        if not (step_size > 0 and 0 < jitter[0] <= jitter[1]):
            raise ValueError(f"step_size must be > 0 and jitter (low, high) with "
                             f"0 < low <= high, got {step_size!r} and {jitter!r}")
        if not 0.0 <= shrinkage <= 1.0:
            raise ValueError(f"shrinkage must be in [0, 1], got {shrinkage!r}")
        self.block = block
        self.step_size = float(step_size)
        self.n_leapfrog = (lo, hi)
        self.jitter = (float(jitter[0]), float(jitter[1]))
        self.shrinkage = float(shrinkage)
        self._tries = 0
        self._accepts = 0
        self._trajectory = jax.jit(_leapfrog_fn(jax.vmap(jax.value_and_grad(logp)),
                                                jnp.asarray(block)))

    @property
    def acceptance(self) -> float:
        return self._accepts / self._tries if self._tries else float("nan")

    def propose(self, model, state):
        x = np.array(state.coords, dtype=float)
        log_prob = np.array(state.log_prob, dtype=float)
        n = len(x)
        if n < 4:
            raise ValueError(f"EnsembleHMC needs at least 4 walkers, got {n}")
        order = model.random.permutation(n)
        halves = (order[:n // 2], order[n // 2:])
        accepted = np.zeros(n, dtype=bool)
        for moving, fixed in (halves, halves[::-1]):
            chol = self._preconditioner(x[fixed][:, self.block])
            r0 = model.random.randn(len(moving), self.block.size)
            eps = self.step_size * model.random.uniform(*self.jitter, size=len(moving))
            steps = model.random.randint(self.n_leapfrog[0], self.n_leapfrog[1] + 1)
            lp0, x1, lp1, r1 = (np.asarray(v) for v in self._trajectory(
                jnp.asarray(x[moving]), jnp.asarray(r0), jnp.asarray(chol), jnp.asarray(eps),
                steps))
            with np.errstate(invalid="ignore", over="ignore"):
                log_ratio = (lp1 - 0.5 * np.sum(r1 ** 2, 1)) - (lp0 - 0.5 * np.sum(r0 ** 2, 1))
            u = np.log(model.random.rand(len(moving)))
            take = np.isfinite(log_ratio) & np.isfinite(lp1) & (u < log_ratio)
            rows = moving[take]
            x[rows] = x1[take]
            log_prob[rows] = lp1[take]
            accepted[rows] = True
            self._tries += len(moving)
            self._accepts += int(take.sum())
        return emcee.State(x, log_prob=log_prob, blobs=state.blobs,
                           random_state=state.random_state), accepted

    def _preconditioner(self, z) -> np.ndarray:
        """Cholesky factor of the shrunk sample covariance of the rows of ``z``."""
        S = np.atleast_2d(np.cov(z.T))
        d = np.diag(S).copy()
        d = np.where(np.isfinite(d) & (d > 0), d, 1.0)
        S = (1.0 - self.shrinkage) * S + self.shrinkage * np.diag(d)
        S[np.diag_indices_from(S)] += 1e-12 * d
        try:
            return np.linalg.cholesky(S)
        except np.linalg.LinAlgError:  # a degenerate ensemble: fall back to the diagonal
            return np.diag(np.sqrt(d))


def _leapfrog_fn(value_and_grad, block):
    """(x, r, chol, eps, steps) -> (lp at x, x', lp at x', r') after ``steps`` leapfrog steps in
    the whitened block coordinates z, x_block = chol z + const (gradient chol^T g_block); one
    compiled function, the start's value and gradient included."""

    def run(x, r, chol, eps, steps):
        e = eps[:, None]
        lp0, g = value_and_grad(x)

        def body(_, carry):
            x, lp, g, r = carry
            r = r + 0.5 * e * (g[:, block] @ chol)
            x = x.at[:, block].add((e * r) @ chol.T)
            lp, g = value_and_grad(x)
            r = r + 0.5 * e * (g[:, block] @ chol)
            return x, lp, g, r

        x, lp, _, r = jax.lax.fori_loop(0, steps, body, (x, lp0, g, r))
        return lp0, x, lp, r

    return run


class IndependenceMove(emcee.moves.MHMove):
    """Independence Metropolis on a block of coordinates, with a fixed multivariate-t proposal
    or a fixed mixture of them.

    Every walker proposes new ``block`` coordinates (the others held: a Gibbs block update)
    drawn from a multivariate t with ``df`` degrees of freedom, location ``mean`` and scale
    matrix ``cov``, whatever its current position, and accepts with the Metropolis-Hastings
    ratio ``p(x') q(x) / (p(x) q(x'))``. The proposal is fixed, so the move leaves the target
    invariant. It costs one log-density per walker and step, as a DE step does, but an accepted
    proposal is a fresh draw, not a small step: where the block's conditional posterior is close
    to the t (near-Gaussian, however correlated), the autocorrelation time is about
    2 / acceptance - 1. Where the block's conditional posterior differs from the proposal (the
    tails, or where the other coordinates shift it), a walker is rarely accepted and "sticks"
    until another move (DE) takes it back: at the demo size 5% of the posterior's states accept
    under 0.2% of proposals.

    With ``mean`` (k, d), ``cov`` (k, d, d) and ``weights`` (k,) the proposal is the mixture
    ``sum_i w_i t(mean_i, cov_i)``, one component per mode of a multimodal posterior: a walker
    in one mode proposes a point of another with probability of that mode's weight, a jump that
    local moves (DE) make only by crossing the low-density region between the modes.

    A proposal fitted to the other half of the ensemble (red-blue, as emcee's moves) was tried
    at the demo size: with 27 walkers per half, the 14-dimensional covariance is too noisy, and
    5% of proposals were accepted, against 25% with the Laplace approximation's covariance.

    Args:
        block: flat indices of the coordinates moved.
        mean: (len(block),) location of the proposal, or (k, len(block)) of its k components.
        cov: (len(block), len(block)) scale matrix, symmetric positive definite, or
            (k, len(block), len(block)) one per component.
        df: degrees of freedom of the t (> 0); large values approach a Gaussian.
        weights: (k,) positive mixture weights (normalised here); default equal.

    ``acceptance`` holds the fraction of accepted proposals so far.
    """

    def __init__(self, block, mean, cov, df: float = 20.0, weights=None):
        block = np.asarray(block, dtype=int).ravel()
        if not block.size:
            raise ValueError("IndependenceMove needs a non-empty block of coordinates")
        d = block.size
        mean = np.asarray(mean, dtype=float)
        mixture = mean.ndim == 2
        means = mean if mixture else mean.ravel()[None]
        k = means.shape[0]
        want_mean = (k, d) if mixture else (d,)
        if means.shape != (k, d) or (not mixture and mean.size != d):
            raise ValueError(f"mean must have shape {want_mean} for a block of {d} "
                             f"coordinates, got {mean.shape}")
        cov = np.asarray(cov, dtype=float)
        covs = cov if mixture else np.atleast_2d(cov)[None]
        if covs.shape != (k, d, d):
            want = (k, d, d) if mixture else (d, d)
            raise ValueError(f"cov must have shape {want} for a block of {d} coordinates, got "
                             f"{cov.shape}")
        try:
            self._chols = np.linalg.cholesky(0.5 * (covs + np.swapaxes(covs, -1, -2)))
        except np.linalg.LinAlgError:
            raise ValueError("IndependenceMove: cov must be symmetric positive definite") from None
        w = np.ones(k) if weights is None else np.asarray(weights, dtype=float).ravel()
        if w.shape != (k,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ValueError(f"weights must be {k} positive numbers, got {weights!r}")
        if not df > 0:
            raise ValueError(f"df must be > 0, got {df!r}")
        self.block = block
        self.means = means
        self.weights = w / w.sum()
        self.df = float(df)
        # log weight - log det of each component's scale (the t's other constants are shared)
        self._log_norm = np.log(self.weights) - np.sum(
            np.log(np.diagonal(self._chols, axis1=-2, axis2=-1)), -1)
        self._tries = 0
        self._accepts = 0
        super().__init__(self._propose)

    @property
    def mean(self) -> np.ndarray:
        """Location of the proposal's first (or only) component."""
        return self.means[0]

    @property
    def acceptance(self) -> float:
        return self._accepts / self._tries if self._tries else float("nan")

    def propose(self, model, state):
        # emcee's update writes into the state's arrays: work on copies
        blobs = None if state.blobs is None else np.array(state.blobs)
        state = emcee.State(np.array(state.coords, dtype=float),
                            log_prob=np.array(state.log_prob, dtype=float), blobs=blobs,
                            random_state=state.random_state)
        state, accepted = super().propose(model, state)
        self._tries += len(accepted)
        self._accepts += int(np.sum(accepted))
        return state, accepted

    def log_q(self, z) -> np.ndarray:
        """Log-density of the proposal at rows ``z`` of block coordinates, up to a constant."""
        z = np.atleast_2d(z)
        terms = np.empty((len(self.means), len(z)))
        for i, (m, L) in enumerate(zip(self.means, self._chols, strict=True)):
            w = np.linalg.solve(L, (z - m).T)
            terms[i] = self._log_norm[i] - 0.5 * (self.df + self.block.size) * np.log1p(
                np.sum(w ** 2, 0) / self.df)
        if len(terms) == 1:
            return terms[0]
        top = terms.max(0)
        return top + np.log(np.sum(np.exp(terms - top), 0))

    def _propose(self, coords, random):
        x = np.asarray(coords, dtype=float)
        n, d = x.shape[0], self.block.size
        scale = np.sqrt(self.df / random.chisquare(self.df, size=n))
        comp = (np.zeros(n, dtype=int) if len(self.means) == 1
                else random.choice(len(self.means), size=n, p=self.weights))
        new = x.copy()
        step = np.einsum("nij,nj->ni", self._chols[comp], random.randn(n, d))
        new[:, self.block] = self.means[comp] + scale[:, None] * step
        return new, self.log_q(x[:, self.block]) - self.log_q(new[:, self.block])


class Sequence(emcee.moves.Move):
    """Applies ``moves`` one after the other at every step; a walker counts as accepted when
    any of them moved it. Each move leaves the target invariant, so their composition does."""

    def __init__(self, *moves):
        if not moves:
            raise ValueError("Sequence needs at least one move")
        self.moves = moves

    def propose(self, model, state):
        accepted = np.zeros(len(state.coords), dtype=bool)
        for move in self.moves:
            state, acc = move.propose(model, state)
            accepted |= np.asarray(acc, dtype=bool)
        return state, accepted
