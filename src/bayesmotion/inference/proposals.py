"""emcee's default moves for the H-GPDM posterior: differential evolution, the style vectors'
rotations, and the independence step whose proposal is a mixture over the posterior's modes."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from bayesmotion.inference.moves import (
    CanonicalDE,
    CanonicalIndependence,
    CanonicalStyles,
    EnsembleHMC,
    IndependenceMove,
    Sequence,
    ShearedDE,
    SinhArcsinh,
    StyleRotations,
    StyleShear,
    style_slices,
)
from bayesmotion.model.params import simplex_to_style

# the independence move: a rotated style coordinate whose Laplace sd is below PINNED_SD (logit
# units) is pinned by the likelihood (the rotations keep each style vector's norm, and near its
# vertex one stick coordinate is that norm), so it joins the non-rotated block (0.2 against 0.1:
# min bulk ESS 3.1x at the quick demo's size, benchmarks/results/pinned_threshold.json); the first
# min(ADAPT_STEPS, n_steps // 4) steps propose from the Laplace approximation, the rest from a
# t fitted to the chain (the adaptation's last two thirds, then REFIT_STEPS)
PINNED_SD = 0.2


ADAPT_STEPS = 150

# after the adaptation the proposal is refitted, once the chain reaches each of these steps, to
# every state since the adaptation: at the demo size a t on the 23 block coordinates fitted to
# the adaptation's steps 50-150 accepts 0.23 of its proposals, fitted to steps 150-500 0.34,
# and after the sinh-arcsinh map 0.26 and 0.45 (benchmarks/results/independence_refit.json)
REFIT_STEPS = (250, 500, 1000)

MARGINAL_MAP = True
"""The independence proposal fitted after the adaptation is a t in the coordinates of a
sinh-arcsinh map of each block coordinate (:class:`bayesmotion.inference.moves.SinhArcsinh`)."""
MAP_FIT_ROWS = 4096


def _rotated(moves) -> set[int]:
    """Flat indices the style rotations move (none when ``moves`` has no rotations)."""
    return ({int(i) for idx, _ in moves.blocks for i in idx}
            if isinstance(moves, StyleRotations) else set())


def independence_block(target, cov) -> np.ndarray:
    """The coordinates the independence move draws: all but the rotated style coordinates,
    plus those of them the likelihood pins (Laplace sd < PINNED_SD)."""
    rotated = _rotated(default_moves(target))
    sd = np.sqrt(np.diag(cov))
    return np.array([i for i in range(target.ndim) if i not in rotated or sd[i] < PINNED_SD],
                    dtype=int)


def idle_factor_modes(target, centre, cov, block) -> list[dict]:
    """Local modes of the sampled density beside the conditional MAP ``centre``: one search
    per style factor whose coordinates the independence move draws (those the rotations do not
    move: two-level factors), started from ``centre`` with that factor's style vectors at the
    simplex's centre, where the factor is idle and the output scales can take up its job.

    Such a mode, where a fit has one, lies several posterior sd away in each of the factor's
    coordinates, and DE walkers cross between the two in thousands of steps; the demo's fit
    has none (``benchmarks/results/posterior_convergence.json``, key ``modes_found``).

    Returns one dict per mode, the main one first: ``x`` (flat), ``cov`` (Laplace), ``logp``,
    ``log_evidence`` (logp + log det(cov) / 2) and ``weight`` (normalised evidence); a search
    that ends within 3 Laplace sd of a mode already found, or more than 20 nats of evidence below
    the main mode, adds nothing."""
    def evidence(lp, c):
        return lp + 0.5 * np.linalg.slogdet(c)[1]

    def logp(x):
        return float(np.asarray(target.logp_batch(jnp.asarray(x)[None]))[0])

    lp0 = logp(centre)
    modes = [{"x": centre, "cov": cov, "logp": lp0, "log_evidence": evidence(lp0, cov),
              "searched_from": None}]
    if not hasattr(target, "unravel"):
        return _weighted(modes)
    inside = set(np.asarray(block).tolist())
    for factor, idx in style_slices(target.unravel, target.x0).items():
        if not set(idx.tolist()) <= inside:
            continue
        K = int(round((1 + np.sqrt(1 + 4 * idx.size)) / 2))  # idx holds K (K - 1) entries
        start = np.array(centre, dtype=np.float64)
        start[idx] = np.asarray(simplex_to_style(np.full((K, K), 1.0 / K))).ravel()
        x, diag = target.conditional_map(start=start)
        if not diag.get("converged", True):
            continue
        lp = logp(x)
        c = target.laplace(x)
        ev = evidence(lp, c)
        b = np.asarray(block)
        far = all(np.sqrt(np.sum(np.linalg.solve(np.linalg.cholesky(m["cov"][np.ix_(b, b)]),
                                                 x[b] - m["x"][b]) ** 2)) > 3.0
                  for m in modes)
        if far and np.isfinite(ev) and ev > modes[0]["log_evidence"] - 20.0:
            modes.append({"x": x, "cov": c, "logp": lp, "log_evidence": ev,
                          "searched_from": factor})
    return _weighted(modes)


def _weighted(modes):
    ev = np.array([m["log_evidence"] for m in modes])
    w = np.exp(ev - ev.max())
    for m, wi in zip(modes, w / w.sum(), strict=True):
        m["weight"] = float(wi)
    return modes


def sheared_modes(modes: list[dict], shear) -> list[dict]:
    """``modes`` (:func:`idle_factor_modes`) in the coordinates of ``shear`` (a
    :class:`bayesmotion.inference.moves.StyleShear`, or None: unchanged): each centre mapped, each
    Laplace covariance carried through the map's Jacobian at it."""
    if shear is None:
        return modes

    def one(v):
        return shear.forward(v[None])[0]

    out = []
    for m in modes:
        J = np.asarray(jax.jacfwd(one)(jnp.asarray(m["x"], dtype=float)))
        out.append({**m, "x": np.asarray(one(jnp.asarray(m["x"], dtype=float))),
                    "cov": J @ np.asarray(m["cov"]) @ J.T})
    return out


