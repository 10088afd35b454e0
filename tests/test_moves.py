"""The style-rotation move: the likelihood is constant along its orbits, it leaves an exact
Dirichlet target invariant, and its log-density bookkeeping matches fresh evaluations."""

import warnings

import emcee
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

import bayesmotion as bm
from bayesmotion.inference.emcee_runner import run_emcee
from bayesmotion.inference.moves import (
    EnsembleHMC,
    IndependenceMove,
    Sequence,
    StyleRotations,
    plane_rotations,
    style_slices,
)
from bayesmotion.inference.posterior import ChainTooShortWarning
from bayesmotion.inference.proposals import default_moves, idle_factor_modes, independence_block
from bayesmotion.inference.sample import sample_posterior
from bayesmotion.inference.target import Target
from bayesmotion.model.params import simplex_to_style, style_log_jacobian, style_to_simplex


@pytest.fixture(scope="module")
def three_emotion_model():
    """Couple c1's happy, sad and angry handshakes at 5 fps (9 trials), free style vectors."""
    ds = bm.load_handshakes(fps=5.0).filter(couple="c1", emotion=["happy", "sad", "angry"])
    ds = bm.MotionDataset(ds.trials, {"emotion": ("happy", "sad", "angry"), "couple": ("c1",)})
    return bm.HGPDM(latent_dim=3, interaction_dim=3).fit(ds, max_iter=20, progress=False)


def _random_rotation(K, rng, scale=0.3):
    return plane_rotations(scale * rng.standard_normal((K - 1, K - 1)))


