from __future__ import annotations

from bayesmotion import validate
from bayesmotion._config import release_compiled_programs
from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.chainfile import check_chain_file
from bayesmotion.inference.emcee_runner import planned_adapt, run_emcee, run_factorised
from bayesmotion.inference.nuts import run_nuts
from bayesmotion.inference.posterior import Posterior
from bayesmotion.inference.target import Target


# --------------------------------------------------------------------------- samplers
def sample_posterior(fitted, n_walkers: int | None = None, n_steps: int = 2000,
                     burn: int | None = None, thin: int | None = None, seed: int = 0,
                     backend=None, progress: bool = True, method: str = "emcee",
                     n_chains: int = 2, init: str = "laplace", ball: float = 1e-3,
                     moves=None, factorise: bool = False, gamma_every: int = 4,
                     hmc: bool = False, independence: bool | None = None,
                     fix_styles: bool = False, check_memory: bool = True) -> Posterior:
    """Sample the posterior over hyperparameters and training style vectors.

    Args:
        fitted: a FittedHGPDM.
        n_walkers: emcee walkers (default ``2 * ndim + 2``, even, ndim counting every
            sampled coordinate). When ``factorise``, both ensembles have this many walkers.
        n_steps: emcee steps per walker (NUTS: samples per chain after as many warm-up steps).
        burn: discarded leading steps; by default chosen from the integrated autocorrelation
            time tau (burn = 2 max tau). NUTS: the number of warm-up (adaptation) steps,
            default ``n_steps``; 0 means no step-size or mass-matrix adaptation.
        thin: thinning; by default max(1, min tau / 2).
        seed: seeds the walker ball, the moves and NUTS.
        backend: path of an emcee HDF5 file. An existing file with the same dimensions is resumed
            from its last step until it holds ``n_steps`` steps (nothing already saved is lost).
            The file is never half-written: each save replaces it with a complete copy, so a run
            killed at any moment resumes from its last save; other processes may read it
            meanwhile (:mod:`bayesmotion.inference.chainfile`).
        progress: progress bars.
        method: "emcee" or "nuts".
        n_chains: NUTS chains.
        init: where the walkers (NUTS: chains) start. ``"laplace"`` (default) draws them from
            the Laplace approximation at the conditional MAP (inverse Hessian), so the ensemble
            starts about as wide as the posterior: differential-evolution moves scale with the
            ensemble's spread, so a tight ball first spends many steps expanding (burn-in).
            ``"ball"``: a Gaussian ball of radius ``ball`` (unconstrained units).
        moves: emcee moves (default: ``emcee.moves.DEMove()``, mixing faster than the stretch
            move in tens of dimensions, each step followed by exact Metropolis steps along the
            style vectors' rotation orbits, where the likelihood is constant:
            :class:`bayesmotion.inference.moves.StyleRotations`; then the independence step, see
            ``independence``). When ``factorise``, the moves of the
            (beta, alpha, styles) ensemble, whose coordinates are the target's without gamma's
            (``Target(fitted, block="upper")``); gamma's ensemble always uses DE.
        factorise: with the latents fixed the posterior factorises, p(gamma | Y, X)
            p(beta, alpha, S | X, I): gamma enters only the bottom layer, the most expensive
            one. ``True`` samples the factors with two independent ensembles, so the
            slow-mixing one (beta, alpha, styles) never evaluates the bottom layer, and updates
            gamma once every ``gamma_every`` steps; output step t pairs the two chains' walkers
            at steps t and t // gamma_every. ``False`` (default): one ensemble over every
            coordinate. Both samplers' cost and effective samples per second are measured side
            by side in ``benchmarks/results/sampler_ess.json``.
        gamma_every: steps of the upper chain per step of the gamma chain.
        hmc: add, after the default moves, two ensemble-preconditioned HMC steps
            (:class:`bayesmotion.inference.moves.EnsembleHMC`): one on the coordinates the style
            rotations do not move (the hyperparameters and two-level style vectors: nearly
            Gaussian but strongly correlated, where DE crawls), one on the rotated style
            vectors (heavy-tailed: smaller steps).
            A step costs about 13x an evaluation of every walker at the built-in size (about 4
            gradients per walker and block; ``benchmarks/results/sampler_ess.json``, key
            ``eval_costs.builtin``). Off by default: no long run has shown it to mix faster
            per second than the default moves.
        independence: add, after DE and the rotations, an independence Metropolis step
            (:class:`bayesmotion.inference.moves.IndependenceMove`) on the coordinates the
            rotations do not
            move, plus the rotated ones the likelihood pins (Laplace sd < 0.2): a multivariate t (20
            degrees of freedom) proposal from the Laplace approximation at the conditional MAP for
            the first min(150, n_steps // 4) steps, then a t after a sinh-arcsinh map of each
            coordinate (:class:`bayesmotion.inference.moves.SinhArcsinh`) fitted to that
            adaptation's last two thirds and refitted at steps 250, 500 and 1,000 to every state
            since it (every walker pooled). Each phase is a fixed kernel; the adaptation is part
            of the burn-in (``burn`` must cover it, as NUTS's warm-up), and a file resumed with
            ``backend`` switches where its first run did. One more log-density per
            walker and step: two per walker with DE's. ``None`` (default):
            on for the joint emcee sampler with the default moves, off otherwise; ``True`` with
            ``method="nuts"``, user ``moves`` or ``factorise`` raises. Its measured effect at the
            demo
            size is in ``benchmarks/results/posterior_convergence.json``. Where a
            two-level style factor has a second local mode (its vectors near the simplex's
            centre, the factor idle; :func:`idle_factor_modes` searches for one per factor, at
            the cost of one more conditional MAP and Laplace approximation), the proposal is a
            mixture with one t per mode (weights from their Laplace evidence, each at least
            0.05; after the adaptation each mode's moments come from the fitted states nearest
            it), so a walker jumps between the modes in one accepted step.
        fix_styles: hold the training style vectors at the model's values and sample the
            hyperparameters alone, p(gamma, beta, alpha, a | S, X, I): a conditional of the
            posterior, not the posterior. The style vectors carry its slow directions (their
            rotation orbits, the trade-off of their norms with the output scales); without them
            the independence step makes nearly independent draws (at the demo size the
            autocorrelation time falls from hundreds of steps to about 2). The posterior's
            spread of the styles is then missing from every answer drawn from it. Not with
            ``factorise``. CLI ``--fix-styles``.
        check_memory: refuse a run whose estimated memory
            (:func:`bayesmotion.validate.sample_memory`: the chain plus the log-posterior's
            kernel matrices) exceeds the memory available; ``False`` skips the check.

    Every argument is checked before any work (numbers, and a ``backend`` file's layout and
    stored values: :func:`bayesmotion.inference.chainfile.check_chain_file`), so a bad one
    fails in milliseconds with a BayesmotionError, and a damaged chain file is left untouched.

    Returns:
        a Posterior. A ``ChainTooShortWarning`` is issued when the chain is shorter than 50
        autocorrelation times.
    """
    if method not in ("emcee", "nuts"):
        raise BayesmotionError(f"method must be 'emcee' or 'nuts', got {method!r}")
    _check_numbers(n_walkers, n_steps, burn, thin, seed, n_chains, ball, gamma_every)
    release_compiled_programs()  # each model compiles its density anew: keep the maps bounded
    held = {} if backend is None else check_chain_file(backend)
    if burn is not None and (burn < 0 or (method == "emcee" and burn >= n_steps)):
        # emcee discards burn of its n_steps; NUTS warms up for burn steps before n_steps draws
        raise BayesmotionError(f"burn must be in [0, n_steps = {n_steps}) for emcee and >= 0 "
                               f"for NUTS, got {burn}")
    if hmc and method != "emcee":
        raise BayesmotionError(f"hmc=True adds HMC steps to emcee's moves; method={method!r} "
                               f"does not use them (NUTS is already Hamiltonian)")
    if hmc and moves is not None:
        raise BayesmotionError("hmc=True adds EnsembleHMC to the default moves; with your own "
                               "moves, add bayesmotion.inference.moves.EnsembleHMC to them instead")
    if independence and (method != "emcee" or moves is not None or factorise):
        raise BayesmotionError("independence=True adds steps to the joint emcee sampler's "
                               "default moves; it does not apply with method='nuts', your own "
                               "moves or factorise=True (add "
                               "bayesmotion.inference.moves.IndependenceMove "
                               "to your moves instead)")
    if fix_styles and factorise:
        raise BayesmotionError("fix_styles=True samples the hyperparameters with the style "
                               "vectors held; factorise=True splits the full posterior's "
                               "coordinates: choose one")
    if independence is None:
        independence = method == "emcee" and moves is None and not factorise
    if independence and method == "emcee":
        n_adapt = planned_adapt(backend, n_steps)
        if n_steps <= n_adapt:
            stored = (f"the run stored in {backend}" if held.get("mcmc", 0) > 0
                      else "the independence move")
            raise BayesmotionError(f"n_steps ({n_steps}) must exceed the {n_adapt} adaptation "
                                   f"steps of {stored}; ask for more steps, or pass "
                                   f"independence=False (CLI: --no-independence)")
        if burn is not None and burn < n_adapt:
            raise BayesmotionError(f"burn ({burn}) must cover the independence move's {n_adapt} "
                                   f"adaptation steps (as NUTS's warm-up); pass burn >= "
                                   f"{n_adapt}, or independence=False")
    target = Target(fitted, block="hyper" if fix_styles else None)
    if check_memory:
        _check_sample_memory(target, method, n_walkers, n_chains, n_steps, burn)
    centre, cdiag = target.conditional_map(progress=False)
    if method == "emcee" and factorise:
        post = run_factorised(target, centre, n_walkers, n_steps, burn, thin, seed, backend,
                               progress, init, ball, moves, int(gamma_every), hmc)
    elif method == "emcee":
        post = run_emcee(target, centre, n_walkers, n_steps, burn, thin, seed, backend,
                          progress, init, ball, moves, hmc, independence)
    else:
        post = run_nuts(target, centre, n_steps, burn, thin, seed, progress, n_chains, init,
                         ball)
    post.info["conditional_map"] = {k: cdiag[k] for k in ("objective", "iterations", "converged")}
    return post


