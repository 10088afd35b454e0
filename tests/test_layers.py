"""Kernels and layer log-likelihoods against dense SciPy references."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.stats import multivariate_normal

import bayesmotion  # noqa: F401  (float64)
from bayesmotion.gp import blas as _blas
from bayesmotion.gp import densities, kernels, linalg
from bayesmotion.model import layers


def dense_loglik(K, Y):
    return sum(multivariate_normal(np.zeros(len(K)), K).logpdf(Y[:, d]) for d in range(Y.shape[1]))


def rbf_loop(A, B, var, inv_ls):
    return np.array([[var * np.exp(-0.5 * inv_ls * np.sum((a - b) ** 2)) for b in B] for a in A])


@pytest.fixture
def rng():
    return np.random.default_rng(42)


def test_rbf_matches_loop_and_is_symmetric_psd(rng):
    A = rng.normal(size=(12, 3))
    K = np.asarray(kernels.rbf(A, A, 1.7, 0.6))
    np.testing.assert_allclose(K, rbf_loop(A, A, 1.7, 0.6), rtol=1e-12)
    np.testing.assert_allclose(K, K.T, atol=0)
    assert np.linalg.eigvalsh(K).min() > -1e-10


def test_rbf_second_derivatives_exact_where_inputs_coincide(rng):
    """Second derivatives of the kernel at a point equal to a training input (where a clip's
    projection starts): d^2/da^2 of v exp(-l/2 |a - b|^2) at a = b is -v l I. The clip of
    rounding-negative squared distances must not zero it."""
    B = rng.normal(size=(5, 3)) * 3.0
    for j in range(5):
        H = jax.hessian(lambda a, j=j: kernels.rbf(a[None], B, 1.7, 0.6)[0, j])(jnp.asarray(B[j]))
        np.testing.assert_allclose(H, -1.7 * 0.6 * np.eye(3), rtol=1e-10, atol=1e-12)
    D = np.asarray(kernels.sqdist(B, B))
    assert np.all(D >= 0) and np.all(np.diag(D) < 1e-12 * np.sum(B**2, 1))


def test_gplvm_loglik_matches_scipy(rng):
    X, Y = rng.normal(size=(15, 2)), rng.normal(size=(15, 4))
    gamma = jnp.array([1.3, 0.7, 20.0])
    K = rbf_loop(X, X, 1.3, 0.7) + np.eye(15) / 20.0
    np.testing.assert_allclose(float(densities.gplvm_loglik(X, Y, gamma)), dense_loglik(K, Y),
                               rtol=1e-8)


def test_multifactor_kernel_and_loglik_match_scipy(rng):
    N = 14
    I, Z = rng.normal(size=(N, 3)), rng.normal(size=(N, 5))
    c = rng.dirichlet(np.ones(2), size=N)
    e = rng.dirichlet(np.ones(4), size=N)
    beta = jnp.array([0.9, 1.4, 30.0])
    K = (c @ c.T) * (e @ e.T) * rbf_loop(I, I, 0.9, 1.4)
    got = np.asarray(kernels.interaction_kernel(I, I, [c, e], [c, e], beta))
    np.testing.assert_allclose(got, K, rtol=1e-12)
    assert np.linalg.eigvalsh(K).min() > -1e-10
    np.testing.assert_allclose(float(layers.style_gplvm_loglik(I, Z, [c, e], beta)),
                               dense_loglik(K + np.eye(N) / 30.0, Z), rtol=1e-8)


def test_one_hot_styles_zero_cross_emotion_covariance_exactly(rng):
    I = rng.normal(size=(8, 2))
    e = np.eye(4)[[0, 0, 1, 1, 2, 2, 3, 3]]
    K = np.asarray(kernels.interaction_kernel(I, I, [e], [e], jnp.array([1.0, 1.0, 1.0])))
    same = e @ e.T
    assert np.all(K[same == 0] == 0.0)
    assert np.all(K[same == 1] > 0.0)
    alpha = jnp.array([1.0, 0.5, 0.5, 0.3, 0.3, 10.0])
    Kd = np.asarray(kernels.dynamics_kernel([I, I], [I, I], [e], [e], alpha))
    assert np.all(Kd[same == 0] == 0.0)


def dynamics_reference(I, lengths, style, alpha, order, prior_var):
    """Plain loops: build inputs per trial, dense kernel, scipy logpdf."""
    outs, ins, ss, firsts = [], [], [], []
    s0 = 0
    for n in lengths:
        tr = I[s0:s0 + n]
        firsts.append(tr[:order])
        for t in range(order, n):
            outs.append(tr[t])
            ins.append([tr[t - l] for l in range(1, order + 1)])
            ss.append(style[s0 + t])
        s0 += n
    M = len(outs)
    K = np.zeros((M, M))
    for i in range(M):
        for j in range(M):
            r = sum(alpha[1 + l] * np.sum((ins[i][l] - ins[j][l]) ** 2) for l in range(order))
            lin = sum(alpha[1 + order + l] * ins[i][l] @ ins[j][l] for l in range(order))
            K[i, j] = (ss[i] @ ss[j]) * (alpha[0] * np.exp(-0.5 * r) + lin)
    K += np.eye(M) / alpha[1 + 2 * order]
    first = np.concatenate(firsts)
    ll0 = multivariate_normal(np.zeros(first.size), prior_var * np.eye(first.size)).logpdf(
        first.ravel())
    return dense_loglik(K, np.array(outs)) + ll0


@pytest.mark.parametrize("order", [1, 2])
def test_gpdm_loglik_matches_loop_reference(rng, order):
    lengths = [6, 7, 5]
    N = sum(lengths)
    I = rng.normal(size=(N, 3))
    style = np.repeat(rng.dirichlet(np.ones(3), size=3), lengths, axis=0)
    alpha = np.array([1.2] + [0.8] * order + [0.4] * order + [25.0])
    index = layers.DynamicsIndex(lengths, order)
    got = float(layers.gpdm_loglik(I, [style], jnp.asarray(alpha), index, prior_var=2.0))
    np.testing.assert_allclose(got, dynamics_reference(I, lengths, style, alpha, order, 2.0),
                               rtol=1e-8)


def test_dynamics_diag_matches_kernel(rng):
    lags = [rng.normal(size=(9, 2)) for _ in range(2)]
    S = [rng.dirichlet(np.ones(3), size=9)]
    alpha = jnp.array([1.1, 0.3, 0.6, 0.2, 0.7, 5.0])
    K = kernels.dynamics_kernel(lags, lags, S, S, alpha)
    np.testing.assert_allclose(kernels.dynamics_diag(lags, S, alpha), jnp.diag(K), rtol=1e-12)


def test_layer_gradients_match_finite_differences(rng):
    X, Y = rng.normal(size=(10, 2)), rng.normal(size=(10, 3))
    check_grads(lambda X, g: densities.gplvm_loglik(X, Y, jnp.exp(g)), (X, jnp.log(jnp.array(
        [1.0, 0.5, 10.0]))), order=1, modes=["rev"], atol=1e-5, rtol=1e-5)
    style = [rng.dirichlet(np.ones(2), size=10)]
    index = layers.DynamicsIndex([5, 5], 2)
    check_grads(lambda I, a: layers.gpdm_loglik(I, style, jnp.exp(a), index),
                (X, jnp.log(jnp.array([1.0, 0.5, 0.5, 0.3, 0.3, 10.0]))), order=1,
                modes=["rev"], atol=1e-5, rtol=1e-5)


def test_jit_equals_eager(rng):
    X, Y = rng.normal(size=(10, 2)), rng.normal(size=(10, 3))
    g = jnp.array([1.0, 0.5, 10.0])
    eager = densities.gplvm_loglik(X, Y, g)
    jitted = jax.jit(densities.gplvm_loglik)(X, Y, g)
    np.testing.assert_allclose(float(eager), float(jitted), rtol=1e-13)


def test_non_positive_definite_gives_minus_inf_not_nan():
    K = -jnp.eye(4)
    val = densities.gaussian_loglik(K, jnp.ones((4, 2)))
    assert val == -jnp.inf


@pytest.mark.parametrize("n", [1, 7, 16, 33, 130])
def test_blocked_inverses_match_numpy(rng, n):
    A = rng.normal(size=(n, n))
    K = A @ A.T / n + np.eye(n)
    L = np.linalg.cholesky(K)
    # block 8 makes every size above it recurse, with uneven halves for the odd ones
    np.testing.assert_allclose(linalg.triangular_inverse(jnp.asarray(L), block=8),
                               np.linalg.inv(L), rtol=1e-10, atol=1e-12)
    Kinv = np.asarray(linalg.lower_gram(linalg.triangular_inverse(jnp.asarray(L), block=8),
                                        block=8))
    np.testing.assert_allclose(Kinv, np.linalg.inv(K), rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(Kinv, Kinv.T)


@pytest.mark.parametrize("path", ["public", "lapack", "xla"])
def test_cholesky_inverse_matches_numpy(rng, path):
    """Both implementations (LAPACK callback on CPU from N = 256, XLA elsewhere), single and
    batched (vmap), float64 and float32; a matrix that is not positive definite gives a NaN
    diagonal, the callers' failure test."""
    if path == "lapack" and not linalg.HOST_CALLBACK:
        pytest.skip("jaxlib >= 0.10: bayesmotion does not use the host callback there")
    fn = {"public": linalg.cholesky_inverse, "lapack": linalg._cholesky_inverse_lapack,
          "xla": linalg._cholesky_inverse_xla}[path]
    n = 300
    Ks = []
    for _ in range(2):
        A = rng.normal(size=(n, n))
        Ks.append(A @ A.T / n + 0.5 * np.eye(n))
    d, Kinv = jax.jit(fn)(jnp.asarray(Ks[0]))
    np.testing.assert_allclose(d, np.diag(np.linalg.cholesky(Ks[0])), rtol=1e-12)
    np.testing.assert_allclose(Kinv, np.linalg.inv(Ks[0]), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(Kinv, np.asarray(Kinv).T, rtol=1e-13, atol=1e-15)
    db, Kb = jax.jit(jax.vmap(fn))(jnp.asarray(np.stack(Ks)))
    for b, K in enumerate(Ks):
        np.testing.assert_allclose(Kb[b], np.linalg.inv(K), rtol=1e-9, atol=1e-11)
    d32, K32 = jax.jit(fn)(jnp.asarray(Ks[1], jnp.float32))
    assert K32.dtype == jnp.float32
    np.testing.assert_allclose(K32, np.linalg.inv(Ks[1]), rtol=2e-3, atol=2e-3)
    bad = Ks[0] - 10 * np.eye(n)
    assert np.all(np.isnan(np.asarray(jax.jit(fn)(jnp.asarray(bad))[0])))


@pytest.mark.parametrize("host_callback", [True, False])
def test_cholesky_inverse_uses_a_host_callback_only_where_allowed(monkeypatch, host_callback):
    """On CPU from N = 256 the program holds the LAPACK callback only where HOST_CALLBACK
    allows it (jaxlib < 0.10); otherwise it is callback-free XLA, at every size."""
    monkeypatch.setattr(linalg, "HOST_CALLBACK", host_callback)
    for n, expected in [(300, host_callback and jax.default_backend() == "cpu"), (100, False)]:
        # a fresh function each time: make_jaxpr caches traces by function, not by globals
        text = str(jax.make_jaxpr(lambda K: linalg.cholesky_inverse(K))(jnp.eye(n)))
        assert ("pure_callback" in text) == expected, (n, host_callback)
    assert linalg.HOST_CALLBACK == host_callback


def test_lapack_path_restores_the_blas_thread_count(rng):
    """The host factorisation raises OpenBLAS's threads for its own thread only and puts the
    previous count back (the rest of the process keeps bayesmotion's one thread)."""
    set_local = _blas._set_threads_local()
    if set_local is None:
        pytest.skip("no scipy-bundled OpenBLAS with openblas_set_num_threads_local here, or "
                    "OPENBLAS_NUM_THREADS was set by the caller")
    before = set_local(1)
    A = rng.normal(size=(300, 300))
    d, Kinv = linalg._host_cholesky_inverse(A @ A.T / 300 + np.eye(300))
    assert set_local(before) == 1
    np.testing.assert_allclose(Kinv @ (A @ A.T / 300 + np.eye(300)), np.eye(300), atol=1e-10)


def test_blas_threads_are_raised_only_when_other_processes_leave_the_cores_idle(monkeypatch):
    """The decision uses windows of >= 0.25 s: machine busy time minus this process's CPU time
    per wall second; under half a core used by others -> idle. No sample (not Linux) -> no."""
    assert _blas.others_cores(3.0, 1.0, 2.0) == 1.0
    samples = iter([(10.0, 1.0, 100.0),    # first window starts: no history yet -> no
                    (10.5, 1.4, 100.1),    # 0.1 s later: too short a window, keep the answer
                    (11.6, 2.4, 101.0),    # others: (1.6 - 1.4) / 1.0 = 0.2 cores -> idle
                    (13.6, 2.6, 102.0),    # others: (2.0 - 0.2) / 1.0 = 1.8 cores -> busy
                    None])                  # no /proc/stat -> no
    load = _blas._OtherLoad()
    monkeypatch.setattr(load, "_sample", lambda: next(samples))
    assert [load.idle() for _ in range(5)] == [False, False, True, False, False]


def test_layer_gradient_at_lapack_size_equals_dense_reference(rng):
    """N = 300 takes the LAPACK path on CPU: value and d logp / dK of gaussian_loglik against
    scipy and the closed form (alpha alpha^T - D K^-1) / 2; gplvm_loglik's gradient against
    autodiff through jnp.linalg.cholesky; -inf with a zero gradient outside the support."""
    n, D = 300, 5
    X, Y = rng.normal(size=(n, 3)), rng.normal(size=(n, D))
    g = jnp.array([1.3, 0.8, 30.0])
    K = np.asarray(kernels.bottom_kernel(X, X, g)) + np.eye(n) / 30.0
    v, dK = jax.value_and_grad(densities.gaussian_loglik)(jnp.asarray(K), jnp.asarray(Y))
    np.testing.assert_allclose(float(v), dense_loglik(K, Y), rtol=1e-10)
    Kinv = np.linalg.inv(K)
    alpha = Kinv @ Y
    ref = 0.5 * (alpha @ alpha.T - D * Kinv)
    np.testing.assert_allclose(dK, ref, rtol=1e-8, atol=1e-11 * np.abs(ref).max())

    def reference(X, g):
        L = jnp.linalg.cholesky(kernels.bottom_kernel(X, X, g) + jnp.eye(n) / g[2])
        z = jax.scipy.linalg.solve_triangular(L, Y, lower=True)
        return -0.5 * jnp.sum(z**2) - D * jnp.sum(jnp.log(jnp.diag(L))) - 0.5 * n * D * np.log(
            2 * np.pi)

    grads = jax.jit(jax.grad(densities.gplvm_loglik, argnums=(0, 2)))(jnp.asarray(X), Y, g)
    for a, b in zip(grads, jax.grad(reference, argnums=(0, 1))(jnp.asarray(X), g), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-9 * float(jnp.max(jnp.abs(b))))
    bad = jnp.array([1.0, 0.5, -0.5])
    v, grads = jax.value_and_grad(densities.gplvm_loglik, argnums=(0, 2))(X, Y, bad)
    assert v == -jnp.inf and all(np.all(np.asarray(d) == 0) for d in grads)


@pytest.mark.parametrize("jitter", [0.0, 1e-3])
def test_hand_written_gplvm_gradient_equals_autodiff_of_generic_layer(rng, jitter):
    """gplvm_loglik's own VJP against autodiff of gaussian_loglik on the same kernel, for every
    argument (latents, outputs, hyperparameters, jitter), at N large enough to recurse."""
    X, Y = rng.normal(size=(150, 3)), rng.normal(size=(150, 4))
    g = jnp.array([1.3, 0.8, 30.0])

    def generic(X, Y, g, j):
        return densities.gaussian_loglik(kernels.bottom_kernel(X, X, g) + jnp.eye(len(X)) / g[2],
                                      Y, j)

    args = (jnp.asarray(X), jnp.asarray(Y), g, jnp.asarray(jitter))
    v_ref, g_ref = jax.value_and_grad(generic, argnums=(0, 1, 2, 3))(*args)
    v, grads = jax.jit(jax.value_and_grad(densities.gplvm_loglik, argnums=(0, 1, 2, 3)))(*args)
    np.testing.assert_allclose(float(v), float(v_ref), rtol=1e-11)
    for a, b in zip(grads, g_ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-9 * float(jnp.max(jnp.abs(b))))


def test_outside_support_is_minus_inf_with_zero_gradient(rng):
    X, Y = rng.normal(size=(6, 2)), rng.normal(size=(6, 2))
    g = jnp.array([1.0, 0.5, -0.5])  # noise variance -2: K is not positive definite
    v, grads = jax.value_and_grad(densities.gplvm_loglik, argnums=(0, 1, 2))(X, Y, g)
    assert v == -jnp.inf
    assert all(np.all(np.asarray(d) == 0) for d in grads)
    # an outer function whose own derivative is NaN there (logsumexp of -inf terms) must still
    # get zeros, not NaN, from both hand-written VJPs
    outer = lambda f: lambda *a: jax.nn.logsumexp(jnp.stack([f(*a)] * 2))
    for d in jax.grad(outer(densities.gplvm_loglik), argnums=(0, 1, 2))(X, Y, g):
        assert np.all(np.asarray(d) == 0)
    dK = jax.grad(outer(densities.gaussian_loglik))(-jnp.eye(4), jnp.ones((4, 2)))
    assert np.all(np.asarray(dK) == 0)


def test_gplvm_gradient_is_finite_when_the_variance_underflows(rng):
    X, Y = rng.normal(size=(8, 2)), rng.normal(size=(8, 3))
    grad = jax.grad(lambda lg: densities.gplvm_loglik(X, Y, jnp.exp(lg)))(
        jnp.array([-800., 0., 3.]))
    assert np.all(np.isfinite(np.asarray(grad)))


def test_value_under_differentiation_equals_the_triangular_solve_value(rng):
    """The differentiated path forms K^-1 (its gradient needs it); its value must agree with the
    value-only path (Cholesky + triangular solve) on an ill-conditioned kernel matrix too."""
    X = np.cumsum(rng.normal(scale=0.05, size=(300, 2)), axis=0)  # a smooth, dense path
    g = jnp.array([1.0, 1.0, 1e5])  # noise variance 1e-5
    K = np.asarray(kernels.bottom_kernel(X, X, g)) + np.eye(300) / 1e5
    assert np.linalg.cond(K) > 1e6
    # white outputs, and outputs drawn from the GP itself (Y = L z: the quadratic form then
    # runs along K's small eigenvalues, where forming K^-1 loses most)
    for Y in (rng.normal(size=(300, 4)), np.linalg.cholesky(K) @ rng.normal(size=(300, 4))):
        plain = float(densities.gplvm_loglik(X, Y, g))
        with_grad = float(jax.value_and_grad(densities.gplvm_loglik)(X, Y, g)[0])
        generic = float(jax.value_and_grad(densities.gaussian_loglik)(jnp.asarray(K), Y)[0])
        np.testing.assert_allclose(with_grad, plain, rtol=1e-9)
        np.testing.assert_allclose(generic, plain, rtol=1e-9)
