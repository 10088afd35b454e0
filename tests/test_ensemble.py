"""The pure-JAX differential-evolution ensemble sampler (bayesmotion.inference.ensemble)
against known answers and against emcee's DEMove on the same target."""

import emcee
import jax.numpy as jnp
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.inference.ensemble import run_de


def gaussian(x, mu, Linv):
    z = (x - mu) @ Linv.T
    return -0.5 * jnp.sum(z * z, -1)


def _problem(d=4, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((d, d))
    C = A @ A.T + 0.5 * np.eye(d)
    mu = rng.standard_normal(d)
    Linv = np.linalg.inv(np.linalg.cholesky(C))
    p0 = mu + 0.5 * rng.standard_normal((24, d))
    return mu, C, (jnp.asarray(mu), jnp.asarray(Linv)), p0


def test_samples_a_correlated_gaussian():
    """Mean within 4 Monte-Carlo standard errors (ESS from the integrated autocorrelation) and
    the covariance within 10 %; the acceptance rate and autocorrelation time of emcee's DEMove
    on the same target (the same move, other random numbers)."""
    mu, C, args, p0 = _problem()
    n = 3000
    run = run_de(gaussian, args, p0, n, seed=3)
    chain = np.asarray(run.chain)[n // 4:]
    tau = emcee.autocorr.integrated_time(chain, tol=0)
    ess = chain.shape[0] * chain.shape[1] / tau
    flat = chain.reshape(-1, mu.size)
    assert np.all(np.abs(flat.mean(0) - mu) < 4 * np.sqrt(np.diag(C) / ess))
    assert np.all(np.abs(np.cov(flat.T) - C) <= 0.1 * np.sqrt(np.outer(np.diag(C), np.diag(C))))
    np.testing.assert_allclose(np.asarray(run.log_prob),
                               np.asarray(gaussian(run.chain, *args)), rtol=1e-12)
    ref = emcee.EnsembleSampler(24, mu.size, lambda x: np.asarray(gaussian(jnp.asarray(x), *args)),
                                vectorize=True, moves=emcee.moves.DEMove())
    ref.run_mcmc(p0, n)
    acc = np.asarray(run.accepted).mean() / n
    assert abs(acc - ref.acceptance_fraction.mean()) < 0.03
    tau_ref = emcee.autocorr.integrated_time(ref.get_chain(discard=n // 4), tol=0)
    assert np.all(np.abs(tau / tau_ref - 1) < 0.35)


def test_seeded_and_never_moves_into_zero_density():
    """The same seed gives the same chain; proposals where the density is -inf or NaN are
    always refused."""
    def half_plane(x, c):
        lp = -0.5 * jnp.sum(x * x, -1)
        return jnp.where(x[:, 0] > c, lp, jnp.where(x[:, 0] > c - 1, jnp.nan, -jnp.inf))

    p0 = np.abs(np.random.default_rng(1).standard_normal((10, 2))) + 0.1
    a = run_de(half_plane, (jnp.asarray(0.0),), p0, 200, seed=7)
    b = run_de(half_plane, (jnp.asarray(0.0),), p0, 200, seed=7)
    np.testing.assert_array_equal(np.asarray(a.chain), np.asarray(b.chain))
    assert np.all(np.asarray(a.chain)[..., 0] > 0)
    assert np.all(np.isfinite(np.asarray(a.log_prob)))
    c = run_de(half_plane, (jnp.asarray(0.0),), p0, 200, seed=8)
    assert not np.array_equal(np.asarray(a.chain), np.asarray(c.chain))


@pytest.mark.parametrize("p0, n, match", [
    (np.zeros((9, 2)), 5, "even number of walkers"),
    (np.zeros((4, 2)), 5, "even number of walkers >= 2 d \\+ 2 = 6"),
    (np.zeros(6), 5, "walkers, dimensions"),
    (np.zeros((6, 2)), 0, "n_steps must be a positive integer"),
    (np.full((6, 2), -1.0), 5, "6 of 6 have none"),
])
def test_refuses_bad_arguments(p0, n, match):
    def lp(x, c):
        return jnp.where(x[:, 0] >= c, -jnp.sum(x * x, -1), -jnp.inf)

    with pytest.raises(bm.BayesmotionError, match=match):
        run_de(lp, (jnp.asarray(0.0),), p0, n)


@pytest.mark.slow
def test_infer_emotion_samplers_agree(tiny_model):
    """infer_emotion's default style sampler (this one, one compiled program) and emcee give
    the same style posterior: the emotion coordinates' means within 4 Monte-Carlo standard
    errors of their difference."""
    from .conftest import make_tiny_dataset

    trial = make_tiny_dataset()[1]
    eps = {m: bm.infer_emotion(tiny_model, trial, n_steps=600, latent_uncertainty=False,
                               method=m, seed=2) for m in ("ensemble", "emcee")}
    assert eps["ensemble"].info["sampler"] == "ensemble"
    assert eps["emcee"].info["sampler"] == "emcee"
    means, var = [], []
    for ep in eps.values():
        s = np.asarray(ep.samples)  # (walkers, steps, K)
        means.append(s.reshape(-1, s.shape[-1]).mean(0))
        var.append(s.reshape(-1, s.shape[-1]).var(0) / ep.info["ess"])
    assert np.all(np.abs(means[0] - means[1]) <= 4 * np.sqrt(var[0] + var[1]) + 1e-9)
    # both ran the same move: similar acceptance
    assert abs(eps["ensemble"].info["acceptance"] - eps["emcee"].info["acceptance"]) < 0.05
