"""The sparse H-GPDM (HGPDM(inducing=M)): Titsias's bound against the exact GP, layer by layer
and as a whole model, and the sparse model through fit, files, generation, sampling and
inference."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.emotion.ood import training_reference
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.gp import densities, kernels, sparse
from bayesmotion.model import predict
from bayesmotion.model.data import fit_codecs, prepare_data
from bayesmotion.model.fit import init_params
from bayesmotion.model.logpost import LogPosterior

from .conftest import make_tiny_dataset


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def layer(rng):
    N, D = 60, 5
    X = rng.normal(size=(N, 2))
    gamma = jnp.array([1.3, 0.7, 20.0])
    return X, rng.normal(size=(N, D)), gamma, kernels.bottom_kernel(X, X, gamma)


def test_bound_equals_the_exact_log_density_at_the_training_inputs(layer):
    """Q = K_ff and tr(K_ff - Q) = 0 when U = X: the bound is the exact value (to the relative
    jitter of K_uu, 1e-8 of its diagonal)."""
    X, Y, gamma, K = layer
    exact = densities.gaussian_loglik(K + jnp.eye(len(X)) / gamma[2], Y)
    bound = sparse.sparse_loglik(K, K, jnp.diag(K), Y, 1 / gamma[2])
    np.testing.assert_allclose(float(bound), float(exact), rtol=1e-6)


def test_bound_is_below_the_exact_value_and_dtc_above_the_bound(layer):
    """Titsias's bound <= exact for any inducing subset, tighter with more points; DTC drops
    the trace term, so it is the bound plus D / (2 s2) tr(K - Q) >= the bound."""
    X, Y, gamma, K = layer
    exact = float(densities.gaussian_loglik(K + jnp.eye(len(X)) / gamma[2], Y))
    values = []
    for step in (6, 3, 2):
        U = X[::step]
        args = (kernels.bottom_kernel(U, U, gamma), kernels.bottom_kernel(U, X, gamma),
                jnp.diag(K), Y, 1 / gamma[2])
        vfe, dtc = float(sparse.sparse_loglik(*args)), float(sparse.sparse_loglik(
            *args, trace_term=False))
        assert vfe < exact and dtc > vfe
        values.append(vfe)
    assert values[0] < values[1] < values[2]


def test_sparse_predictive_and_held_out_blocks_equal_the_exact_ones_at_the_training_inputs(
        layer, rng):
    X, Y, gamma, K = layer
    Kn = K + jnp.eye(len(X)) / gamma[2]
    parts = sparse.sparse_parts(K, K, Y, 1 / gamma[2])
    W, R = sparse.predictive_weights(parts)
    Xs = rng.normal(size=(7, 2))
    ks = kernels.bottom_kernel(X, Xs, gamma)
    mean = ks.T @ jnp.linalg.solve(Kn, Y)
    var = gamma[0] - jnp.sum(ks * jnp.linalg.solve(Kn, ks), 0)
    np.testing.assert_allclose(ks.T @ W, mean, atol=1e-4 * float(jnp.max(jnp.abs(mean))))
    np.testing.assert_allclose(gamma[0] - jnp.sum((R @ ks) ** 2, 0), var, rtol=1e-5)
    rows = np.arange(10, 20)
    C, KinvY = sparse.held_out_blocks(parts, Y, rows)
    Kinv = jnp.linalg.inv(Kn)
    np.testing.assert_allclose(C, Kinv[np.ix_(rows, rows)], rtol=1e-5,
                               atol=1e-5 * float(jnp.max(jnp.abs(Kinv))))
    np.testing.assert_allclose(KinvY, (Kinv @ Y)[rows], rtol=1e-5,
                               atol=1e-5 * float(jnp.max(jnp.abs(Kinv @ Y))))


def _models(dynamics_linear="stable", optimize_style=False):
    ds = make_tiny_dataset()
    spec = bm.HGPDM(latent_dim=3, interaction_dim=3, dynamics_linear=dynamics_linear)
    spec = spec.resolved(ds)
    data = prepare_data(spec, ds, fit_codecs(spec, ds))
    N = int(data.lengths.sum())
    sspec = bm.HGPDM(latent_dim=3, interaction_dim=3, dynamics_linear=dynamics_linear,
                     inducing=N).resolved(ds)
    params = {k: jnp.asarray(v) for k, v in init_params(sspec, data, 0).items()}
    if optimize_style:  # free style vectors, off their vertices
        params["style:emotion"] = jnp.array([[1.0], [-0.5]])
    exact = {k: v for k, v in params.items() if k not in ("Xu", "Iu", "Du")}
    return LogPosterior(spec, data, dense=True), LogPosterior(sspec, data), exact, params


@pytest.mark.slow
@pytest.mark.parametrize("dynamics_linear,free", [("stable", False), ("kernel", True)])
def test_sparse_model_with_inducing_at_every_frame_equals_the_exact_model(dynamics_linear,
                                                                           free):
    """M = N: every layer's bound, the total and its gradients equal the exact model's, and
    the inducing inputs' gradient is ~0 (the bound is at its maximum over them, touching the
    exact value)."""
    exact, sp, pe, ps = _models(dynamics_linear, free)
    te, ts = exact.layer_terms(pe, 1e-8), sp.layer_terms(ps, 1e-8)
    for k in te:
        np.testing.assert_allclose(float(ts[k]), float(te[k]), rtol=1e-5, err_msg=k)
    ge = jax.grad(lambda q: exact(q, 1e-8))(pe)
    gs = jax.grad(lambda q: sp(q, 1e-8))(ps)
    for k in ge:
        scale = float(jnp.max(jnp.abs(ge[k])))
        np.testing.assert_allclose(gs[k], ge[k], atol=1e-4 * scale, err_msg=k)
    for k, latent in (("Xu", "X"), ("Iu", "I")):
        assert float(jnp.max(jnp.abs(gs[k]))) < 1e-4 * float(jnp.max(jnp.abs(ge[latent])))


def test_sparse_predictor_with_inducing_at_every_frame_predicts_as_the_exact_one(rng):
    exact, sp, pe, ps = _models()
    Pe = predict._condition(exact.spec, exact.data, pe, 1e-8, blocked=False)
    Ps = predict._condition(sp.spec, sp.data, ps, 1e-8)
    styles = [jnp.tile(jnp.eye(2)[:1], (5, 1)), jnp.ones((5, 1))]  # happy, c1
    f = exact.spec.dynamics_factors
    s = [styles[0] if name == "emotion" else styles[1] for name in f]
    lags = jnp.asarray(rng.normal(size=(2, 5, 3)))
    for fn, args in [(predict.predict_dynamics, (lags, s)),
                     (predict.predict_interaction, (lags[0], s)),
                     (predict.predict_bottom, (0, jnp.asarray(rng.normal(size=(5, 3)))))]:
        (me, ve), (ms, vs) = fn(Pe, *args), fn(Ps, *args)
        np.testing.assert_allclose(ms, me, atol=1e-4 * float(jnp.max(jnp.abs(me))))
        np.testing.assert_allclose(vs, ve, rtol=1e-4, atol=1e-6 * float(jnp.max(ve)))
    # the out-of-distribution reference: held-out residuals by Woodbury from the sparse parts
    tof = exact.data.trial_of_frame
    ref_e = training_reference(Pe, tof, 2)
    ref_s = training_reference(Ps, tof, 2, predict.sparse_layers(sp.spec, sp.data, ps, 1e-8))
    for k, v in ref_e.items():
        np.testing.assert_allclose(ref_s[k]["values"], v["values"], rtol=1e-3, err_msg=k)


@pytest.mark.parametrize("bad", [True, 1, 2.5, "10", -3])
def test_inducing_must_be_a_whole_number_of_at_least_two(bad):
    with pytest.raises(BayesmotionError, match="inducing"):
        bm.HGPDM(inducing=bad)
    assert bm.HGPDM(inducing=np.int64(8)).inducing == 8


@pytest.fixture(scope="module")
def sparse_model():
    return bm.HGPDM(latent_dim=3, interaction_dim=3, inducing=20).fit(
        make_tiny_dataset(), max_iter=60, progress=False)


@pytest.mark.slow
def test_a_sparse_model_fits_saves_loads_and_generates(sparse_model, tmp_path):
    m = sparse_model
    assert m.params["Xu"].shape == (2, 20, 3) and m.params["Iu"].shape == (20, 3)
    assert m.params["Du"].shape == (2, 20, 3)
    init = init_params(m.spec, m.data, 0)
    assert not np.allclose(m.params["Iu"], init["Iu"])  # the inducing inputs were fitted
    path = tmp_path / "sparse.npz"
    m.save(path)
    back = bm.load(path)
    assert back.spec.inducing == 20
    assert float(back.log_posterior()) == float(m.log_posterior())
    r = back.generate(emotion="sad", n_frames=40, n_samples=2, seed=1)
    r0 = m.generate(emotion="sad", n_frames=40, n_samples=2, seed=1)
    np.testing.assert_array_equal(r.I, r0.I)
    assert np.all(np.isfinite(r.positions)) and np.all(r.I_var[r.n_observed:] > 0)
    # samples conditioned on their own path, through the inducing inputs' predictive
    rp = m.generate(emotion="sad", n_frames=40, n_samples=2, seed=1, sample_memory=16)
    assert np.all(np.isfinite(rp.samples["positions"]))
    np.testing.assert_array_equal(rp.I, r0.I)
    # a file whose inducing inputs do not have the specification's shape is refused
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(arrays["__meta__"].tobytes().decode())
    for value, match in [(30, "Xu"), (-1, "inducing"), ("20", "inducing")]:
        meta["spec"]["inducing"] = value
        arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        np.savez(tmp_path / "bad.npz", **arrays)
        with pytest.raises(ModelFileError, match=match):
            bm.load(tmp_path / "bad.npz")


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bayesmotion.inference.posterior.ChainTooShortWarning")
def test_sampling_and_inference_on_a_sparse_model_keep_its_inducing_inputs(sparse_model):
    m = sparse_model
    post = bm.sample_posterior(m, n_steps=30, burn=10, thin=1, progress=False, seed=0)
    names = post.target.names
    assert not any(n.startswith(("Xu", "Iu", "Du", "X[", "I[")) for n in names)
    full = post.target.full(post.target.x0)
    for k in ("Xu", "Iu", "Du"):
        np.testing.assert_array_equal(full[k], m.params[k])
    clip = make_tiny_dataset().trials[0]
    res = bm.infer_emotion(m, clip, n_steps=40, seed=0)
    assert res.levels == ("happy", "sad") and abs(res.probabilities.sum() - 1) < 1e-9
    assert res.label == clip.labels["emotion"]  # a training clip reads as its own emotion
    assert np.isfinite(res.info["ood"]["score"]) and not res.out_of_distribution


def test_memory_estimates_count_inducing_columns_not_frames():
    from bayesmotion import validate

    exact = validate.fit_memory(12_000, 3, 12)
    sparse_ = validate.fit_memory(12_000, 3, 12, inducing=200)
    assert sparse_ < exact / 50
    assert validate.fit_memory(100, 3, 12, inducing=500) == validate.fit_memory(100, 3, 12)
    assert validate.sample_memory(54, 100, 26, 12_000, 3, 200) < \
        validate.sample_memory(54, 100, 26, 12_000, 3) / 50


@pytest.mark.slow
def test_cli_fits_a_sparse_model(capsys, tmp_path):
    from bayesmotion.app.cli import main

    out = tmp_path / "m.npz"
    assert main(["fit", "builtin:handshakes", "--fps", "5", "--inducing", "30", "--max-iter",
                 "3", "--latent-dim", "2", "--interaction-dim", "2", "--out", str(out)]) == 0
    m = bm.load(out)
    assert m.spec.inducing == 30 and m.params["Iu"].shape == (30, 2)
    capsys.readouterr()
    assert main(["fit", "builtin:handshakes", "--inducing", "1", "--out", str(out)]) == 2
    assert "--inducing" in capsys.readouterr().err
