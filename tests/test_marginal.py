"""SinhArcsinh: the map, its inverse and log-Jacobian against finite differences and
quadrature, maximum likelihood on known laws, and the independence move taken after it keeps
its target (moments within Monte-Carlo error) and accepts more on a skewed one."""

import emcee
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from bayesmotion.inference.moves import IndependenceMove, SinhArcsinh
from bayesmotion.inference.moves.marginal import sas_forward, sas_log_density

PARAMS = np.array([[0.3, np.log(1.7), 0.8, np.log(0.6)],    # right-skewed, heavy tails
                   [-1.0, np.log(0.5), -0.5, np.log(1.8)],  # left-skewed, light tails
                   [2.0, 0.0, 0.0, 0.0]])                   # affine


def draws(params, n, seed):
    """Exact draws: x = loc + scale sinh((asinh(u) + eps) / delta), u ~ N(0, 1)."""
    u = np.random.default_rng(seed).normal(size=(n, len(params)))
    return SinhArcsinh(params).inverse(u)


def test_inverse_undoes_forward_and_the_log_jacobian_is_the_slope():
    m = SinhArcsinh(PARAMS)
    x = draws(PARAMS, 50, 0)
    y, log_jac = m.forward(x)
    np.testing.assert_allclose(m.inverse(y), x, rtol=1e-10, atol=1e-10)
    eps = 1e-6
    fd = (m.forward(x + eps)[0] - m.forward(x - eps)[0]) / (2 * eps)
    np.testing.assert_allclose(m.slope(x), fd, rtol=1e-6)
    np.testing.assert_allclose(log_jac, np.log(fd).sum(1), rtol=1e-6, atol=1e-8)
    # the traced map's gradient is the same slope
    grad = jax.vmap(jax.grad(lambda v: jnp.sum(sas_forward(jnp.asarray(PARAMS), v[None])[0])))
    np.testing.assert_allclose(np.asarray(grad(jnp.asarray(x))), m.slope(x), rtol=1e-9)


@pytest.mark.parametrize("row", range(len(PARAMS)))
def test_log_density_integrates_to_one_and_matches_the_draws(row):
    p = jnp.asarray(PARAMS[row:row + 1])

    def dens(v):
        return float(np.exp(sas_log_density(p, jnp.asarray([[v]]))[0]))

    total, err = integrate.quad(dens, -np.inf, np.inf, limit=200)
    assert abs(total - 1.0) < 1e-6 and err < 1e-6
    # the CDF Phi(forward(x)) fits exact draws (Kolmogorov-Smirnov)
    m = SinhArcsinh(PARAMS[row:row + 1])
    x = draws(PARAMS[row:row + 1], 4000, row + 1)[:, 0]
    assert stats.kstest(x, lambda v: stats.norm.cdf(m.forward(v[:, None])[0][:, 0])).pvalue > 0.01


def test_fit_recovers_known_laws_and_leaves_a_gaussian_gaussian():
    x = draws(PARAMS, 20000, 3)
    m = SinhArcsinh.fit(x)
    # the fitted law's quantiles are the true ones (parameters trade off; quantiles do not)
    q = stats.norm.ppf([0.01, 0.1, 0.5, 0.9, 0.99])[:, None] * np.ones(len(PARAMS))
    truth = SinhArcsinh(PARAMS).inverse(q)
    got = m.inverse(q)
    spread = truth[-1] - truth[0]
    assert np.all(np.abs(got - truth) < 0.03 * spread)
    g = SinhArcsinh.fit(np.random.default_rng(4).normal(2.0, 3.0, size=(20000, 1)))
    _, _, eps, log_delta = g.params[0]
    assert abs(eps) < 0.05 and abs(log_delta) < 0.05