def nearest_mode(block, modes, z) -> np.ndarray:
    """Index of the mode (:func:`idle_factor_modes`) nearest each row of ``z`` (block
    coordinates), by Mahalanobis distance under the mode's Laplace covariance."""
    d2 = np.array([np.sum(np.linalg.solve(np.linalg.cholesky(m["cov"][np.ix_(block, block)]),
                                          (z - m["x"][block]).T) ** 2, 0) for m in modes])
    return d2.argmin(0)


def mixture_proposal(block, modes, z=None):
    """(block, means, covs, weights, marginal) of the independence move: each mode's Laplace
    approximation; with ``z`` (adaptation states, block coordinates), a sinh-arcsinh map of each
    coordinate fitted to them (``marginal``, :class:`bayesmotion.inference.moves.SinhArcsinh`)
    and, in its coordinates, each mode's sample moments over the states nearest it (Mahalanobis
    under its Laplace), where it has at least 2 (d + 1) of them, else its Laplace approximation
    carried through the map. Weights: the modes' Laplace evidence, at least 0.05 each."""
    means = np.array([m["x"][block] for m in modes])
    covs = np.array([m["cov"][np.ix_(block, block)] for m in modes])
    if z is None:
        return _proposal(block, means, covs, modes)
    near = nearest_mode(block, modes, z)
    return _mapped_proposal(block, z, near, means, covs, modes)


def _mapped_proposal(block, z, near, means, covs, modes):
    """The proposal in the coordinates of a sinh-arcsinh map fitted to ``z`` (rows of block
    coordinates, ``near`` each row's mode): each mode's moments there, or (too few rows) its
    Gaussian ``means[i], covs[i]`` carried through the map's slope at the mean."""
    # the map is fitted to at most MAP_FIT_ROWS states spread evenly over the window (each
    # evaluation of its likelihood costs ~1.5 microseconds per state and coordinate)
    rows = np.unique(np.linspace(0, len(z) - 1, min(len(z), MAP_FIT_ROWS)).astype(int))
    marginal = SinhArcsinh.fit(z[rows]) if MARGINAL_MAP else None
    y = z if marginal is None else marginal.forward(z)[0]
    out_means, out_covs = [], []
    for i in range(len(modes)):
        yi = y[near == i]
        if len(yi) >= 2 * (block.size + 1):
            out_means.append(yi.mean(0))
            out_covs.append(_pooled_cov(yi))
        elif marginal is None:
            out_means.append(means[i])
            out_covs.append(covs[i])
        else:
            slope = marginal.slope(means[i][None])[0]
            out_means.append(marginal.forward(means[i][None])[0][0])
            out_covs.append(slope[:, None] * covs[i] * slope[None, :])
    return _proposal(block, np.array(out_means), np.array(out_covs), modes, marginal)


def _proposal(block, means, covs, modes, marginal=None):
    w = np.maximum([m["weight"] for m in modes], 0.05)
    if len(modes) == 1:
        return block, means[0], covs[0], None, marginal
    return block, means, covs, w / w.sum(), marginal


