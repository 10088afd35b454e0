"""CanonicalStyles: the LQ split of the style vectors is an exact inverse pair, and its volume
term is the map's log-Jacobian (by finite differences of the full bijection)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm

from bayesmotion.inference.moves import StyleShear, plane_basis
from bayesmotion.inference.moves.canonical import CanonicalStyles, lq
from bayesmotion.model.params import simplex_to_style, style_to_simplex

K = 4
IDX = np.arange(2, 2 + K * (K - 1))


def random_states(n, rng):
    """(n, 2 + K (K - 1)): two scales, then style vectors well inside the simplex."""
    S = np.array([[rng.dirichlet(2.0 + 6.0 * np.eye(K)[k]) for k in range(K)]
                  for _ in range(n)])
    u = np.asarray(simplex_to_style(jnp.asarray(S))).reshape(n, -1)
    return np.concatenate([rng.normal(size=(n, 2)), u], 1)


@pytest.mark.parametrize("sheared", [False, True])
def test_split_and_merge_are_inverse_and_split_is_the_lq_factor(sheared):
    shear = (StyleShear({"e": IDX}, {"e": np.eye(K)[[0, 1, 2, 3, 0]]},
                        [([0, 1], ["e"], np.array([3.0, 4, 5, 6, 7]))]) if sheared else None)
    can = CanonicalStyles({"e": IDX, "two": np.array([0])}, shear)  # a 2-level factor: left alone
    assert len(can.blocks) == 1
    x = random_states(6, np.random.default_rng(0))
    w, (Q,) = can.split(x)
    back, inside = can.merge(w, [Q])
    assert inside.all()
    np.testing.assert_allclose(back, x, atol=1e-10)
    np.testing.assert_allclose(Q @ np.swapaxes(Q, 1, 2), np.broadcast_to(np.eye(K - 1), Q.shape),
                               atol=1e-12)
    S = np.asarray(style_to_simplex(jnp.asarray(x[:, IDX].reshape(-1, K, K - 1))))
    V = (S - 1.0 / K) @ plane_basis(K)
    T, _ = lq(V)
    # the free entries are T's lower trapezoid (log diagonal), the Gram is T T^T
    np.testing.assert_allclose(T @ np.swapaxes(T, 1, 2), V @ np.swapaxes(V, 1, 2), atol=1e-12)
    assert np.all(np.triu(T, 1) == 0) and np.all(np.diagonal(T, axis1=1, axis2=2) > 0)
    np.testing.assert_allclose(w[:, IDX[0]], np.log(T[:, 0, 0]), rtol=1e-12)
    assert np.all(w[:, IDX[9:]] == 0)
    # everything else is the (sheared) input
    y = x if shear is None else np.asarray(shear.forward(jnp.asarray(x)))
    np.testing.assert_allclose(w[:, :2], y[:, :2], rtol=1e-12)
    # a step that leaves the simplex is flagged
    far = w.copy()
    far[:, IDX[0]] += 5.0
    assert not can.merge(far, [Q])[1].any()


def test_volume_term_is_the_log_jacobian_of_the_full_bijection():
    # (T's free entries, Q = Q0 expm(A(a))) -> stick coordinates is a bijection of 12 dimensions;
    # at a = 0 its log |det| must be log_volume + log_stick up to one constant
    can = CanonicalStyles({"e": IDX})
    rng = np.random.default_rng(1)
    x = random_states(5, rng)
    w, (Q,) = can.split(x)
    iu = np.triu_indices(K - 1, 1)

    def forward(p, Q0):
        a = np.zeros((K - 1, K - 1))
        a[iu] = p[9:]
        wt = np.zeros(2 + K * (K - 1))
        wt[IDX[:9]] = p[:9]
        xx, inside = can.merge(wt[None], [(Q0 @ expm(a - a.T))[None]])
        assert inside.all()
        return xx[0, IDX]

    diffs = []
    for i in range(len(x)):
        p0 = np.concatenate([w[i, IDX[:9]], np.zeros(3)])
        h = 1e-6
        J = np.stack([(forward(p0 + h * e, Q[i]) - forward(p0 - h * e, Q[i])) / (2 * h)
                      for e in np.eye(12)], 1)
        logdet = np.linalg.slogdet(J)[1]
        diffs.append(logdet - can.log_volume(w[i:i + 1])[0] - can.log_stick(x[i:i + 1])[0])
    assert np.ptp(diffs) < 1e-6


@pytest.fixture(scope="module")
def three_emotions():
    """A small model whose emotion factor has 3 levels (so it is rotated and canonical)."""
    import bayesmotion as bm

    ds = bm.load_handshakes(fps=5.0).filter(couple="c1", emotion=["neutral", "happy", "sad"])
    data = bm.MotionDataset(ds.trials, {"emotion": ("neutral", "happy", "sad"),
                                        "couple": ("c1",)})
    return bm.HGPDM(latent_dim=2, interaction_dim=2).fit(data, max_iter=60, progress=False)


@pytest.mark.slow
@pytest.mark.optimized
def test_default_sampler_with_canonical_de_agrees_with_nuts_on_three_emotions(three_emotions):
    # the default moves on a model with a rotated (3-level) style factor: DE on the LQ factor,
    # the rotations, the independence step (after the adaptation, on the hyperparameters and
    # the Gram factor); NUTS on the same potential is the reference
    import warnings

    import bayesmotion as bm
    from bayesmotion.inference.diagnostics import compare_posteriors
    from bayesmotion.inference.moves import CanonicalDE, StyleRotations
    from bayesmotion.inference.posterior import ChainTooShortWarning
    from bayesmotion.inference.proposals import default_moves
    from bayesmotion.inference.target import Target

    model = three_emotions
    moves = default_moves(Target(model))
    assert isinstance(moves, StyleRotations) and isinstance(moves.inner, CanonicalDE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        e = bm.sample_posterior(model, n_steps=1200, progress=False, seed=0)
        n = bm.sample_posterior(model, n_steps=400, method="nuts", n_chains=2, progress=False,
                                seed=1)
    cmp = compare_posteriors(e, n)
    print("emcee vs NUTS: max |z| =", cmp["max_abs_z"], "max |z_sd| =", cmp["max_abs_z_sd"])
    assert cmp["max_abs_z"] < 3.5 and cmp["max_abs_z_sd"] < 3.5
    # the run did draw the Gram factor in the independence step after its adaptation
    sampled = e.info["independence_block_sampling"]
    assert "log T:emotion[0, 0]" in sampled and "T:emotion[1, 0]" in sampled
    assert not any(name.startswith("style:emotion") for name in sampled)
    assert 0.02 < e.info["independence_acceptance"] < 1


@pytest.mark.slow
@pytest.mark.optimized
def test_a_resumed_run_recomputes_the_canonical_proposal_bit_for_bit(three_emotions, tmp_path,
                                                                       monkeypatch):
    # the proposal after the adaptation is computed from the file's stored chain: a run
    # stopped inside the sampling phase and resumed is the uninterrupted run
    import warnings

    import bayesmotion as bm
    from bayesmotion.inference import emcee_runner, proposals
    from bayesmotion.inference.chainfile import REFIT_ATTR, open_h5
    from bayesmotion.inference.posterior import ChainTooShortWarning

    monkeypatch.setattr(emcee_runner, "adapt_steps", lambda n: 20)
    # refitted at 40 and 80: the stop at 50 falls between them
    monkeypatch.setattr(proposals, "REFIT_STEPS", (40, 80))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        whole = bm.sample_posterior(three_emotions, n_steps=120, progress=False, burn=20, thin=1,
                                    backend=tmp_path / "whole.h5")
        bm.sample_posterior(three_emotions, n_steps=50, progress=False, burn=20, thin=1,
                            backend=tmp_path / "parts.h5")
        parts = bm.sample_posterior(three_emotions, n_steps=120, progress=False, burn=20, thin=1,
                                    backend=tmp_path / "parts.h5")
    assert parts.info["adapt_steps"] == whole.info["adapt_steps"] == 20
    assert parts.info["refit_steps"] == whole.info["refit_steps"] == [40, 80]
    with open_h5(tmp_path / "parts.h5", "r") as f:
        assert f["mcmc"].attrs[REFIT_ATTR].tolist() == [40, 80]
    assert "log T:emotion[0, 0]" in whole.info["independence_block_sampling"]
    np.testing.assert_array_equal(parts.chains, whole.chains)


def test_a_proposal_that_overflows_is_outside_not_a_hang():
    # exp of a huge log-diagonal, NaN or inf in T: marked outside (refused), never handed to
    # the SVD of the alignment (which can loop forever on inf)
    can = CanonicalStyles({"e": IDX})
    x = random_states(4, np.random.default_rng(0))
    w, (R,) = can.split(x)
    bad = w.copy()
    bad[0, IDX[0]] = 800.0
    bad[1, IDX[1]] = np.nan
    bad[2, IDX[3]] = np.inf
    out, inside = can.merge(bad, [R])
    assert inside.tolist() == [False, False, False, True]
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[3], x[3], atol=1e-10)


@pytest.mark.parametrize(("reflect", "align"), [(True, True), (True, False), (False, False)])
def test_reflections_let_canonical_de_reach_both_orientations(reflect, align):
    # unaligned, CanonicalDE keeps each walker's Q and the rotations have det 1, so the vectors'
    # orientation in the plane (sign of det of the first K - 1 rows of V) can change only by the
    # rotations' reflection sub-step; under a loose Dirichlet both orientations carry mass
    import emcee

    from bayesmotion.inference.moves import CanonicalDE, StyleRotations
    from bayesmotion.model.params import log_dirichlet, style_log_jacobian

    k = 3
    conc = 1.0 + 0.5 * np.eye(k)
    B = plane_basis(k)
    rng = np.random.default_rng(0)
    draws = np.array([[rng.dirichlet(conc[j]) for j in range(k)] for _ in range(20000)])

    def positive(S):
        return np.linalg.det(((S - 1.0 / k) @ B)[:, :k - 1]) > 0

    want = positive(draws).mean()  # the prior's share of one orientation

    @jax.jit
    def density(u):  # (n, k, k - 1) -> (n,): the Dirichlet prior of each walker's vectors
        return (jnp.sum(log_dirichlet(style_to_simplex(u), jnp.asarray(conc)), -1)
                + jax.vmap(style_log_jacobian)(u))

    def logp(xs):
        return np.asarray(density(jnp.asarray(xs).reshape(-1, k, k - 1)), dtype=float)

    idx = np.arange(k * (k - 1))
    start = draws[:32][positive(draws[:32])][:16]  # every walker in one orientation
    x0 = np.asarray(simplex_to_style(jnp.asarray(start))).reshape(len(start), -1)
    moves = StyleRotations(CanonicalDE(CanonicalStyles({"e": idx}, align=align)), {"e": idx},
                           {"e": conc}, reflect=reflect)
    sampler = emcee.EnsembleSampler(len(x0), idx.size, logp, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(4).get_state()
    sampler.run_mcmc(x0, 1500, progress=False)
    S = np.asarray(style_to_simplex(jnp.asarray(sampler.get_chain(discard=300).reshape(
        -1, k, k - 1))))
    share = positive(S).mean()
    if reflect:
        assert 0.1 < want < 0.9 and abs(share - want) < 0.06
        assert 0 < moves.reflection_acceptance < 1
    else:  # the orientation never changes
        assert share == 1.0


@pytest.mark.parametrize("align", [False, True])
def test_aligned_split_is_an_inverse_pair_that_keeps_the_gram_factor(align):
    can = CanonicalStyles({"e": IDX}, align=align)
    plain = CanonicalStyles({"e": IDX}, align=False)
    x = random_states(8, np.random.default_rng(3))
    w, (R,) = can.split(x)
    back, inside = can.merge(w, [R])
    assert inside.all()
    np.testing.assert_allclose(back, x, atol=1e-10)
    np.testing.assert_allclose(w, plain.split(x)[0], atol=1e-12)  # the same T either way
    if align:  # vectors near their own vertices: R, the rotation left over, is near the identity
        assert np.trace(R, axis1=1, axis2=2).min() > 0.8 * (K - 1)


def _gram(S):
    iu = np.triu_indices(S.shape[-1])
    return (S @ np.swapaxes(S, -1, -2))[..., iu[0], iu[1]]


@pytest.mark.parametrize(("align", "volume"), [(True, True), (False, True), (True, False)])
def test_canonical_independence_keeps_an_exact_posterior(align, volume):
    # a Dirichlet prior times a likelihood of the Gram entries (what the GP layers see of the
    # style vectors); exact draws by rejection from the prior. Walkers started at exact draws
    # must stay exact under CanonicalIndependence with the rotations; without the map's volume
    # change in the ratio they drift (the check can fail)
    import emcee
    import jax

    from bayesmotion.inference.moves import CanonicalIndependence, StyleRotations
    from bayesmotion.model.params import log_dirichlet, style_log_jacobian

    k, n = 4, 3000
    conc = 1.0 + 0.5 * np.eye(k)
    rng = np.random.default_rng(0)
    prior = _gram(np.stack([rng.dirichlet(conc[j], size=20000) for j in range(k)], 1))
    m, sig = prior.mean(0), prior.std(0)

    def loglik(S):
        return -0.5 * np.sum(((_gram(S) - m) / sig) ** 2, -1)

    found = []
    while sum(len(f) for f in found) < 2 * n:
        D = np.stack([rng.dirichlet(conc[j], size=200000) for j in range(k)], 1)
        found.append(D[np.log(rng.uniform(size=len(D))) < loglik(D)])
    exact = np.concatenate(found)[:2 * n]
    jac = jax.jit(jax.vmap(style_log_jacobian))

    def logp(xs):
        u = jnp.asarray(xs).reshape(-1, k, k - 1)
        S = np.asarray(style_to_simplex(u))
        return (np.asarray(jnp.sum(log_dirichlet(jnp.asarray(S), jnp.asarray(conc)), -1))
                + np.asarray(jac(u)) + loglik(S))

    idx = np.arange(k * (k - 1))
    can = CanonicalStyles({"e": idx}, align=align)
    x = np.asarray(simplex_to_style(jnp.asarray(exact))).reshape(len(exact), -1)
    block = can.slots()
    w = can.split(x[:n])[0][:, block]  # the proposal: moments of other exact draws
    if not volume:
        can.change = lambda w0, *rest: np.zeros(len(w0))
    move = StyleRotations(CanonicalIndependence(can, block, w.mean(0), 1.2 * np.cov(w.T)),
                          {"e": idx}, {"e": conc}, reflect=True)
    sampler = emcee.EnsembleSampler(n, idx.size, logp, vectorize=True, moves=move)
    sampler.random_state = np.random.RandomState(1).get_state()
    sampler.run_mcmc(x[n:], 20, progress=False)
    g = _gram(np.asarray(style_to_simplex(jnp.asarray(
        sampler.get_last_sample().coords.reshape(-1, k, k - 1)))))
    ref = _gram(exact[:n])
    z = (g.mean(0) - ref.mean(0)) / np.sqrt((g.var(0) + ref.var(0)) / n)
    accepted = move.inner.acceptance
    print(f"align={align} volume={volume}: acceptance {accepted:.3f}, "
          f"max |z| {np.abs(z).max():.1f}")
    assert 0.03 < accepted < 0.5  # enough fresh draws for a drift to show
    if volume:
        assert np.abs(z).max() < 4.0
    else:
        assert np.abs(z).max() > 10.0


def test_canonical_mixture_takes_moments_in_canonical_coordinates(monkeypatch):
    # the proposal after the adaptation: a sinh-arcsinh map of each canonical coordinate over
    # the block (hyperparameters and the Gram factor's entries) fitted to the states, and the
    # moments of the mapped states; a mode with too few states gets its Laplace approximation
    # carried through the canonical map's Jacobian and the sinh-arcsinh map's slope
    from bayesmotion.inference import proposals
    from bayesmotion.inference.proposals import canonical_block, canonical_mixture

    rng = np.random.default_rng(5)
    can = CanonicalStyles({"e": IDX})
    x0 = random_states(1, rng)[0]
    A = rng.normal(size=(x0.size, x0.size))
    cov = 1e-4 * (A @ A.T / x0.size + np.eye(x0.size))
    modes = [{"x": x0, "cov": cov, "weight": 1.0}]
    block = np.array([0, 1])  # the coordinates that are not rotated style vectors
    cb = canonical_block(can, block)
    assert cb.tolist() == [0, 1, *IDX[:9].tolist()]
    assert can.slot_names()[:2] == ["log T:e[0, 0]", "T:e[1, 0]"]
    z = rng.multivariate_normal(x0, cov, size=400)
    got_block, mean, c, weights, marginal = canonical_mixture(can, block, modes, z)
    w = can.split(z)[0][:, cb]
    assert got_block.tolist() == cb.tolist() and weights is None and marginal.ndim == cb.size
    y = marginal.forward(w)[0]
    np.testing.assert_allclose(mean, y.mean(0), atol=1e-12)
    np.testing.assert_allclose(c, np.cov(y.T), rtol=1e-6, atol=1e-14)
    # too few states, no map: the Laplace covariance, linearised, against many mapped draws
    monkeypatch.setattr(proposals, "MARGINAL_MAP", False)
    _, mean2, c2, _, none = canonical_mixture(can, block, modes, z[:5])
    assert none is None
    many = can.split(rng.multivariate_normal(x0, cov, size=200000))[0][:, cb]
    np.testing.assert_allclose(mean2, can.split(x0[None])[0][0, cb], atol=1e-12)
    sd = np.sqrt(np.diag(np.cov(many.T)))
    np.testing.assert_allclose(np.sqrt(np.diag(c2)), sd, rtol=0.05)
    np.testing.assert_allclose(c2 / np.outer(sd, sd), np.corrcoef(many.T), atol=0.05)
    # with the map (fitted to the 5 states): that Gaussian carried through its slope
    monkeypatch.setattr(proposals, "MARGINAL_MAP", True)
    _, mean3, c3, _, m3 = canonical_mixture(can, block, modes, z[:5])
    slope = m3.slope(mean2[None])[0]
    np.testing.assert_allclose(mean3, m3.forward(mean2[None])[0][0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(c3, slope[:, None] * c2 * slope[None, :], rtol=1e-9, atol=1e-14)
