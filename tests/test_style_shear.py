"""StyleShear and ShearedDE: the map is a volume-preserving bijection that adds the log mean
style diagonal to the output scales, and DE in its coordinates leaves a known target
invariant."""

import warnings

import emcee
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmotion.gp.kernels import style_gram_diag
from bayesmotion.inference.moves import ShearedDE, StyleShear
from bayesmotion.inference.proposals import default_moves
from bayesmotion.inference.target import Target
from bayesmotion.model.params import log_dirichlet, style_log_jacobian, style_to_simplex

# a ridge target: K = 3 levels, 4 trials; x = [z_beta, z_alpha, u (3 x 2 stick coordinates)]
K = 3
CONC = 1.0 + 4.0 * np.eye(K)
ONEHOT = np.eye(K)[[0, 1, 2, 0]]
LENGTHS = np.array([3.0, 5.0, 4.0, 6.0])
STYLE_IDX = np.arange(2, 2 + K * (K - 1))
SD = np.array([0.3, 0.5])
LOC = np.array([0.0, 1.0])


def make_shear():
    return StyleShear({"emotion": STYLE_IDX}, {"emotion": ONEHOT}, [([0, 1], ["emotion"], LENGTHS)])


def log_g_reference(u):
    """log of the frame-weighted mean of |s(n)|^2, frame by frame in NumPy."""
    s = np.asarray(style_to_simplex(jnp.asarray(u.reshape(K, K - 1))))
    frames = np.repeat(ONEHOT @ s, LENGTHS.astype(int), axis=0)
    return np.log(np.mean(np.sum(frames**2, -1)))


def test_shear_is_a_volume_preserving_bijection_that_shifts_only_the_scales():
    shear = make_shear()
    rng = np.random.default_rng(0)
    xs = rng.normal(size=(5, 2 + K * (K - 1)))
    ys = np.asarray(shear.forward(jnp.asarray(xs)))
    for x, y in zip(xs, ys, strict=True):
        np.testing.assert_allclose(y[2:], x[2:], rtol=0, atol=0)
        np.testing.assert_allclose(y[:2], x[:2] + log_g_reference(x[2:]), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(shear.inverse(jnp.asarray(ys))), xs, atol=1e-13)
    one = lambda v: shear.forward(v[None])[0]  # noqa: E731
    J = np.asarray(jax.jacfwd(one)(jnp.asarray(xs[0])))
    assert np.linalg.slogdet(J) == pytest.approx((1.0, 0.0), abs=1e-12)


def test_shear_refuses_inconsistent_layouts():
    styles, onehot = {"emotion": STYLE_IDX}, {"emotion": ONEHOT}
    with pytest.raises(ValueError, match="do not fit"):
        StyleShear({"emotion": STYLE_IDX[:-1]}, onehot, [([0, 1], ["emotion"], LENGTHS)])
    with pytest.raises(ValueError, match="one positive number per trial"):
        StyleShear(styles, onehot, [([0, 1], ["emotion"], -LENGTHS)])
    with pytest.raises(ValueError, match="one positive number per trial"):
        StyleShear(styles, onehot, [([0, 1], ["emotion"], LENGTHS[:-1])])
    with pytest.raises(ValueError, match="overlap"):
        StyleShear(styles, onehot, [([0, 2], ["emotion"], LENGTHS)])
    with pytest.raises(ValueError, match="no style coordinates"):
        StyleShear(styles, onehot, [([0, 1], ["couple"], LENGTHS)])
    with pytest.raises(ValueError, match="output-scale coordinates"):
        StyleShear(styles, onehot, [([], ["emotion"], LENGTHS)])
    with pytest.raises(ValueError, match="style factor"):
        StyleShear({}, {}, [([0], ["emotion"], LENGTHS)])


