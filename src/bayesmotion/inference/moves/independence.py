"""Independence Metropolis on a block of coordinates (see :class:`IndependenceMove`)."""

from __future__ import annotations

import emcee
import numpy as np


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
    until another move (DE) takes it back.

    With ``mean`` (k, d), ``cov`` (k, d, d) and ``weights`` (k,) the proposal is the mixture
    ``sum_i w_i t(mean_i, cov_i)``, one component per mode of a multimodal posterior: a walker
    in one mode proposes a point of another with probability of that mode's weight, a jump that
    local moves (DE) make only by crossing the low-density region between the modes.

    The proposal is not fitted to the other half of the ensemble (red-blue, as emcee's moves):
    at the demo size, with 27 walkers per half, a 14-dimensional covariance estimated from one
    half is too noisy for a proposal that must match the whole posterior.

    Args:
        block: flat indices of the coordinates moved.
        mean: (len(block),) location of the proposal, or (k, len(block)) of its k components.
        cov: (len(block), len(block)) scale matrix, symmetric positive definite, or
            (k, len(block), len(block)) one per component.
        df: degrees of freedom of the t (> 0); large values approach a Gaussian.
        weights: (k,) positive mixture weights (normalised here); default equal.
        shear: a :class:`bayesmotion.inference.moves.StyleShear` (or anything with vmapped
            ``forward`` and ``inverse`` maps of unit Jacobian): the block, ``mean`` and ``cov``
            are then in its coordinates ``y = forward(x)``; a walker's ``y`` gets the new block
            and maps back, and the ratio is the same (a unit Jacobian adds nothing). Default:
            the sampled coordinates themselves.
        marginal: a :class:`bayesmotion.inference.moves.SinhArcsinh` over the block's
            coordinates, or None: the t (mixture) is then the law of the mapped block
            ``marginal.forward(block)``, and ``mean`` and ``cov`` are in those coordinates; the
            proposal's density carries the map's log-Jacobian. A drawn point the map cannot
            take back (overflow) is refused.

    ``acceptance`` holds the fraction of accepted proposals so far.
    """

    def __init__(self, block, mean, cov, df: float = 20.0, weights=None, shear=None,
                 marginal=None):
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
        if marginal is not None and marginal.ndim != d:
            raise ValueError(f"marginal maps {marginal.ndim} coordinates, the block has {d}")
        self.block = block
        self.marginal = marginal
        self.shear = shear
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
        log_jac = 0.0
        if self.marginal is not None:
            z, log_jac = self.marginal.forward(z)
        terms = np.empty((len(self.means), len(z)))
        for i, (m, L) in enumerate(zip(self.means, self._chols, strict=True)):
            w = np.linalg.solve(L, (z - m).T)
            terms[i] = self._log_norm[i] - 0.5 * (self.df + self.block.size) * np.log1p(
                np.sum(w ** 2, 0) / self.df)
        if len(terms) == 1:
            return terms[0] + log_jac
        top = terms.max(0)
        return top + np.log(np.sum(np.exp(terms - top), 0)) + log_jac

    def draw(self, z, random) -> tuple[np.ndarray, np.ndarray]:
        """Fresh block coordinates for walkers at block coordinates ``z`` (n, len(block)):
        (new (n, len(block)), log q(z) - log q(new), the proposal's part of the ratio)."""
        n, d = z.shape[0], self.block.size
        scale = np.sqrt(self.df / random.chisquare(self.df, size=n))
        comp = (np.zeros(n, dtype=int) if len(self.means) == 1
                else random.choice(len(self.means), size=n, p=self.weights))
        step = np.einsum("nij,nj->ni", self._chols[comp], random.randn(n, d))
        new = self.means[comp] + scale[:, None] * step
        if self.marginal is None:
            return new, self.log_q(z) - self.log_q(new)
        new = self.marginal.inverse(new)
        ok = np.all(np.isfinite(new), 1)
        new[~ok] = z[~ok]
        log_q_new = self.log_q(new)
        ok &= np.isfinite(log_q_new)  # a point so far out that its map's slope overflows
        new[~ok] = z[~ok]  # refused below; a finite point keeps the density finite
        with np.errstate(invalid="ignore"):
            return new, np.where(ok, self.log_q(z) - log_q_new, -np.inf)

    def _propose(self, coords, random):
        x = np.asarray(coords, dtype=float)
        if self.shear is not None:
            x = np.asarray(self.shear.forward(x), dtype=float)
        new = x.copy()
        new[:, self.block], log_ratio = self.draw(x[:, self.block], random)
        if self.shear is not None:
            new = np.asarray(self.shear.inverse(new), dtype=float)
        return new, log_ratio
