"""The mapping layers' noise floor (``HGPDM(mapping_noise_floor=...)``): a noise variance of
the bottom and interaction layers is the floor plus a free part, in the MAP, the samplers and
every prediction, and the plain model is the floor-0 case."""

import jax.numpy as jnp
import numpy as np
import pytest

from bayesmotion.errors import BayesmotionError
from bayesmotion.model.data import fit_codecs, prepare_data
from bayesmotion.model.fit import init_params, initial_inducing
from bayesmotion.model.io import load as load_model
from bayesmotion.model.logpost import NOISE_ENTRY, LogPosterior, constrained
from bayesmotion.model.spec import HGPDM

from .conftest import make_tiny_dataset

FLOOR = 1e-2


def test_constrained_adds_the_floor_to_the_mapping_noise_variances_only():
    p = {"log_gamma": jnp.log(jnp.array([2.0, 3.0, 50.0])),
         "log_beta": jnp.log(jnp.array([1.5, 0.5, 1e6])),
         "log_alpha": jnp.log(jnp.array([1.0, 2.0, 3.0, 1e5]))}
    plain, floored = constrained(p), constrained(p, FLOOR)
    for k in ("gamma", "beta"):
        np.testing.assert_allclose(1 / floored[k][NOISE_ENTRY],
                                   1 / plain[k][NOISE_ENTRY] + FLOOR, rtol=1e-12)
        np.testing.assert_array_equal(np.delete(floored[k], NOISE_ENTRY),
                                      np.delete(plain[k], NOISE_ENTRY))
    np.testing.assert_array_equal(floored["alpha"], plain["alpha"])
    # however large the free precision, the noise variance stays above the floor
    huge = {**p, "log_gamma": jnp.array([0.0, 0.0, 700.0])}
    assert 1 / float(constrained(huge, FLOOR)["gamma"][NOISE_ENTRY]) >= FLOOR


@pytest.mark.parametrize("bad", [-1e-3, float("nan"), float("inf"), True, "1e-3", None])
def test_a_bad_floor_is_refused(bad):
    with pytest.raises(BayesmotionError, match="mapping_noise_floor"):
        HGPDM(mapping_noise_floor=bad)


def _mapped(params):
    """The plain model's log precisions that give the floored model's noise at ``params``."""
    out = dict(params)
    for k in ("log_gamma", "log_beta"):
        out[k] = params[k].at[NOISE_ENTRY].set(
            -jnp.log(jnp.exp(-params[k][NOISE_ENTRY]) + FLOOR))
    return out


def test_the_floored_likelihood_is_the_plain_one_at_the_floored_precisions():
    """Numerical reference: every layer's log-likelihood of the floored model at free log
    precision l equals the plain model's at log(1 / (exp(-l) + floor)); only the prior, which
    is on the free part, differs."""
    ds = make_tiny_dataset()
    plain_spec = HGPDM(latent_dim=3, interaction_dim=3).resolved(ds)
    floored_spec = HGPDM(latent_dim=3, interaction_dim=3,
                         mapping_noise_floor=FLOOR).resolved(ds)
    data = prepare_data(plain_spec, ds, fit_codecs(plain_spec, ds))
    params = {k: jnp.asarray(v) for k, v in init_params(plain_spec, data, 0).items()}
    mapped = _mapped(params)
    floored = LogPosterior(floored_spec, data).layer_terms(params, 1e-8)
    plain = LogPosterior(plain_spec, data).layer_terms(mapped, 1e-8)
    for layer in ("bottom", "interaction", "dynamics"):
        np.testing.assert_allclose(float(floored[layer]), float(plain[layer]), rtol=1e-10)
    # and the floor matters at these parameters (the initial noise is near the floor)
    unfloored = LogPosterior(plain_spec, data).layer_terms(params, 1e-8)
    assert abs(float(floored["bottom"]) - float(unfloored["bottom"])) > 1.0


