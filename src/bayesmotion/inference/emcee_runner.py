"""emcee runs of the posterior: one joint ensemble (in two phases with the independence
move) or two ensembles over its factors; resumable from an HDF5 chain file."""

from __future__ import annotations

import os
import sys
import time

import numpy as np

from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.chainfile import (
    ADAPT_ATTR,
    REFIT_ATTR,
    ChainFile,
    check_chain_file,
    committing,
    h5_errors,
    open_h5,
    refit_attr,
    write_h5,
)
from bayesmotion.inference.moves import StyleShear
from bayesmotion.inference.posterior import format_seconds, posterior_from_chain
from bayesmotion.inference.proposals import (
    adapt_steps,
    canonical_block,
    canonical_mixture,
    canonical_styles,
    default_moves,
    idle_factor_modes,
    independence_block,
    mixture_proposal,
    move_stats,
    phase_stats,
    refit_steps,
    sheared_modes,
)
from bayesmotion.inference.target import Target, in_halves, start_points

CANONICAL_INDEPENDENCE = True
"""After the adaptation, the independence step draws the rotated style vectors' Gram factors
(canonical coordinates) with the hyperparameters."""


def _n_walkers(n_walkers, ndim) -> int:
    W = n_walkers or 2 * ndim + 2
    W += W % 2
    if W < 2 * ndim:
        raise BayesmotionError(f"emcee needs at least 2 * ndim = {2 * ndim} walkers, got {W}")
    return W


def _open_backend(backend, name, W, ndim, log_prob):
    """(emcee HDF5 backend or None, steps it already holds); a resumed file must hold a run of
    this shape and of this posterior. The caller has checked the file
    (:func:`~bayesmotion.inference.chainfile.check_chain_file`): a damaged one is refused before
    any group of it is reset."""
    if backend is None:
        return None, 0
    be = ChainFile(str(backend), name=name)
    if be.initialized and be.iteration > 0:
        if be.shape != (W, ndim):
            raise BayesmotionError(f"backend {backend} holds a run of shape {be.shape} in its "
                                   f"group {name!r}, this run needs {(W, ndim)}; use another "
                                   f"file (a file of the joint sampler resumes with "
                                   f"factorise=False)")
        _check_resumed_density(be, log_prob, backend)
        return be, be.iteration
    be.reset(W, ndim)
    return be, 0


def _initial_state(start, seed):
    import emcee

    # seeded: emcee keeps its generator state in the State (and the backend)
    return emcee.State(start, random_state=np.random.RandomState(seed).get_state())


class Pace:
    """The run's pace, measured on its first steps, and the whole run's time estimated from it.

    The first step of a call is not timed (it compiles the vectorised density); the pace is the
    mean over the next steps until ``after_seconds`` have passed or ``after_steps`` steps are
    timed, whichever comes first. The estimate (``info``) is said once, on stderr, when
    ``say`` is set (the progress bars are on), and kept in ``Posterior.info["pace"]`` beside
    the run's measured ``seconds``.
    """

    def __init__(self, n_steps: int, say: bool, after_seconds: float = 10.0,
                 after_steps: int = 20):
        self.left, self.say = n_steps, say
        self.after_seconds, self.after_steps = after_seconds, after_steps
        self.t0, self.timed, self.info = None, 0, None

    def step(self) -> None:
        """Called after each step."""
        self.left -= 1
        if self.info is not None:
            return
        now = time.perf_counter()
        if self.t0 is None:
            self.t0 = now
            return
        self.timed += 1
        spent = now - self.t0
        if spent >= self.after_seconds or self.timed >= self.after_steps or self.left == 0:
            per = spent / self.timed
            self.info = {"seconds_per_step": per, "timed_steps": self.timed,
                         "estimated_seconds_left": per * self.left}
            if self.say and self.left:
                from tqdm.auto import tqdm

                tqdm.write(f"emcee: {per:.3g} s per step over {self.timed} steps; the "
                           f"{self.left} steps left take about "
                           f"{format_seconds(per * self.left)}", file=sys.stderr)


PHASE_LABELS = {True: "emcee, adapting ({W} walkers)", False: "emcee, sampling ({W} walkers)",
                None: "emcee ({W} walkers)"}
"""Progress-bar label of each phase (the independence proposal's adaptation, then sampling)."""


