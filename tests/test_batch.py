"""bayesmotion.gp.batch.over_points: a per-point function over a batch, against a Python loop."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

import bayesmotion  # noqa: F401  (float64)
from bayesmotion.gp import batch, densities, kernels


def _gp_logp(data):
    """log N(Y | 0, var RBF(X; inv_ls) + noise I) as a function of (log var, log inv_ls, log
    noise): a Cholesky-based density, the kind the walkers evaluate."""
    X, Y = data

    def logp(theta):
        var, inv_ls, noise = jnp.exp(theta)
        K = kernels.rbf(X, X, var, inv_ls) + noise * jnp.eye(X.shape[0])
        return densities.gaussian_loglik(K, Y)

    return logp


@pytest.fixture
def problem():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(15, 2))
    Y = rng.normal(size=(15, 3))
    thetas = rng.normal(scale=0.3, size=(7, 3))
    return (jnp.asarray(X), jnp.asarray(Y)), thetas


def _reference(data, thetas):
    X, Y = map(np.asarray, data)
    out = []
    for var, inv_ls, noise in np.exp(thetas):
        d2 = ((X[:, None] - X[None]) ** 2).sum(-1)
        K = var * np.exp(-0.5 * inv_ls * d2) + noise * np.eye(len(X))
        out.append(sum(multivariate_normal(np.zeros(len(X)), K).logpdf(Y[:, j])
                       for j in range(Y.shape[1])))
    return np.array(out)


@pytest.mark.parametrize("chunk", [None, 1, 2, 3, 7, 10])
def test_over_points_matches_a_loop_for_every_chunk(problem, chunk):
    # 7 points: chunks that divide it, that leave a remainder (padded) and one larger than it
    data, thetas = problem
    fn = jax.jit(batch.over_points(_gp_logp(data), chunk))
    got = np.asarray(fn(jnp.asarray(thetas)))
    assert got.shape == (7,)
    np.testing.assert_allclose(got, _reference(data, thetas), rtol=1e-9)


def test_over_points_maps_pytrees_and_keeps_trailing_shapes(problem):
    data, thetas = problem
    logp = _gp_logp(data)

    def both(p):
        return {"value": logp(p["theta"]), "grad": jax.grad(logp)(p["theta"])}

    pts = {"theta": jnp.asarray(thetas)}
    got = jax.jit(batch.over_points(both, 2))(pts)
    want = jax.vmap(both)(pts)
    assert got["grad"].shape == (7, 3)
    for k in ("value", "grad"):
        np.testing.assert_allclose(np.asarray(got[k]), np.asarray(want[k]), rtol=1e-9)


@pytest.mark.parametrize("n", [0, 1, 2, 3, 7])
def test_over_points_handles_every_batch_size_and_mixed_leaves(n):
    # leaves of different trailing shapes in and out; sizes below, at and past the chunk, none
    rng = np.random.default_rng(n)
    pts = {"a": jnp.asarray(rng.normal(size=(n, 3))), "b": jnp.asarray(rng.normal(size=(n, 2, 2)))}

    def fn(p):
        return {"s": jnp.sum(p["a"]) + jnp.trace(p["b"]), "m": p["b"] @ p["a"][:2]}

    got = jax.jit(batch.over_points(fn, 2))(pts)
    want = jax.vmap(fn)(pts)
    assert got["s"].shape == (n,) and got["m"].shape == (n, 2)
    for k in ("s", "m"):
        np.testing.assert_allclose(np.asarray(got[k]), np.asarray(want[k]), rtol=1e-12)


def test_targets_batched_density_equals_its_pointwise_density(tiny_model):
    # emcee's log-density over walkers (chunks on a CPU) against the jitted one-point density,
    # with a point outside the support (-inf) among them
    from bayesmotion.inference.target import Target

    t = Target(tiny_model)
    rng = np.random.default_rng(0)
    xs = t.x0 + 0.05 * rng.standard_normal((5, t.ndim))
    xs[3] = np.nan  # not finite: -inf, and it must not leak into the other walkers
    got = np.asarray(t.logp_batch(jnp.asarray(xs)))
    want = np.array([float(t.logp(jnp.asarray(x))) for x in xs])
    assert got[3] == -np.inf and want[3] == -np.inf
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_default_layout_follows_the_backend(monkeypatch):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert batch.default_chunk() is None
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert batch.default_chunk() == batch.CPU_CHUNK
    # a NumPy integer is a chunk size like any other
    fn = batch.over_points(jnp.sum, np.int64(3))
    np.testing.assert_allclose(np.asarray(fn(jnp.ones((4, 2)))), 2.0)


@pytest.mark.parametrize("chunk", [0, -2, 1.5, -1.0, True, "2"])
def test_over_points_refuses_a_bad_chunk(chunk):
    with pytest.raises(ValueError, match="chunk must be"):
        batch.over_points(jnp.sum, chunk)