def test_fit_of_a_constant_or_broken_column_is_the_affine_map_or_identity():
    rng = np.random.default_rng(6)
    z = np.column_stack([rng.normal(size=200), np.full(200, 3.0)])
    m = SinhArcsinh.fit(z)
    np.testing.assert_array_equal(m.params[1], [0.0, 0.0, 0.0, 0.0])  # identity
    y, log_jac = m.forward(z)
    assert np.all(np.isfinite(y)) and np.all(np.isfinite(log_jac))
    with pytest.raises(ValueError, match="finite"):
        SinhArcsinh(np.array([[0.0, 0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="samples"):
        SinhArcsinh.fit(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="maps 3 coordinates"):
        IndependenceMove([0, 1], np.zeros(2), np.eye(2), marginal=SinhArcsinh(PARAMS))


def _skewed_logp(x):
    """Two independent Gamma(2) coordinates, on the log scale (a skewed target)."""
    return np.sum(2.0 * x - np.exp(x), -1)


def _run(move, n_steps, seed):
    W = 40
    rng = np.random.default_rng(seed)
    start = np.log(rng.gamma(2.0, size=(W, 2)))
    sampler = emcee.EnsembleSampler(W, 2, _skewed_logp, vectorize=True, moves=move)
    sampler.run_mcmc(emcee.State(start, random_state=np.random.RandomState(seed).get_state()),
                     n_steps)
    return sampler.get_chain(), move.acceptance


def test_independence_after_the_map_keeps_a_skewed_target_and_accepts_more():
    # proposals fitted to exact draws: a t in the mapped coordinates, and one without the map
    z = np.log(np.random.default_rng(7).gamma(2.0, size=(5000, 2)))
    m = SinhArcsinh.fit(z)
    y = m.forward(z)[0]
    mapped = IndependenceMove([0, 1], y.mean(0), np.cov(y.T), marginal=m)
    plain = IndependenceMove([0, 1], z.mean(0), np.cov(z.T))
    chain, acc_mapped = _run(mapped, 600, 8)
    _, acc_plain = _run(plain, 600, 8)
    assert acc_mapped > acc_plain + 0.05
    # the walkers (started exact) stay exact: mean and variance of log Gamma(2)
    tau = emcee.autocorr.integrated_time(chain[100:], quiet=True).max()
    kept = chain[100:].reshape(-1, 2)
    n_eff = kept.shape[0] / tau
    law = stats.loggamma(2.0)
    mean, var = law.mean(), law.var()
    assert np.all(np.abs(kept.mean(0) - mean) < 4 * np.sqrt(var / n_eff))
    # var of the sample variance: (mu4 - var^2) / n
    mu4 = (law.stats(moments="k") + 3.0) * var ** 2
    assert np.all(np.abs(kept.var(0) - var) < 4 * np.sqrt((mu4 - var ** 2) / n_eff))


def test_a_draw_the_map_cannot_take_back_is_refused():
    # delta 1/4: a t draw of 40 maps back to loc + scale sinh(4 asinh 40) ~ 1e8; one of 1e80
    # overflows to inf and must be refused, the walker kept where it was
    m = SinhArcsinh(np.array([[0.0, 0.0, 0.0, np.log(0.25)]]))
    move = IndependenceMove([0], np.zeros(1), np.eye(1) * 1e160, marginal=m, df=1e6)
    z = np.array([[0.5], [1.5]])
    new, log_ratio = move.draw(z, np.random.RandomState(0))
    assert np.all(np.isneginf(log_ratio)) and np.array_equal(new, z)


def test_a_draw_whose_map_slope_overflows_is_refused_not_accepted():
    # a finite draw so far out that log|dy/dx| is not finite would give q(new) = 0 and an
    # infinite ratio: it must be refused like an overflow. The map's slope is computed without
    # overflow up to the largest floats (hypot), so a map whose log-slope is -inf beyond
    # |x| = 1e100 stands in for one that runs out of range
    class Steep(SinhArcsinh):
        def forward(self, x):
            y, log_jac = super().forward(x)
            return y, np.where(np.all(np.abs(x) < 1e100, 1), log_jac, -np.inf)

    m = Steep(np.array([[0.0, 0.0, 0.0, np.log(0.25)]]))
    move = IndependenceMove([0], np.zeros(1), np.eye(1) * 1e80, marginal=m, df=1e6)
    z = np.array([[0.5], [1.5]])
    new, log_ratio = move.draw(z, np.random.RandomState(0))  # draws ~1e161: slope "-inf"
    assert np.all(np.isneginf(log_ratio)) and np.array_equal(new, z)
    # the same move with the plain map keeps those finite draws, with a finite ratio
    plain = IndependenceMove([0], np.zeros(1), np.eye(1) * 1e80, marginal=SinhArcsinh(
        np.array([[0.0, 0.0, 0.0, np.log(0.25)]])), df=1e6)
    new, log_ratio = plain.draw(z, np.random.RandomState(0))
    assert np.all(np.isfinite(log_ratio)) and np.all(np.abs(new) > 1e100)