def test_a_model_targets_shear_is_the_kernels_mean_style_diagonal(tiny_model):
    target = Target(tiny_model)
    shear = StyleShear.for_target(target)
    assert [target.names[i] for i in shear.scale_index] == ["log_beta[0]", "log_alpha[0]"]
    assert StyleShear.for_target(target) is shear  # built once per target
    p = target.unravel(jnp.asarray(target.x0))
    data = tiny_model.data
    frames = [np.repeat(np.asarray(data.onehot[f]) @ np.asarray(style_to_simplex(p["style:" + f])),
                        np.asarray(data.lengths), axis=0) for f in tiny_model.spec.factors
              if "style:" + f in p]
    want = np.log(np.mean(np.asarray(style_gram_diag(frames, sum(data.lengths)))))
    assert float(shear.log_g(jnp.asarray(target.x0), 0)) == pytest.approx(want, rel=1e-12)
    # the dynamics' g weighs each trial by its outputs, its frames after the first o
    o = tiny_model.spec.order
    outs = [np.repeat(np.asarray(data.onehot[f]) @ np.asarray(style_to_simplex(p["style:" + f])),
                      np.asarray(data.lengths) - o, axis=0) for f in tiny_model.spec.factors
            if "style:" + f in p]
    want = np.log(np.mean(np.asarray(style_gram_diag(outs, sum(data.lengths) - o * len(
        data.lengths)))))
    assert float(shear.log_g(jnp.asarray(target.x0), 1)) == pytest.approx(want, rel=1e-12)
    # the default moves propose with it; nothing to shear where the styles are held fixed
    assert isinstance(default_moves(target).inner, ShearedDE)
    assert StyleShear.for_target(Target(tiny_model, block="hyper")) is None
    upper = Target(tiny_model, block="upper")  # the factorised sampler's (beta, alpha, S)
    assert [upper.names[i] for i in StyleShear.for_target(upper).scale_index] == [
        "log_beta[0]", "log_alpha[0]"]


@pytest.mark.parametrize("kw, want", [
    ({"dynamics_linear": "kernel"}, ["log_beta[0]", "log_alpha[0]", "log_alpha[3]",
                                     "log_alpha[4]"]),
    ({"dynamics_factors": ()}, ["log_beta[0]"]),
])
def test_each_layer_shears_the_scales_its_own_style_factor_multiplies(kw, want):
    # the paper's linear dynamics term is multiplied by the style factor too; a layer without
    # style factors keeps its scales
    from bayesmotion import HGPDM

    from .conftest import make_tiny_dataset

    model = HGPDM(latent_dim=2, interaction_dim=2, **kw).fit(make_tiny_dataset(), max_iter=3,
                                                             progress=False)
    target = Target(model)
    assert [target.names[i] for i in StyleShear.for_target(target).scale_index] == want


def ridge_logp(x):
    u = x[2:].reshape(K, K - 1)
    s = style_to_simplex(u)
    lp = jnp.sum(log_dirichlet(s, jnp.asarray(CONC))) + style_log_jacobian(u)
    d = jnp.sum((jnp.asarray(ONEHOT) @ s) ** 2, -1)  # |s|^2 of each trial's level
    log_g = jnp.log(jnp.sum(jnp.asarray(LENGTHS / LENGTHS.sum()) * d))
    z = (x[:2] + log_g - jnp.asarray(LOC)) / jnp.asarray(SD)
    return lp - 0.5 * jnp.sum(z**2)