def _check_numbers(n_walkers, n_steps, burn, thin, seed, n_chains, ball, gamma_every) -> None:
    """Types and ranges of :func:`sample_posterior`'s numbers (before any work)."""
    if n_walkers is not None:
        validate.integer(n_walkers, "n_walkers", low=1)
    validate.integer(n_steps, "n_steps", low=1)
    if burn is not None:
        validate.integer(burn, "burn", low=0)
    if thin is not None:
        validate.integer(thin, "thin", low=1)
    validate.seed(seed)
    validate.integer(n_chains, "n_chains", low=1)
    validate.real(ball, "ball", above=0.0)
    validate.integer(gamma_every, "gamma_every", low=1)


def _check_sample_memory(target, method, n_walkers, n_chains, n_steps, burn) -> None:
    """Refuse a run whose :func:`bayesmotion.validate.sample_memory` exceeds the memory
    available (NUTS: its chains as walkers, warm-up steps counted)."""
    model, ndim = target.model, target.ndim
    if method == "nuts":
        walkers, steps = n_chains, n_steps + (n_steps if burn is None else burn)
    else:
        walkers, steps = (n_walkers or 2 * ndim + 2), n_steps
    need = validate.sample_memory(walkers, steps, ndim, len(model.data.trial_of_frame),
                                  model.n_actors + 2, model.spec.inducing)
    validate.check_memory(need, f"sampling {steps} steps of {walkers} walkers over {ndim} "
                                f"coordinates")