def _label(which, W: int, n_adapt: int) -> str:
    """The progress bar's label of a phase (``which``: True, None, or the window of steps a
    sampling phase's proposal is fitted to)."""
    if not isinstance(which, tuple):
        return PHASE_LABELS[which].format(W=W)
    if which[1] == n_adapt:
        return PHASE_LABELS[False].format(W=W)
    return f"emcee, sampling ({W} walkers, proposal refitted at step {which[1]})"


def run_emcee(target, centre, n_walkers, n_steps, burn, thin, seed, backend, progress, init,
               ball, moves, hmc=False, independence=False):
    """One ensemble over every sampled coordinate. With ``independence``, in phases: the
    adaptation (its independence proposal is the Laplace approximation), then sampling with the
    proposal fitted to the adaptation's last two thirds, refitted at each of
    :func:`bayesmotion.inference.proposals.refit_steps` to every state since the adaptation;
    each phase is a fixed kernel. A resumed file continues in the phase where it stopped, with
    the adaptation length and refit steps stored in it, its proposals recomputed from it."""
    import emcee

    W = _n_walkers(n_walkers, target.ndim)

    def log_prob(xs):
        return in_halves(target.logp_batch, xs, W)

    if backend is not None:
        check_chain_file(backend)
    be, done = _open_backend(backend, "mcmc", W, target.ndim, log_prob)
    be = emcee.backends.Backend() if be is None else be  # shared by the phases
    cov, n_adapt, refits = None, 0, []
    if backend is not None:
        n_adapt = _adapt_record(backend, done, adapt_steps(n_steps) if independence else None)
        refits = _refit_record(backend, done, n_adapt,
                               refit_steps(n_adapt) if independence else None)
    elif independence:
        n_adapt = adapt_steps(n_steps)
        refits = refit_steps(n_adapt)
    modes = None
    if independence:
        cov = target.laplace(centre)
        block = independence_block(target, cov)
        # the proposal lives where DE proposes: in the shear's coordinates, where there is one
        shear = StyleShear.for_target(target)
        modes = idle_factor_modes(target, centre, cov, block)  # info reports them as found
        proposal_modes = sheared_modes(modes, shear)
        canonical = canonical_styles(target)

        def phase_moves(which):
            if which is True:
                return default_moves(target, hmc, mixture_proposal(block, proposal_modes))
            lo, hi = which  # the steps the proposal is fitted to
            z = be.get_chain()[lo:hi].reshape(-1, target.ndim)
            if CANONICAL_INDEPENDENCE and canonical.blocks:
                proposal = canonical_mixture(canonical, block, modes, z)
                return default_moves(target, hmc, proposal, canonical_proposal=canonical)
            if shear is not None:
                z = in_halves(shear.forward, z, W)
            return default_moves(target, hmc, mixture_proposal(block, proposal_modes,
                                                               z[:, block]))

        # (a resumed file's stored adaptation may be longer than this call's n_steps)
        windows = [(n_adapt // 3, n_adapt)] + [(n_adapt, r) for r in refits]
        ends = [min(e, n_steps) for e in [*refits, n_steps]]
        phases = ([(min(n_adapt, n_steps), True), *zip(ends, windows, strict=True)] if n_adapt
                  else [(n_steps, True)])
    else:
        phases = [(n_steps, None)]

        def phase_moves(_):
            return default_moves(target, hmc) if moves is None else moves

    pace = Pace(max(0, n_steps - done), progress)
    t0 = time.perf_counter()
    ran = []  # (moves, steps) of each phase run by this call
    with committing(be):  # a stopped run keeps its steps
        for end, which in phases:
            if done >= end:
                continue
            used = phase_moves(which)
            ran.append((used, end - done))
            sampler = emcee.EnsembleSampler(W, target.ndim, log_prob, vectorize=True,
                                            backend=be, moves=used)
            label = {"desc": _label(which, W, n_adapt)}
            if done:
                state = sampler._previous_state
            else:
                start = start_points(target, centre, W, init, ball,
                                      np.random.default_rng(seed), cov)
                state = _initial_state(start, seed)
            for _ in sampler.sample(state, iterations=end - done, progress=progress,
                                    progress_kwargs=label):
                pace.step()
            done = end
    seconds = time.perf_counter() - t0
    info = {"seconds": seconds, "pace": pace.info, "factorised": False, **phase_stats(ran)}
    if independence:
        info["adapt_steps"] = n_adapt
        info["refit_steps"] = [r for r in refits if r < done]  # those the chain got past
        names = getattr(target, "names", None)  # a bare target has indices only
        info["independence_block"] = ([names[i] for i in block] if names is not None
                                      else block.tolist())
        if CANONICAL_INDEPENDENCE and canonical.blocks and n_adapt and done > n_adapt:
            # the block after the adaptation (where the chain has got there)
            slots = dict(zip(canonical.slots().tolist(), canonical.slot_names(), strict=True))
            info["independence_block_sampling"] = [
                slots.get(i, names[i] if names is not None else i)
                for i in canonical_block(canonical, block).tolist()]
        info["modes"] = [{"weight": m["weight"], "logp": m["logp"],
                          "log_evidence": m["log_evidence"], "searched_from": m["searched_from"],
                          "x": m["x"].tolist()} for m in modes]
    return posterior_from_chain(target, be.get_chain(), be.get_log_prob(),
                                be.accepted / max(be.iteration, 1), burn, thin, info,
                                min_burn=n_adapt)


def _adapt_record(backend, done: int, n_adapt: int | None) -> int:
    """The adaptation length a backend file's run uses, stored with its chain (so a run resumed
    with another ``n_steps`` switches proposals where the first did); ``None``: this run uses no
    independence move. A resumed file must have been written with the same choice."""
    with open_h5(backend, "r") as f, h5_errors(backend):
        attrs = f["mcmc"].attrs
        stored = int(attrs[ADAPT_ATTR]) if ADAPT_ATTR in attrs else None
    if done and (stored is None) != (n_adapt is None):
        flag = "False (CLI: --no-independence)" if stored is None else "True (the default)"
        raise BayesmotionError(
            f"backend {backend} was written {'without' if stored is None else 'with'} the "
            f"independence move (files written before it existed have none); resume it with "
            f"independence={flag}")
    if n_adapt is None:
        return 0
    if done:
        return stored
    with h5_errors(backend, "write"), write_h5(backend) as f:
        f["mcmc"].attrs[ADAPT_ATTR] = n_adapt
    return n_adapt


def _refit_record(backend, done: int, n_adapt: int, refits: list[int] | None) -> list[int]:
    """The refit steps a backend file's run uses, stored with its chain as its adaptation
    length is (:func:`_adapt_record`); a file written before refits existed has none. Stored
    steps must come after the stored adaptation."""
    if refits is None:
        return []
    with open_h5(backend, "r") as f, h5_errors(backend):
        attrs = f["mcmc"].attrs
        if done:
            stored = refit_attr(attrs, str(backend)) if REFIT_ATTR in attrs else []
            if stored and stored[0] <= n_adapt:
                raise BayesmotionError(
                    f"backend {backend}: its refit steps {stored} do not all come after its "
                    f"{n_adapt}-step adaptation; the file was not written by this package: use "
                    f"another file")
            return stored
    with h5_errors(backend, "write"), write_h5(backend) as f:
        f["mcmc"].attrs[REFIT_ATTR] = np.asarray(refits, dtype=np.int64)
    return refits


def planned_adapt(backend, n_steps: int) -> int:
    """The adaptation length a run will use: a resumed file's, else this run's."""
    if backend is not None and os.path.exists(str(backend)):
        # waits for another process writing the file itself; names a foreign or damaged file
        with open_h5(backend, "r") as f, h5_errors(backend):
            attrs = f["mcmc"].attrs if "mcmc" in f else {}
            if ADAPT_ATTR in attrs and int(attrs.get("iteration", 0)) > 0:
                return int(attrs[ADAPT_ATTR])
    return adapt_steps(n_steps)


def run_factorised(target, centre, n_walkers, n_steps, burn, thin, seed, backend, progress,
                    init, ball, moves, gamma_every, hmc=False):
    """Two independent ensembles, one per factor of p(gamma | Y, X) p(beta, alpha, S | X, I).

    The upper ensemble (beta, alpha, styles) takes ``n_steps`` steps and never evaluates the
    bottom layer; the bottom ensemble (gamma, 3 coordinates) takes one step for every
    ``gamma_every`` of them. Output step t pairs upper step t with bottom step
    ``t // gamma_every``, walker by walker. As the factors are independent, this is the chain
    of a valid composite kernel on the joint posterior (the gamma update is applied every
    ``gamma_every`` steps): its draws, autocorrelation times and diagnostics are those of the
    joint chain, with gamma's held values counted as the repeats they are.
    """
    import emcee

    model = target.model
    up = Target(model, target.jitter, "upper")
    bot = Target(model, target.jitter, "bottom")
    iu = np.array([target.names.index(n) for n in up.names])
    ib = np.array([target.names.index(n) for n in bot.names])
    # as many walkers as the joint sampler by default (the demo-size runs used 48 and 54)
    W = _n_walkers(n_walkers or 2 * target.ndim + 2, up.ndim)

    def lp_up(xs):
        return in_halves(up.logp_batch, xs, W)

    def lp_bot(xs):
        return in_halves(bot.logp_batch, xs, W)

    if backend is not None:  # both groups, before either is reset
        check_chain_file(backend)
    be_up, done_up = _open_backend(backend, "mcmc", W, up.ndim, lp_up)
    be_bot, done_bot = _open_backend(backend, "gamma", W, bot.ndim, lp_bot)
    n_steps = max(n_steps, done_up)  # a file holding more steps returns them all (as joint)
    n_bot = -(-n_steps // gamma_every)
    moves_up = default_moves(up, hmc) if moves is None else moves
    moves_bot = default_moves(bot, hmc=False)  # DE: gamma has no style coordinates
    s_up = emcee.EnsembleSampler(W, up.ndim, lp_up, vectorize=True, backend=be_up,
                                 moves=moves_up)
    s_bot = emcee.EnsembleSampler(W, bot.ndim, lp_bot, vectorize=True, backend=be_bot,
                                  moves=moves_bot)
    start = None
    if not (done_up and done_bot):
        start = start_points(target, centre, W, init, ball, np.random.default_rng(seed))
    init_up = s_up._previous_state if done_up else _initial_state(start[:, iu], seed)
    init_bot = s_bot._previous_state if done_bot else _initial_state(start[:, ib], seed + 1)
    pace = Pace(max(0, n_steps - done_up), progress)
    t0 = time.perf_counter()
    gen_up = s_up.sample(init_up, iterations=max(0, n_steps - done_up), progress=progress,
                         progress_kwargs={"desc": f"emcee, factorised ({W} walkers)"})
    gen_bot = s_bot.sample(init_bot, iterations=max(0, n_bot - done_bot))
    with committing(be_up, be_bot):  # a stopped run keeps its steps
        for t in range(done_up, n_steps):  # interleaved: a killed run resumes either group
            next(gen_up)
            while done_bot < min(n_bot, t // gamma_every + 1):
                next(gen_bot)
                done_bot += 1
            pace.step()
        for _ in gen_bot:  # the bottom steps still missing when the upper chain was complete
            pass
        for _ in gen_up:  # close the generators (each saves a step before it yields it)
            pass
    seconds = time.perf_counter() - t0
    c_up, c_bot = s_up.get_chain()[:n_steps], s_bot.get_chain()[:n_bot]
    l_up, l_bot = s_up.get_log_prob()[:n_steps], s_bot.get_log_prob()[:n_bot]
    held = np.arange(n_steps) // gamma_every
    chain = np.empty((n_steps, W, target.ndim))
    chain[..., iu], chain[..., ib] = c_up, c_bot[held]
    info = {"seconds": seconds, "pace": pace.info, "factorised": True, "gamma_every": gamma_every,
            "bottom_acceptance": np.asarray(s_bot.acceptance_fraction), **move_stats(moves_up)}
    return posterior_from_chain(target, chain, l_up + l_bot[held], s_up.acceptance_fraction,
                                burn, thin, info)


def _check_resumed_density(be, log_prob, backend) -> None:
    """A resumed run continues from the log-densities stored with its last step; they must be
    this posterior's. Recomputed at the stored walkers, they differ (by hundreds of nats) when
    the file was written for another model, e.g. a refit of the same size; the style rotations
    carry the stored values forward by increments, hence the small tolerance."""
    last = be.get_last_sample()
    fresh = log_prob(np.asarray(last.coords))
    stored = np.asarray(last.log_prob, dtype=np.float64)
    if not np.allclose(fresh, stored, rtol=1e-7, atol=1e-6, equal_nan=True):
        worst = float(np.nanmax(np.abs(fresh - stored)))
        raise BayesmotionError(f"backend {backend} holds a run of another posterior: its stored "
                               f"log-densities differ from this model's by up to {worst:.3g} "
                               f"nats at the same walkers; use another file")