def run_ridge(moves, n_steps=3000, burn=500, n_walkers=40):
    batch = jax.jit(jax.vmap(ridge_logp))
    rng = np.random.default_rng(1)
    u0 = np.log(CONC[:, :-1] / CONC[:, -1:]).ravel() * 0.5  # near the levels' vertices
    x0 = np.concatenate([LOC - 0.8, u0])[None] + 0.05 * rng.normal(size=(n_walkers, 8))
    sampler = emcee.EnsembleSampler(n_walkers, 8, lambda xs: np.asarray(batch(jnp.asarray(xs))),
                                    vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(3).get_state()
    sampler.run_mcmc(x0, n_steps, progress=False)
    return sampler.get_chain(discard=burn)


def test_sheared_de_leaves_a_ridge_target_invariant():
    # styles ~ Dirichlet(1 + 4 onehot) per level, and each log scale + log g(styles) ~ N(LOC, SD):
    # the ridge of the module docstring with known marginals
    shear = make_shear()
    n_walkers = 40
    chain = run_ridge(ShearedDE(shear), n_walkers=n_walkers)  # (T, W, 8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = emcee.autocorr.integrated_time(chain, quiet=True)
    n_eff = chain.shape[0] * n_walkers / tau.max()
    flat = chain.reshape(-1, 8)
    s = np.asarray(jax.vmap(lambda u: style_to_simplex(u.reshape(K, K - 1)))(
        jnp.asarray(flat[:, 2:])))
    # the Dirichlet means, each within 4 Monte-Carlo errors
    want = CONC / CONC.sum(1, keepdims=True)
    se = s.std(0) / np.sqrt(n_eff)
    assert np.all(np.abs(s.mean(0) - want) < 4 * se + 1e-3)
    # the sheared scales: mean LOC and sd SD
    y = np.asarray(shear.forward(jnp.asarray(flat)))[:, :2]
    assert np.all(np.abs(y.mean(0) - LOC) < 4 * SD / np.sqrt(n_eff))
    assert np.all(np.abs(y.std(0) / SD - 1) < 4 * np.sqrt(0.5 / n_eff) + 0.02)


def test_independence_move_in_shear_coordinates_draws_the_scales_exactly():
    # in the shear's coordinates the scales' conditional is N(LOC, SD^2) whatever the styles:
    # that proposal is exact there (every proposal accepted), and a wrong one keeps the target
    from bayesmotion.inference.moves import IndependenceMove, Sequence

    shear = make_shear()
    exact = IndependenceMove([0, 1], LOC, np.diag(SD**2), df=1e6, shear=shear)
    run_ridge([(Sequence(ShearedDE(shear), exact), 1.0)], n_steps=300, burn=0, n_walkers=16)
    assert exact.acceptance > 0.999
    wrong = IndependenceMove([0, 1], LOC + 0.3, np.diag((1.5 * SD) ** 2), shear=shear)
    chain = run_ridge([(Sequence(ShearedDE(shear), wrong), 1.0)])
    assert 0.2 < wrong.acceptance < 0.95
    flat = chain.reshape(-1, 8)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        n_eff = flat.shape[0] / emcee.autocorr.integrated_time(chain, quiet=True).max()
    y = np.asarray(shear.forward(jnp.asarray(flat)))[:, :2]
    assert np.all(np.abs(y.mean(0) - LOC) < 4 * SD / np.sqrt(n_eff))
    assert np.all(np.abs(y.std(0) / SD - 1) < 4 * np.sqrt(0.5 / n_eff) + 0.02)


def test_sheared_modes_carry_the_laplace_covariance_through_the_jacobian():
    from bayesmotion.inference.proposals import sheared_modes

    shear = make_shear()
    x = np.concatenate([LOC, np.zeros(K * (K - 1))])
    cov = np.diag(np.linspace(0.1, 0.8, 8))
    (m,) = sheared_modes([{"x": x, "cov": cov, "weight": 1.0}], shear)
    np.testing.assert_allclose(m["x"], np.asarray(shear.forward(jnp.asarray(x[None])))[0])
    # finite differences of the map give the same Jacobian
    eps = 1e-6
    J = np.stack([(np.asarray(shear.forward(jnp.asarray((x + eps * e)[None])))[0]
                   - np.asarray(shear.forward(jnp.asarray((x - eps * e)[None])))[0]) / (2 * eps)
                  for e in np.eye(8)], 1)
    np.testing.assert_allclose(m["cov"], J @ cov @ J.T, rtol=1e-6, atol=1e-9)
    assert sheared_modes([{"x": x, "cov": cov}], None)[0]["cov"] is cov


def test_a_target_that_cannot_be_cached_still_gets_its_answer():
    from dataclasses import dataclass

    @dataclass
    class Bare:  # eq=True makes it unhashable: no cache, and no model, so no shear
        ndim: int = 2

    assert StyleShear.for_target(Bare()) is None


@pytest.mark.parametrize("sheared", [True, False])
def test_canonical_de_leaves_the_ridge_target_invariant(sheared):
    # DE on the style vectors' LQ factor (each walker keeping its rotation, the rotations moving
    # it): the volume term must be exact for the norms |s - c|^2 to keep their Dirichlet law
    from bayesmotion.inference.moves import StyleRotations
    from bayesmotion.inference.moves.canonical import CanonicalDE, CanonicalStyles

    shear = make_shear()
    can = CanonicalStyles({"emotion": STYLE_IDX}, shear if sheared else None)
    moves = StyleRotations(CanonicalDE(can), {"emotion": STYLE_IDX}, {"emotion": CONC})
    chain = run_ridge(moves, n_walkers=40)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tau = emcee.autocorr.integrated_time(chain, quiet=True)
    n_eff = chain.shape[0] * chain.shape[1] / tau.max()
    flat = chain.reshape(-1, 8)
    s = np.asarray(jax.vmap(lambda u: style_to_simplex(u.reshape(K, K - 1)))(
        jnp.asarray(flat[:, 2:])))
    a0 = CONC.sum(1, keepdims=True)
    mean, var = CONC / a0, CONC * (a0 - CONC) / (a0**2 * (a0 + 1))
    r2 = np.sum((s - 1.0 / K) ** 2, -1)  # each level's squared distance from the centre
    assert np.all(np.abs(r2.mean(0) - np.sum(var + (mean - 1.0 / K) ** 2, 1))
                  < 4 * r2.std(0) / np.sqrt(n_eff) + 1e-3)
    assert np.all(np.abs(s.mean(0) - mean) < 4 * s.std(0) / np.sqrt(n_eff) + 1e-3)
    y = np.asarray(shear.forward(jnp.asarray(flat)))[:, :2]
    assert np.all(np.abs(y.mean(0) - LOC) < 4 * SD / np.sqrt(n_eff))
    assert np.all(np.abs(y.std(0) / SD - 1) < 4 * np.sqrt(0.5 / n_eff) + 0.02)
