"""The style vectors' Gram entries, what the likelihood identifies of them, count in the
chain's diagnostics: burn-in, thinning, the too-short warning and the convergence summary."""

import warnings

import arviz as az
import emcee
import jax.numpy as jnp
import numpy as np
import pytest

from bayesmotion.inference.diagnostics import arviz_without_numba, convergence
from bayesmotion.inference.posterior import ChainTooShortWarning, posterior_from_chain
from bayesmotion.inference.target import Target, gram_entries, style_grams
from bayesmotion.model.params import simplex_to_style, style_to_simplex


def test_gram_entries_are_the_level_vectors_inner_products(tiny_model):
    target = Target(tiny_model)
    rng = np.random.default_rng(0)
    xs = target.x0 + 0.3 * rng.normal(size=(5, target.ndim))
    G = style_grams(target, xs)["emotion"]
    names, vals = gram_entries(target, xs)
    assert names == ["gram:emotion[happy, happy]", "gram:emotion[happy, sad]",
                     "gram:emotion[sad, sad]"]
    for x, g, v in zip(xs, G, vals, strict=True):
        S = np.asarray(style_to_simplex(target.unravel(jnp.asarray(x))["style:emotion"]))
        np.testing.assert_allclose(g, S @ S.T, rtol=1e-12)
        np.testing.assert_allclose(v, [g[0, 0], g[0, 1], g[1, 1]], rtol=1e-12)
    hyper = Target(tiny_model, block="hyper")  # the style vectors held: nothing to report
    assert style_grams(hyper, hyper.x0[None]) == {}
    assert gram_entries(hyper, hyper.x0[None])[0] == []


def flipping_chain(target, n_steps, n_walkers, rho, seed=0):
    """Two-level style vectors (p, 1 - p) whose distance from the centre follows an AR(1) of
    coefficient ``rho`` while a random sign each step swaps p and 1 - p for both levels: the
    swap keeps the Gram matrix, so the style coordinates decorrelate in a step and the Gram
    entries in about (1 + rho) / (1 - rho) steps. The other coordinates are white noise."""
    rng = np.random.default_rng(seed)
    chain = target.x0 + 0.01 * rng.normal(size=(n_steps, n_walkers, target.ndim))
    idx = [i for i, n in enumerate(target.names) if n.startswith("style:emotion")]
    z = rng.normal(size=(n_walkers, 2))
    for t in range(n_steps):
        z = rho * z + np.sqrt(1 - rho**2) * rng.normal(size=z.shape)
        sign = rng.choice([-1.0, 1.0], size=(n_walkers, 1))
        p = 0.5 + sign * (0.25 + 0.05 * z)  # (walkers, levels)
        S = np.stack([p, 1 - p], -1)  # (walkers, 2 levels, 2)
        chain[t][:, idx] = np.asarray(simplex_to_style(jnp.asarray(S))).reshape(n_walkers, -1)
    return chain


def test_burn_in_and_the_warning_follow_the_slow_gram_not_the_fast_coordinates(tiny_model):
    target = Target(tiny_model)
    rho = 0.95  # tau = 39
    chain = flipping_chain(target, 600, 16, rho)
    with pytest.warns(ChainTooShortWarning, match="max tau ~ [3-5][0-9]"):
        post = posterior_from_chain(target, chain, np.zeros(chain.shape[:2]),
                                    np.ones(16), None, None, {})
    tau, tau_gram = post.info["tau"], post.info["tau_gram"]
    assert sorted(tau_gram) == ["gram:emotion[happy, happy]", "gram:emotion[happy, sad]",
                                "gram:emotion[sad, sad]"]
    assert np.max(tau) < 5  # the style coordinates look independent step to step
    assert 20 < min(tau_gram.values()) and max(tau_gram.values()) < 80
    assert post.info["burn"] == int(min(2 * max(tau_gram.values()), 300))


def test_convergence_reports_the_gram_entries_r_hat_and_ess(tiny_model):
    target = Target(tiny_model)
    chain = flipping_chain(target, 400, 16, 0.95, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = posterior_from_chain(target, chain, np.zeros(chain.shape[:2]), np.ones(16),
                                    100, 1, {})
    got = convergence(post)
    _, g = gram_entries(target, post.chains.reshape(-1, target.ndim))
    g = g.reshape(*post.chains.shape[:2], -1)
    with arviz_without_numba():
        d = az.convert_to_dataset({"g": g})
        raw = az.convert_to_dataset({"x": post.chains})
        rhat_g, ess_g = float(az.rhat(d)["g"].max()), float(az.ess(d, method="bulk")["g"].min())
        rhat_x = float(az.rhat(raw)["x"].max())
    assert got["max_rhat"] == pytest.approx(max(rhat_g, rhat_x))
    assert got["min_ess_bulk"] == pytest.approx(ess_g)  # the Gram is the slowest
    assert rhat_g > rhat_x
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.all(emcee.autocorr.integrated_time(g.swapaxes(0, 1), quiet=True) > 10)


def test_grams_of_a_long_chain_come_in_chunks_and_of_none_as_empty(tiny_model, monkeypatch):
    import bayesmotion.inference.target as target_mod

    target = Target(tiny_model)
    xs = target.x0 + 0.2 * np.random.default_rng(3).normal(size=(7, target.ndim))
    whole = style_grams(target, xs)["emotion"]
    monkeypatch.setattr(target_mod, "GRAM_CHUNK", 3)
    np.testing.assert_array_equal(style_grams(target, xs)["emotion"], whole)
    assert style_grams(target, xs[:0])["emotion"].shape == (0, 2, 2)
    names, vals = gram_entries(target, xs[:0])
    assert len(names) == 3 and vals.shape == (0, 3)
