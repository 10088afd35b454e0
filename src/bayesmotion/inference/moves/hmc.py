"""Ensemble-preconditioned HMC on a block of coordinates (see :class:`EnsembleHMC`)."""

from __future__ import annotations

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.gp.batch import over_points


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

    Why: the hyperparameters' posterior is nearly Gaussian but strongly correlated, and the
    style coordinates' heavy tails spoil differential evolution's joint proposals; gradient
    steps preconditioned by the ensemble follow the correlations. Each such step costs about
    13 ensemble steps at the built-in size (``benchmarks/results/sampler_ess.json``, key
    ``eval_costs``), so it is opt-in (``sample_posterior(hmc=True)``).

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
        self._trajectory = jax.jit(_leapfrog_fn(over_points(jax.value_and_grad(logp)),
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