def test_plane_rotations_are_orthogonal_and_keep_rows_on_the_simplex_plane():
    rng = np.random.default_rng(0)
    Q = _random_rotation(4, rng)
    np.testing.assert_allclose(Q @ Q.T, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(Q @ np.ones(4), np.ones(4), atol=1e-14)
    assert np.linalg.det(Q) == pytest.approx(1.0)


def test_likelihood_is_constant_along_style_rotations(three_emotion_model):
    model = three_emotion_model
    target = Target(model)
    lp = model.log_posterior_fn
    idx = style_slices(target.unravel, target.x0)["emotion"]
    x = target.x0.copy()
    S = np.asarray(style_to_simplex(jnp.asarray(x[idx].reshape(3, 2))))
    S2 = S @ _random_rotation(3, np.random.default_rng(1), scale=0.2)
    assert np.all(S2 > 0) and np.abs(S2 - S).max() > 0.01
    x2 = x.copy()
    x2[idx] = np.asarray(simplex_to_style(jnp.asarray(S2))).ravel()
    terms = [lp.layer_terms(target.full(v), target.jitter) for v in (x, x2)]
    for layer in ("bottom", "interaction", "dynamics"):
        np.testing.assert_allclose(float(terms[1][layer]), float(terms[0][layer]), rtol=1e-10)
    assert abs(float(terms[1]["prior"]) - float(terms[0]["prior"])) > 1e-3  # the prior moves


class _Stay(emcee.moves.Move):
    def propose(self, model, state):
        return state, np.zeros(len(state.coords), dtype=bool)


class _Model:
    def __init__(self, seed):
        self.random = np.random.RandomState(seed)


def _dirichlet_logp_u(u, conc):
    """Target density in unconstrained space: Dirichlet rows + stick-breaking Jacobian."""
    S = np.asarray(style_to_simplex(jnp.asarray(u)))
    return (np.sum((conc - 1) * np.log(S)) + float(style_log_jacobian(jnp.asarray(u))))


def test_style_rotations_leave_an_exact_dirichlet_target_invariant():
    # walkers start as exact iid draws of the target; an invariant kernel keeps them so
    K, n = 4, 3000
    conc = 1.0 + 4.0 * np.eye(K)
    rng = np.random.default_rng(0)
    S0 = np.stack([rng.dirichlet(conc[k], size=n) for k in range(K)], axis=1)  # (n, K, K)
    u0 = np.asarray(simplex_to_style(jnp.asarray(S0))).reshape(n, -1)
    lp0 = np.array([_dirichlet_logp_u(u.reshape(K, K - 1), conc) for u in u0])
    move = StyleRotations(_Stay(), {"e": np.arange(K * (K - 1))}, {"e": conc},
                          n_rotations=200, scale=0.3)
    state, _ = move.propose(_Model(1), emcee.State(u0, log_prob=lp0))
    assert 0.05 < move.acceptance < 0.9
    S = np.asarray(style_to_simplex(jnp.asarray(state.coords.reshape(n, K, K - 1))))
    assert np.mean(np.abs(S - S0)) > 0.02  # the walkers did move along their orbits
    # the Gram matrices, which the likelihood sees, did not change
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", S, S),
                               np.einsum("nij,nkj->nik", S0, S0), atol=1e-12)
    # still Dirichlet. The sharpest check is the prior log-density itself: a kernel that
    # accepts by the wrong ratio drifts it (accepting every rotation inside the simplex gives
    # z = -18 here; the right ratio z ~ 0)
    kern = lambda S: np.sum((conc - 1) * np.log(S), axis=(1, 2))  # noqa: E731
    shift = kern(S) - kern(S0)
    assert abs(shift.mean()) < 4.5 * kern(S0).std() * np.sqrt(2 / n)
    a0 = conc.sum(1, keepdims=True)
    mean = conc / a0
    assert np.all(np.abs(S.mean(0) - mean) < 4.5 * np.sqrt(mean * (1 - mean) / (a0 + 1) / n))
    # bookkeeping: the updated log-density equals a fresh evaluation
    fresh = np.array([_dirichlet_logp_u(u.reshape(K, K - 1), conc) for u in state.coords[:50]])
    np.testing.assert_allclose(state.log_prob[:50], fresh, rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_sample_posterior_rotates_style_vectors_and_keeps_log_density_exact(three_emotion_model):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = sample_posterior(three_emotion_model, n_steps=40, burn=10, thin=1, seed=0,
                                progress=False)
    assert 0.05 < post.info["rotation_acceptance"] < 0.95
    assert 0 <= post.info["reflection_acceptance"] < 1  # reported beside the rotations'
    # the default independence step ran, after its 10 adaptation steps, on every coordinate the
    # rotations do not move
    assert post.info["adapt_steps"] == 10 and 0.02 < post.info["independence_acceptance"] < 1
    # the block: every coordinate the rotations leave alone, and a rotated one only when its
    # Laplace sd is under 0.2 (pinned by the likelihood)
    ndim = post.target.ndim
    rotated = sorted({int(i) for idx, _ in default_moves(post.target).blocks for i in idx})
    free = [i for i in range(ndim) if i not in rotated]
    cov = np.eye(ndim)
    cov[rotated[4], rotated[4]] = 0.05 ** 2
    assert independence_block(post.target, cov).tolist() == sorted(free + [rotated[4]])
    assert independence_block(post.target, np.eye(ndim)).tolist() == free
    # the run says which coordinates its independence step drew
    assert {post.target.names[i] for i in free} <= set(post.info["independence_block"])
    x = post.chains[:3, -1]
    fresh = np.asarray(post.target.logp_batch(jnp.asarray(x)))
    np.testing.assert_allclose(post.log_prob[:3, -1], fresh, rtol=1e-9)


# ----------------------------------------------------------------------- ensemble HMC
_COV = np.array([[1.0, 0.95, 0.2], [0.95, 1.0, 0.0], [0.2, 0.0, 1.0]]) * np.array(
    [3.0, 0.1, 1.0])[:, None] * np.array([3.0, 0.1, 1.0])[None, :]
_MEAN = np.array([1.0, -2.0, 0.5])
_PREC = np.linalg.inv(_COV)


def _gauss_logp(x):
    """A correlated, badly scaled Gaussian in coordinates 0-2 times a logistic coordinate 3,
    which the HMC block leaves alone."""
    d = x[:3] - _MEAN
    return -0.5 * d @ jnp.asarray(_PREC) @ d - 2.0 * jnp.logaddexp(0.0, x[3]) + x[3]


def test_ensemble_hmc_keeps_an_exact_target_and_touches_only_its_block():
    # walkers start as exact iid draws of the target; an invariant kernel keeps them so, and
    # leaves coordinate 3 (outside the block) unchanged
    rng = np.random.default_rng(0)
    n = 2000
    x0 = np.c_[rng.multivariate_normal(_MEAN, _COV, n), rng.logistic(size=n)]
    move = EnsembleHMC(_gauss_logp, [0, 1, 2], step_size=0.8)
    lp0 = np.asarray(jax.vmap(_gauss_logp)(jnp.asarray(x0)))
    state = emcee.State(x0, log_prob=lp0)
    model = _Model(1)
    for _ in range(5):
        state, acc = move.propose(model, state)
    assert 0.5 < move.acceptance < 1.0 and acc.mean() > 0.4
    x = state.coords
    np.testing.assert_array_equal(x[:, 3], x0[:, 3])
    assert np.mean(x[:, 0] != x0[:, 0]) > 0.5
    # decorrelated from the start: HMC moves a walker across its distribution, not by a jitter
    assert abs(np.corrcoef(x[:, 0], x0[:, 0])[0, 1]) < 0.6
    se = np.sqrt(np.diag(_COV) / n)
    assert np.all(np.abs(x[:, :3].mean(0) - _MEAN) < 4.5 * se)
    np.testing.assert_allclose(np.cov(x[:, :3].T), _COV, rtol=0.15, atol=0.02 * np.abs(_COV).max())
    # bookkeeping: the stored log-density is a fresh evaluation's
    np.testing.assert_allclose(state.log_prob, np.asarray(jax.vmap(_gauss_logp)(
        jnp.asarray(x))), rtol=1e-12, atol=1e-9)


def _check_block_mixes_from_a_bad_start(block_move, discard, max_tau, sd_rtol):
    """emcee with DE then ``block_move`` on coordinates 0-2, 24 walkers started 5 units off:
    the block's tau stays under ``max_tau`` and its moments match the target's."""
    rng = np.random.default_rng(3)
    W = 24
    start = np.c_[_MEAN + 5.0 + 1e-3 * rng.standard_normal((W, 3)), rng.logistic(size=W)]
    lp = jax.jit(jax.vmap(_gauss_logp))
    sampler = emcee.EnsembleSampler(W, 4, lambda xs: np.asarray(lp(jnp.asarray(xs))),
                                    vectorize=True,
                                    moves=Sequence(emcee.moves.DEMove(), block_move))
    sampler.run_mcmc(emcee.State(start, random_state=np.random.RandomState(0).get_state()),
                     1500, progress=False)
    chain = sampler.get_chain(discard=discard)
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    assert np.all(tau[:3] < max_tau)  # the block mixes in a few steps despite the correlations
    flat = chain.reshape(-1, 4)
    mcse = np.sqrt(np.diag(_COV) * tau[:3] / len(flat))
    assert np.all(np.abs(flat[:, :3].mean(0) - _MEAN) < 4.0 * mcse)
    np.testing.assert_allclose(flat[:, :3].std(0), np.sqrt(np.diag(_COV)), rtol=sd_rtol)


def test_ensemble_hmc_in_emcee_recovers_moments_from_a_bad_start():
    _check_block_mixes_from_a_bad_start(EnsembleHMC(_gauss_logp, [0, 1, 2]), 300, 5, 0.1)


def _walled(x):
    return jnp.where(x[0] < 1.5, _gauss_logp(x), -jnp.inf)


def _walled_state() -> emcee.State:
    """200 exact draws of the target cut at x0 = 1.5 (the density is -inf beyond)."""
    rng = np.random.default_rng(0)
    x0 = np.c_[rng.multivariate_normal(_MEAN, _COV, 400), rng.logistic(size=400)]
    x0 = x0[x0[:, 0] < 1.5][:200]
    return emcee.State(x0, log_prob=np.asarray(jax.vmap(_walled)(jnp.asarray(x0))))


def test_ensemble_hmc_rejects_trajectories_into_non_finite_regions():
    move = EnsembleHMC(_walled, [0, 1, 2], step_size=1.0, n_leapfrog=(3, 5))
    state = _walled_state()
    for _ in range(3):
        state, _ = move.propose(_Model(2), state)
    assert np.all(state.coords[:, 0] < 1.5) and np.all(np.isfinite(state.log_prob))
    assert move.acceptance > 0.2


def test_ensemble_hmc_validates_its_arguments():
    with pytest.raises(ValueError, match="non-empty block"):
        EnsembleHMC(_gauss_logp, [])
    with pytest.raises(ValueError, match="n_leapfrog"):
        EnsembleHMC(_gauss_logp, [0], n_leapfrog=(3, 2))
    with pytest.raises(ValueError, match="step_size"):
        EnsembleHMC(_gauss_logp, [0], jitter=(0.0, 1.0))
    with pytest.raises(ValueError, match="shrinkage"):
        EnsembleHMC(_gauss_logp, [0], shrinkage=2.0)
    with pytest.raises(ValueError, match="at least one move"):
        Sequence()


@pytest.mark.slow
def test_sample_posterior_with_hmc_blocks_keeps_log_density_exact(three_emotion_model):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = sample_posterior(three_emotion_model, n_steps=20, burn=5, thin=1, seed=0,
                                progress=False, hmc=True)
    acc = post.info["hmc_block_acceptance"]
    assert len(acc) == 2 and all(0.05 < a <= 1.0 for a in acc)  # both blocks moved walkers
    assert 0.05 < post.info["rotation_acceptance"] < 0.95
    x = post.chains[:4, -1]
    fresh = np.asarray(post.target.logp_batch(jnp.asarray(x)))
    np.testing.assert_allclose(post.log_prob[:4, -1], fresh, rtol=1e-9)
    # every coordinate moved in every walker over the run
    assert np.all(np.ptp(post.chains, axis=1) > 0)


def test_hmc_flag_refuses_user_moves_and_nuts(tiny_model):
    with pytest.raises(bm.BayesmotionError, match="hmc=True"):
        sample_posterior(tiny_model, n_steps=10, progress=False, hmc=True,
                         moves=emcee.moves.DEMove())
    with pytest.raises(bm.BayesmotionError, match="NUTS is already Hamiltonian"):
        sample_posterior(tiny_model, n_steps=10, progress=False, hmc=True, method="nuts")


# ------------------------------------------------------------------ independence Metropolis
class _LPModel(_Model):
    """emcee's model interface as the independence move uses it: a generator and a batched
    log-density returning (log_prob, blobs)."""

    def __init__(self, seed, logp):
        super().__init__(seed)
        self._lp = jax.jit(jax.vmap(logp))
        self.calls = 0

    def compute_log_prob_fn(self, xs):
        self.calls += 1
        return np.asarray(self._lp(jnp.asarray(xs))), None


def test_independence_move_keeps_an_exact_target_with_a_wrong_proposal():
    # exact iid draws stay exact under an invariant kernel, even when the proposal's centre and
    # scale are off (a kernel that accepted every proposal would hand back the proposal's
    # moments: mean shifted by 0.7 sd, variances 2.25x)
    rng = np.random.default_rng(0)
    n = 4000
    x0 = np.c_[rng.multivariate_normal(_MEAN, _COV, n), rng.logistic(size=n)]
    sd = np.sqrt(np.diag(_COV))
    move = IndependenceMove([0, 1, 2], _MEAN + 0.7 * sd, 2.25 * _COV, df=10.0)
    model = _LPModel(1, _gauss_logp)
    state = emcee.State(x0, log_prob=np.asarray(jax.vmap(_gauss_logp)(jnp.asarray(x0))))
    for _ in range(4):
        state, acc = move.propose(model, state)
    assert model.calls == 4  # one batched evaluation per step
    assert 0.2 < move.acceptance < 0.9 and acc.dtype == bool
    x = state.coords
    np.testing.assert_array_equal(x[:, 3], x0[:, 3])
    assert np.mean(x[:, 0] != x0[:, 0]) > 0.5
    se = sd / np.sqrt(n)
    assert np.all(np.abs(x[:, :3].mean(0) - _MEAN) < 4.5 * se)
    np.testing.assert_allclose(np.cov(x[:, :3].T), _COV, rtol=0.12, atol=0.02 * np.abs(_COV).max())
    np.testing.assert_allclose(state.log_prob, np.asarray(jax.vmap(_gauss_logp)(
        jnp.asarray(x))), rtol=1e-12, atol=1e-9)


def test_independence_move_in_emcee_mixes_a_correlated_block_in_a_few_steps():
    _check_block_mixes_from_a_bad_start(IndependenceMove([0, 1, 2], _MEAN, 1.3 * _COV), 100, 4,
                                        0.05)



def _two_modes(x):
    """0.7 N(-3, 0.5^2) + 0.3 N(2, 0.8^2) in x[0], N(0, 1) in x[1], logistic in x[2]."""
    a = jnp.log(0.7) - 0.5 * ((x[0] + 3) / 0.5) ** 2 - jnp.log(0.5)
    b = jnp.log(0.3) - 0.5 * ((x[0] - 2) / 0.8) ** 2 - jnp.log(0.8)
    return jnp.logaddexp(a, b) - 0.5 * x[1] ** 2 - x[2] - 2 * jnp.log1p(jnp.exp(-x[2]))


def test_mixture_proposal_moves_walkers_between_modes_and_keeps_the_target():
    # every walker starts in the left mode; a mixture with one (misplaced, too wide) component
    # per mode brings 30% of them to the right mode, with the right moments; one component at
    # the left mode leaves nearly all of them there
    rng = np.random.default_rng(5)
    n = 4000
    x0 = np.c_[rng.normal(-3, 0.5, n), rng.normal(size=n), rng.logistic(size=n)]
    lp0 = np.asarray(jax.vmap(_two_modes)(jnp.asarray(x0)))
    mix = IndependenceMove([0, 1], [[-2.8, 0.2], [2.3, -0.1]],
                           [np.diag([0.5, 1.5]), np.diag([1.0, 1.2])], df=10.0,
                           weights=[0.5, 0.5])
    one = IndependenceMove([0, 1], [-2.8, 0.2], np.diag([0.5, 1.5]), df=10.0)
    out = {}
    for name, move in (("mix", mix), ("one", one)):
        state, model = emcee.State(x0.copy(), log_prob=lp0.copy()), _LPModel(6, _two_modes)
        for _ in range(25):
            state, _ = move.propose(model, state)
        out[name] = state.coords
        np.testing.assert_allclose(state.log_prob, np.asarray(jax.vmap(_two_modes)(
            jnp.asarray(state.coords))), rtol=1e-12, atol=1e-9)
    right = out["mix"][:, 0] > 0
    assert abs(right.mean() - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n)
    x = out["mix"]
    assert abs(x[right, 0].mean() - 2) < 4 * 0.8 / np.sqrt(right.sum())
    assert abs(x[~right, 0].mean() + 3) < 4 * 0.5 / np.sqrt((~right).sum())
    assert abs(x[:, 1].std() - 1) < 0.05
    np.testing.assert_array_equal(x[:, 2], x0[:, 2])
    assert np.mean(out["one"][:, 0] > 0) < 0.05  # its t tails reach the right mode rarely
    assert 0.3 < mix.acceptance < 0.9
    with pytest.raises(ValueError, match=r"cov must have shape \(2, 2, 2\)"):
        IndependenceMove([0, 1], np.zeros((2, 2)), np.eye(2))
    with pytest.raises(ValueError, match="weights must be 2 positive"):
        IndependenceMove([0, 1], np.zeros((2, 2)), np.stack([np.eye(2)] * 2), weights=[1, 0])

def test_independence_move_rejects_non_finite_proposals_and_validates_arguments():
    move = IndependenceMove([0, 1, 2], _MEAN, _COV)
    state = _walled_state()
    for _ in range(3):
        state, _ = move.propose(_LPModel(2, _walled), state)
    assert np.all(state.coords[:, 0] < 1.5) and np.all(np.isfinite(state.log_prob))
    assert move.acceptance > 0.2
    with pytest.raises(ValueError, match="non-empty block"):
        IndependenceMove([], [], np.zeros((0, 0)))
    with pytest.raises(ValueError, match=r"mean must have shape \(2,\)"):
        IndependenceMove([0, 1], [0.0], np.eye(2))
    with pytest.raises(ValueError, match="positive definite"):
        IndependenceMove([0, 1], [0.0, 0.0], -np.eye(2))
    with pytest.raises(ValueError, match="df"):
        IndependenceMove([0], [0.0], np.eye(1), df=0.0)



class _TwoModeTarget:
    """A stand-in for posterior.Target over (log_beta, a two-level 'couple' style) with a known
    answer: 0.75 N(m1, 0.2^2 I) + 0.25 N(m2, 0.2^2 I); m2 has the couple vectors near the
    simplex's centre (unconstrained 0), as the demo-size posterior's second mode."""

    M1, M2, SD = np.array([0.0, 1.2, -1.2]), np.array([0.5, 0.1, -0.2]), 0.2

    def __init__(self):
        tree = {"log_beta": jnp.zeros(1), "style:couple": jnp.zeros((2, 1))}
        x0, self.unravel = ravel_pytree(tree)
        self.x0 = np.asarray(x0)
        self.ndim = 3
        self.names = ["log_beta[0]", "style:couple[0, 0]", "style:couple[1, 0]"]

        def logp(x):
            a = jnp.log(0.75) - 0.5 * jnp.sum(((x - self.M1) / self.SD) ** 2)
            b = jnp.log(0.25) - 0.5 * jnp.sum(((x - self.M2) / self.SD) ** 2)
            return jnp.logaddexp(a, b)

        self._logp = logp
        self.logp = jax.jit(logp)
        self.logp_batch = jax.jit(jax.vmap(logp))
        conc = {"couple": np.array([[11.0, 1.0], [1.0, 11.0]])}
        self.model = type("M", (), {"log_posterior_fn": type("F", (), {
            "style_prior": type("P", (), {"concentration": conc})})})
        self.searches = []

    def laplace(self, centre):
        return np.linalg.inv(-np.asarray(jax.hessian(self._logp)(jnp.asarray(centre))))

    def conditional_map(self, max_iter=500, progress=False, start=None):
        from scipy.optimize import minimize

        self.searches.append(np.array(start))
        vg = jax.jit(jax.value_and_grad(lambda x: -self._logp(x)))
        r = minimize(lambda x: [np.asarray(v, dtype=float) for v in vg(jnp.asarray(x))],
                     self.x0 if start is None else start, jac=True, method="L-BFGS-B")
        return r.x, {"converged": bool(r.success)}


def test_independence_move_finds_the_idle_factor_mode_and_samples_both_modes():
    target = _TwoModeTarget()
    centre = target.conditional_map(start=target.M1 + 0.1)[0]
    modes = idle_factor_modes(target, centre, target.laplace(centre), np.arange(3))
    # the search started from the main mode with the couple vectors at the simplex's centre
    np.testing.assert_allclose(target.searches[-1], [centre[0], 0.0, 0.0], atol=1e-12)
    assert [m["searched_from"] for m in modes] == [None, "couple"]
    np.testing.assert_allclose(modes[1]["x"], target.M2, atol=1e-4)
    # Laplace evidence is exact for Gaussian modes: weights 0.75 / 0.25
    np.testing.assert_allclose([m["weight"] for m in modes], [0.75, 0.25], atol=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = run_emcee(target, centre, 32, 400, 100, 1, 0, None, False, "ball", 1e-2,
                          None, independence=True)
    x = post.chains.reshape(-1, 3)
    second = x[:, 1] < 0.65
    # 9,600 kept draws, walkers started at the main mode: each mode holds its share
    assert abs(second.mean() - 0.25) < 0.04
    np.testing.assert_allclose(x[~second].mean(0), target.M1, atol=0.03)
    np.testing.assert_allclose(x[second].mean(0), target.M2, atol=0.05)
    assert post.info["independence_acceptance"] > 0.5
    assert [round(m["weight"], 2) for m in post.info["modes"]] == [0.75, 0.25]
    # a factor whose coordinates the independence move does not draw is not searched
    one = idle_factor_modes(target, centre, target.laplace(centre), np.array([0]))
    assert len(one) == 1  # the couple coordinates are not in that block: no search