def canonical_block(canonical, block) -> np.ndarray:
    """The independence block in the canonical coordinates of ``canonical`` (a
    :class:`bayesmotion.inference.moves.CanonicalStyles`): ``block`` without the style
    coordinates of its factors, plus each factor's Gram-factor entries (``T``)."""
    styles = set(canonical.styles().tolist())
    return np.array(sorted([int(i) for i in block if int(i) not in styles]
                           + canonical.slots().tolist()), dtype=int)


def canonical_mixture(canonical, block, modes, z):
    """:func:`mixture_proposal` in canonical coordinates over :func:`canonical_block`: the
    adaptation states ``z`` (model coordinates, rows) are split between the modes as there (in
    the coordinates of ``canonical``'s shear, over ``block``), the sinh-arcsinh map is fitted to
    their canonical coordinates, and each mode's moments are taken over its states there; a
    mode with fewer than 2 (d + 1) states gets its Laplace approximation carried through the
    canonical map's Jacobian (central differences) and the sinh-arcsinh map's slope."""
    cblock = canonical_block(canonical, block)
    sheared = sheared_modes(modes, canonical.shear)
    y = z if canonical.shear is None else np.asarray(canonical.shear.forward(z))
    near = nearest_mode(block, sheared, y[:, block])
    zw = canonical.split(z)[0][:, cblock]
    means, covs = [], []
    for m in modes:  # each mode's Laplace approximation in canonical coordinates
        x = np.asarray(m["x"], dtype=np.float64)
        eps = 1e-5
        steps = np.concatenate([x + eps * np.eye(x.size), x - eps * np.eye(x.size)])
        ws = canonical.split(np.concatenate([x[None], steps]))[0][:, cblock]
        J = (ws[1:1 + x.size] - ws[1 + x.size:]).T / (2 * eps)
        means.append(ws[0])
        covs.append(J @ np.asarray(m["cov"]) @ J.T + 1e-10 * np.eye(cblock.size))
    return _mapped_proposal(cblock, zw, near, np.array(means), np.array(covs), modes)


def canonical_styles(target) -> CanonicalStyles:
    """The canonical coordinates (:class:`bayesmotion.inference.moves.CanonicalStyles`, aligned)
    of ``target``'s style factors with 3 or more levels, in its shear's coordinates; none for a
    bare density."""
    slices = style_slices(target.unravel, target.x0) if hasattr(target, "unravel") else {}
    return CanonicalStyles(slices, StyleShear.for_target(target))


def default_moves(target, hmc: bool = False, proposal=None, canonical_proposal=None):
    """DE (proposing in :class:`bayesmotion.inference.moves.StyleShear`'s coordinates when the
    target samples style vectors with the output scales they multiply,
    :class:`bayesmotion.inference.moves.ShearedDE`, and there in the canonical coordinates of
    the factors with 3 or more levels, :class:`bayesmotion.inference.moves.CanonicalDE`), each
    step followed by the style rotations when the target samples style vectors; then, with
    ``proposal = (block, mean, cov[, weights[, marginal]])`` (a mixture when ``mean`` is 2-d;
    ``marginal`` a sinh-arcsinh map the t is taken after), an
    independence step on that block: in the shear's coordinates where there is one
    (:func:`sheared_modes`; :class:`bayesmotion.inference.moves.IndependenceMove`), or, with
    ``canonical_proposal`` (the :class:`bayesmotion.inference.moves.CanonicalStyles` the
    proposal is in, :func:`canonical_mixture`; DE then uses it too), in its canonical
    coordinates (:class:`bayesmotion.inference.moves.CanonicalIndependence`); then (``hmc``)
    ensemble-preconditioned HMC steps (:class:`bayesmotion.inference.moves.EnsembleHMC`): one on
    the coordinates the rotations do not move, one on those they do.

    Not DESnookerMove: emcee 3.1.6's snooker move does not leave the target invariant (its
    projection divides by sqrt(|z - x|) instead of |z - x|); on 14 iid logit-Beta(11, 1)
    coordinates it returns sd 0.88 for an exact 1.32 (tests/test_posterior.py checks the default
    moves on that target)."""
    import emcee

    shear = StyleShear.for_target(target)
    slices = style_slices(target.unravel, target.x0) if hasattr(target, "unravel") else {}
    canonical = canonical_styles(target) if canonical_proposal is None else canonical_proposal
    if canonical.blocks:  # DE on what the likelihood sees of the rotated style vectors
        moves = CanonicalDE(canonical)
    else:  # DE along the output scales' ridge with the style norms, where there is one
        moves = emcee.moves.DEMove() if shear is None else ShearedDE(shear)
    if slices:  # cross the style vectors' rotation ridges without GP evaluations
        conc = target.model.log_posterior_fn.style_prior.concentration
        moves = StyleRotations(moves, slices, conc)
    rotated = _rotated(moves)
    extra = []
    if proposal is not None:
        # the hyperparameters are nearly Gaussian, strongly correlated (DE crawls there): an
        # accepted independence proposal is a fresh draw
        block, mean, cov, *rest = proposal
        weights, marginal = (list(rest) + [None, None])[:2]
        extra = [CanonicalIndependence(canonical_proposal, block, mean, cov, weights=weights,
                                       marginal=marginal)
                 if canonical_proposal is not None else
                 IndependenceMove(block, mean, cov, weights=weights, shear=shear,
                                  marginal=marginal)]
    if not (hmc and hasattr(target, "_logp")):
        return Sequence(moves, *extra) if extra else moves
    # the hyperparameters (and two-level styles) are nearly Gaussian but strongly correlated,
    # where DE crawls; the rotated styles are heavy-tailed,
    # so they get their own block, preconditioner and a smaller step
    block = [i for i in range(target.ndim) if i not in rotated]
    hmcs = [EnsembleHMC(target._logp, b, step_size=step, jitter=(0.2, 1.1), shrinkage=shrink)
            for b, step, shrink in ((block, 0.6, 0.05), (sorted(rotated), 0.5, 0.1)) if b]
    return Sequence(moves, *extra, *hmcs)


