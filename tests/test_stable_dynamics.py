"""The dynamics' explicit stationary autoregression: the parameterisation cannot represent an
explosive linear part, the layer equals a hand-written Gaussian reference, and rollouts stay
bounded (and keep moving where the data is periodic)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import multivariate_normal

import bayesmotion as bm
from bayesmotion.data.motion import Motion, MotionDataset, Trial
from bayesmotion.errors import BayesmotionError
from bayesmotion.gp import kernels
from bayesmotion.model import layers
from bayesmotion.model.generate import DIVERGED, check_bounded, dynamics_rollout
from bayesmotion.model.params import ar_coefficients, ar_log_prior, ar_pacf
from bayesmotion.model.spec import HGPDM

from .conftest import make_tiny_dataset


def spectral_radius(a) -> float:
    """Largest |root| of the companion matrix of i_t = sum_l a_l i_{t-l}."""
    a = np.asarray(a)
    C = np.zeros((a.size, a.size))
    C[0] = a
    C[1:, :-1] = np.eye(a.size - 1)
    return float(np.max(np.abs(np.linalg.eigvals(C))))


@pytest.mark.parametrize("order", [1, 2])
def test_every_parameter_value_is_a_stationary_autoregression(order):
    rng = np.random.default_rng(0)
    u = np.concatenate([rng.normal(0, 3, (2000, order)),
                        rng.uniform(-8, 8, (2000, order))])
    radii = [spectral_radius(ar_coefficients(jnp.asarray(x))) for x in u]
    assert max(radii) < 1.0
    # the edge is approached, so oscillating gaits with little damping are representable
    assert max(radii) > 0.999


def test_the_map_covers_the_whole_stationary_triangle():
    """Every stationary AR(2) (|a2| < 1, a2 +- a1 < 1) has a parameter value, and points
    outside the triangle are refused by the inverse."""
    rng = np.random.default_rng(1)
    hits = 0
    while hits < 500:
        a = rng.uniform([-2, -1], [2, 1])
        if not (a[1] + a[0] < 1 and a[1] - a[0] < 1):
            with pytest.raises(ValueError, match="not stationary"):
                ar_pacf(a)
            continue
        hits += 1
        back = ar_coefficients(jnp.arctanh(jnp.asarray(ar_pacf(a))))
        np.testing.assert_allclose(back, a, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError):
        ar_pacf([2.0, -1.0])  # the unit-root constant-velocity extrapolation


def test_the_partial_autocorrelation_prior_is_a_normalised_uniform():
    total, _ = quad(lambda u: np.exp(float(ar_log_prior(jnp.array([u])))), -40, 40)
    assert total == pytest.approx(1.0, abs=1e-8)
    u = jnp.array([0.3, -2.0])
    expected = np.sum(np.log(1 - np.tanh(np.asarray(u)) ** 2) - np.log(2))
    assert float(ar_log_prior(u)) == pytest.approx(expected, rel=1e-12)
    assert np.isfinite(float(ar_log_prior(jnp.array([300.0, -300.0]))))
    g = jax.grad(lambda x: ar_log_prior(x))(jnp.array([0.0, 1.0]))
    np.testing.assert_allclose(g, [0.0, -2 * np.tanh(1.0)], rtol=1e-12)


def test_the_layer_is_a_gaussian_around_the_autoregressive_mean():
    """gpdm_loglik with ``ar`` equals, column by column, a dense multivariate normal of the
    outputs less sum_l a_l i_{t-l} under the RBF-only kernel, plus the restart prior."""
    rng = np.random.default_rng(2)
    I = rng.normal(size=(13, 2))
    index = layers.DynamicsIndex([6, 7], 2)
    alpha = jnp.array([0.8, 1.3, 0.6, 40.0])  # rbf, ls lag 1, ls lag 2, noise precision
    a = jnp.array([1.2, -0.5])
    S = [jnp.asarray(np.eye(2)[[0] * 6 + [1] * 7])]
    got = layers.gpdm_loglik(jnp.asarray(I), S, alpha, index, 0.0, 1.5, a)
    lags = [I[ix] for ix in index.lag]
    out = I[index.out] - (1.2 * lags[0] - 0.5 * lags[1])
    s = np.asarray(S[0])[index.out]
    d1 = ((lags[0][:, None] - lags[0][None]) ** 2).sum(-1)
    d2 = ((lags[1][:, None] - lags[1][None]) ** 2).sum(-1)
    K = (s @ s.T) * 0.8 * np.exp(-0.5 * (1.3 * d1 + 0.6 * d2)) + np.eye(len(out)) / 40.0
    want = sum(multivariate_normal(np.zeros(len(out)), K).logpdf(out[:, q]) for q in range(2))
    first = I[index.first]
    want += multivariate_normal(np.zeros(first.size), 1.5 * np.eye(first.size)).logpdf(
        first.ravel())
    assert float(got) == pytest.approx(want, rel=1e-10)
    assert not kernels.has_linear_term(alpha, 2)
    with pytest.raises(ValueError, match="entries"):
        kernels.has_linear_term(jnp.ones(5), 2)


@pytest.fixture(scope="module")
def stable_tiny():
    return HGPDM(latent_dim=3, interaction_dim=3).fit(make_tiny_dataset(), max_iter=60,
                                                      progress=False)


def test_without_the_gp_the_linear_part_decays_from_any_start(stable_tiny):
    """The mechanism itself, in the rollout code: with the RBF GP's weights zeroed the mean
    rollout is the autoregression alone, which returns to the origin from a far start."""
    P = stable_tiny.predictor()
    assert stable_tiny.spec.dynamics_linear == "stable"
    assert spectral_radius(P.ar) < 1.0
    P0 = P._replace(dyn=P.dyn._replace(A=jnp.zeros_like(P.dyn.A)))
    I0 = jnp.full((2, 3), 1e3)
    styles = [jnp.broadcast_to(jnp.eye(s.shape[1])[0], (2000, s.shape[1])) for s in P.dyn_style]
    I, _ = dynamics_rollout(P0, I0, styles, jax.random.PRNGKey(0), 2000, False, False)
    I = np.asarray(I)
    assert np.all(np.isfinite(I))
    assert np.abs(I[-100:]).max() < 1e-3 * np.abs(I[:10]).max()


def test_a_far_start_returns_to_the_training_range(stable_tiny):
    rng = np.abs(np.asarray(stable_tiny.params["I"])).max()
    far = np.full((2, 3), 20 * rng)
    roll = stable_tiny.generate(emotion="happy", n_frames=400, start=far, n_samples=2)
    assert np.abs(roll.I[-100:]).max() < 2 * rng
    assert np.abs(roll.samples["I"][:, -100:]).max() < 3 * rng


def test_a_diverged_rollout_is_refused_with_the_reason():
    train = np.ones((10, 2))
    check_bounded(np.full((50, 2), 0.5 * DIVERGED), train, "stable")
    with pytest.raises(BayesmotionError, match="diverged.*dynamics_linear='stable'"):
        check_bounded(np.full((50, 2), 1e15), train, "kernel")
    with pytest.raises(BayesmotionError, match="diverged"):
        check_bounded(np.array([[0.0, np.nan]]), train, "stable")


def test_the_option_is_validated_and_old_specifications_keep_the_paper_dynamics():
    with pytest.raises(BayesmotionError, match="dynamics_linear"):
        HGPDM(dynamics_linear="linear")
    d = HGPDM().to_dict()
    assert d["dynamics_linear"] == "stable"
    del d["dynamics_linear"]  # written before the option existed
    assert HGPDM.from_dict(d).dynamics_linear == "kernel"


def test_model_files_with_a_unit_root_are_refused(stable_tiny, tmp_path):
    path = tmp_path / "m.npz"
    stable_tiny.save(path)
    assert bm.load(path).spec.dynamics_linear == "stable"
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    key = next(k for k in arrays if k.endswith("atanh_pacf"))
    arrays[key] = np.array([30.0, -30.0])
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(BayesmotionError, match="unit root"):
        bm.load(bad)


def walk_like(fps=10.0, n=40, seed=0) -> MotionDataset:
    """Two styles of a periodic motion on the CMU skeleton: every rotation channel a sinusoid
    (and its second harmonic) of the gait phase, the root moving forward."""
    sk = bm.load_cmu_handshake().actors[0].skeleton
    rng = np.random.default_rng(seed)
    C = sk.n_channels
    amp, ph = rng.uniform(2, 15, C), rng.uniform(0, 2 * np.pi, C)
    base = rng.uniform(-20, 20, C)
    trials = []
    for style, (period, gain) in {"calm": (1.2, 1.0), "brisk": (0.8, 1.6)}.items():
        for k in range(2):
            t = np.arange(n) / fps + 0.3 * k
            phase = 2 * np.pi * t / period
            v = (base + gain * amp * np.sin(phase[:, None] + ph)
                 + 0.3 * np.sin(2 * phase[:, None] + 2 * ph))
            v[:, :3] = 0.0
            v[:, 0] = 5.0 * t * gain
            trials.append(Trial((Motion(sk, v, fps, f"{style}{k}"),), {"emotion": style},
                                f"{style}{k}"))
    return MotionDataset(tuple(trials), {"emotion": ("calm", "brisk")})


@pytest.mark.slow
def test_a_periodic_model_keeps_moving_and_stays_bounded_for_5000_frames():
    ds = walk_like()
    model = HGPDM(latent_dim=3, interaction_dim=3).fit(ds, max_iter=150, progress=False)
    rng = np.abs(np.asarray(model.params["I"])).max()
    for style in ("calm", "brisk", np.array([0.5, 0.5])):
        roll = model.generate(emotion=style, n_frames=5000)
        assert np.all(np.isfinite(roll.angles))
        assert np.abs(roll.I).max() < 2 * rng
        speed = np.abs(np.diff(roll.angles[0, :, 6:], axis=0)).mean(-1)
        print(style, "joint speed, last 500 / first 500 frames:",
              speed[-500:].mean() / speed[:500].mean())
        assert speed[-500:].mean() > 0.7 * speed[:500].mean()
    real = np.mean([np.abs(np.diff(t.actors[0].values[:, 6:], axis=0)).mean()
                    for t in ds if t.labels["emotion"] == "calm"])
    late = np.abs(np.diff(model.generate(emotion="calm", n_frames=5000).angles[0, -500:, 6:],
                          axis=0)).mean()
    assert 0.5 < late / real < 2.0  # the calm walk still moves at about its own pace


def test_the_dynamics_weight_scales_the_dynamics_term_alone(stable_tiny):
    from dataclasses import replace

    from bayesmotion.model.logpost import LogPosterior

    params = {k: jnp.asarray(v) for k, v in stable_tiny.params.items()}
    plain = LogPosterior(stable_tiny.spec, stable_tiny.data).layer_terms(params, 1e-8)
    spec3 = replace(stable_tiny.spec, dynamics_weight=3.0)
    heavy = LogPosterior(spec3, stable_tiny.data).layer_terms(params, 1e-8)
    assert float(heavy["dynamics"]) == pytest.approx(3.0 * float(plain["dynamics"]), rel=1e-12)
    for k in ("bottom", "interaction", "prior"):
        assert float(heavy[k]) == float(plain[k])
    assert HGPDM.from_dict(spec3.to_dict()).dynamics_weight == 3.0
    for bad in (0.0, -1.0, float("nan"), "2", True):
        with pytest.raises(BayesmotionError, match="dynamics_weight"):
            HGPDM(dynamics_weight=bad)


def test_the_posterior_samples_the_autoregression_inside_the_stationary_region(stable_tiny):
    with pytest.warns(Warning, match="shorter than"):  # a short chain is enough here
        post = bm.sample_posterior(stable_tiny, n_steps=40, progress=False, seed=0)
    assert any(n.startswith("atanh_pacf") for n in post.target.names)
    ar = post.idata.posterior["ar"]
    assert list(ar.coords["ar_lag"].values) == ["a_lag1", "a_lag2"]
    draws = np.asarray(ar).reshape(-1, 2)
    assert max(spectral_radius(a) for a in draws) < 1.0
    assert post.idata.posterior["alpha"].shape[-1] == 4  # no linear-kernel weights


def test_a_start_far_outside_the_training_range_is_the_users_and_not_a_divergence(stable_tiny):
    rng = np.abs(np.asarray(stable_tiny.params["I"])).max()
    roll = stable_tiny.generate(emotion="sad", n_frames=200, start=np.full((2, 3), 300 * rng))
    assert np.abs(roll.I[-50:]).max() < 2 * rng