def test_the_sparse_model_sees_the_floor_too():
    ds = make_tiny_dataset()
    spec = HGPDM(latent_dim=3, interaction_dim=3, inducing=12).resolved(ds)
    data = prepare_data(spec, ds, fit_codecs(spec, ds))
    params = init_params(spec, data, 0)
    logp = LogPosterior(spec, data)
    params.update(initial_inducing(np.asarray(params["X"]), np.asarray(params["I"]),
                                   logp.index, spec.inducing))
    params = {k: jnp.asarray(v) for k, v in params.items()}
    floored = LogPosterior(HGPDM(latent_dim=3, interaction_dim=3, inducing=12,
                                 mapping_noise_floor=FLOOR).resolved(ds), data)
    got = floored.layer_terms(params, 1e-8)
    want = logp.layer_terms(_mapped(params), 1e-8)
    for layer in ("bottom", "interaction", "dynamics"):
        np.testing.assert_allclose(float(got[layer]), float(want[layer]), rtol=1e-10)
    assert abs(float(got["bottom"]) - float(logp.layer_terms(params, 1e-8)["bottom"])) > 1.0


@pytest.fixture(scope="module")
def floored_model():
    return HGPDM(latent_dim=3, interaction_dim=3, mapping_noise_floor=FLOOR).fit(
        make_tiny_dataset(), max_iter=80, progress=False)


def test_a_floored_fit_predicts_and_generates_with_the_floored_noise(floored_model):
    from bayesmotion.model.predict import noise_variances

    p = floored_model.params
    free = {k: float(np.exp(-p["log_" + k][NOISE_ENTRY])) for k in ("gamma", "beta")}
    h = floored_model.hyperparameters
    for k in ("gamma", "beta"):
        assert 1 / h[k][NOISE_ENTRY] == pytest.approx(FLOOR + free[k], rel=1e-12)
    noise = noise_variances(floored_model.predictor())
    assert float(noise["Y"]) == pytest.approx(FLOOR + free["gamma"], rel=1e-12)
    assert float(noise["X"]) == pytest.approx(FLOOR + free["beta"], rel=1e-12)
    roll = floored_model.generate(emotion=floored_model.levels["emotion"][0], n_frames=60,
                                  n_samples=2)
    assert np.all(np.isfinite(roll.positions)) and np.all(np.isfinite(roll.samples["Y"]))


def test_a_floored_model_file_round_trips(floored_model, tmp_path):
    path = tmp_path / "floored.npz"
    floored_model.save(path)
    back = load_model(path)
    assert back.spec.mapping_noise_floor == FLOOR
    assert back.log_posterior() == pytest.approx(floored_model.log_posterior(), rel=1e-12)
    for k, v in floored_model.hyperparameters.items():
        np.testing.assert_allclose(back.hyperparameters[k], v, rtol=1e-12)


def test_files_without_the_field_load_as_the_plain_model(floored_model):
    d = floored_model.spec.to_dict()
    del d["mapping_noise_floor"]
    assert HGPDM.from_dict(d).mapping_noise_floor == 0.0


def test_the_posterior_samples_the_floored_model(floored_model):
    """The samplers see the same density: every draw's noise variances are above the floor,
    and each draw's log-density is the floored model's, not the plain one's."""
    import warnings

    import bayesmotion as bm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = bm.sample_posterior(floored_model, n_steps=40, progress=False, burn=10, thin=1)
    c = post.constrained()
    for k in ("gamma", "beta"):
        assert np.all(1 / c[k][..., NOISE_ENTRY] >= FLOOR)
    i = post.n_draws // 2
    lp = float(np.asarray(post.log_prob).reshape(-1)[i])
    assert floored_model.log_posterior(post.params(i)) == pytest.approx(lp, rel=1e-9, abs=1e-6)
    # ... and not the plain model's at the same parameters
    plain = LogPosterior(HGPDM(latent_dim=3, interaction_dim=3).resolved(make_tiny_dataset()),
                         floored_model.data)
    assert abs(float(plain(post.params(i), 1e-8)) - lp) > 1.0