def move_stats(moves) -> dict:
    """Acceptance of the style rotations and their reflections, of the independence step and of
    the HMC blocks, in the order they run (None where absent)."""
    found = {}
    stack = [moves]
    while stack:
        m = stack.pop()
        if isinstance(m, Sequence):
            stack.extend(reversed(m.moves))  # popped in the order they run
        elif isinstance(m, StyleRotations):
            found["rotation_acceptance"] = m.acceptance
            found["reflection_acceptance"] = m.reflection_acceptance
            stack.append(m.inner)
        elif isinstance(m, EnsembleHMC):
            found.setdefault("hmc", []).append(m.acceptance)
        elif isinstance(m, IndependenceMove):
            found["independence_acceptance"] = m.acceptance
    hmc = found.get("hmc")
    return {"rotation_acceptance": found.get("rotation_acceptance"),
            "reflection_acceptance": found.get("reflection_acceptance"),
            "independence_acceptance": found.get("independence_acceptance"),
            "hmc_acceptance": None if hmc is None else float(np.mean(hmc)),
            "hmc_block_acceptance": hmc}


def phase_stats(ran) -> dict:
    """:func:`move_stats` over the phases run, each acceptance weighted by its phase's steps
    (None where no phase ran or the move is absent)."""
    stats = [(move_stats(m), n) for m, n in ran]
    out = {}
    for key in ("rotation_acceptance", "reflection_acceptance", "independence_acceptance",
                "hmc_acceptance"):
        vals = [(s[key], n) for s, n in stats if s[key] is not None and np.isfinite(s[key])]
        out[key] = (float(sum(v * n for v, n in vals) / sum(n for _, n in vals))
                    if vals else None)
    blocks = [(np.asarray(s["hmc_block_acceptance"]), n) for s, n in stats
              if s["hmc_block_acceptance"] is not None]
    out["hmc_block_acceptance"] = ([float(v) for v in sum(a * n for a, n in blocks)
                                    / sum(n for _, n in blocks)] if blocks else None)
    return out


def _pooled_cov(z) -> np.ndarray:
    """Sample covariance of the rows of ``z``, with a ridge of 1e-10 of its diagonal."""
    c = np.atleast_2d(np.cov(z.T))
    c[np.diag_indices_from(c)] += 1e-10 * np.maximum(np.diag(c), 1e-300)
    return c


def adapt_steps(n_steps: int) -> int:
    return min(ADAPT_STEPS, n_steps // 4)


def refit_steps(n_adapt: int) -> list[int]:
    """The steps (:data:`REFIT_STEPS` past the adaptation's ``n_adapt``) at which the
    independence proposal is refitted; none without an adaptation (its proposal then stays the
    Laplace approximation). They do not depend on the run's length: stored with a chain file
    beside the first call's adaptation length, they give a resumed run the first call's
    kernels."""
    return [r for r in REFIT_STEPS if r > n_adapt] if n_adapt > 0 else []
