"""benchmarks/fit_convergence.py's pieces: the fit with its noise held is the same density
with the noise entries put back where they belong, and the records read the hyperparameters
as the model defines them."""

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import fit_convergence  # noqa: E402
import run_all  # noqa: E402

from bayesmotion.model.logpost import constrained  # noqa: E402
from bayesmotion.optim.minimize import map_optimize  # noqa: E402


def test_it_is_in_the_suite():
    assert "fit_convergence" in run_all.BENCHMARKS


def test_held_noise_logp_is_the_density_with_the_noise_entries_put_back(tiny_model):
    from bayesmotion.model.logpost import LogPosterior

    logp = LogPosterior(tiny_model.spec, tiny_model.data)
    params = {k: jnp.asarray(v) for k, v in tiny_model.params.items()}
    idx = fit_convergence.NOISE_ENTRY
    held = {k: float(params[k][i]) for k, i in idx.items()}
    free = {k: (jnp.delete(v, idx[k]) if k in idx else v) for k, v in params.items()}
    fn = fit_convergence.held_noise_logp(logp, held)
    assert float(fn(free, 1e-8)) == pytest.approx(float(logp(params, 1e-8)), rel=1e-12)
    # the held entry is the noise precision: moving it changes the density, moving another
    # entry of the same vector through the free dict changes it too
    bumped = {**held, "log_beta": held["log_beta"] + 0.5}
    assert float(fit_convergence.held_noise_logp(logp, bumped)(free, 1e-8)) != \
        pytest.approx(float(logp(params, 1e-8)), rel=1e-9)
    # and it is where the model reads the noise precision: the last log_alpha entry
    h = constrained(params)
    assert np.exp(held["log_alpha"]) == pytest.approx(float(h["alpha"][-1]))
    assert np.exp(held["log_gamma"]) == pytest.approx(float(h["gamma"][2]))


def test_a_held_noise_fit_leaves_the_noise_where_it_was(tiny_model):
    from bayesmotion.model.logpost import LogPosterior

    logp = LogPosterior(tiny_model.spec, tiny_model.data)
    idx = fit_convergence.NOISE_ENTRY
    held = {k: float(tiny_model.params[k][i]) - 1.0 for k, i in idx.items()}
    free = {k: (np.delete(v, idx[k]) if k in idx else v) for k, v in tiny_model.params.items()}
    out, diag = map_optimize(fit_convergence.held_noise_logp(logp, held), free, max_iter=5,
                             progress=False)
    assert set(out) == set(free)
    assert out["log_gamma"].shape == (2,) and out["log_alpha"].shape == \
        (tiny_model.params["log_alpha"].size - 1,)
    assert diag["iterations"] == 5 and diag["objective"] < diag["initial_objective"]


def test_records_give_each_layer_its_noise_and_signal_variance():
    params = {"log_gamma": np.log([2.0, 3.0, 100.0]), "log_beta": np.log([0.5, 4.0, 1e4]),
              "log_alpha": np.log([0.1, 5.0, 6.0, 1e3])}
    h = fit_convergence._hyper(params)
    assert h["bottom"] == {"noise_variance": pytest.approx(0.01), "signal_variance":
                           pytest.approx(2.0), "inverse_lengthscales": [pytest.approx(3.0)]}
    assert h["interaction"]["noise_variance"] == pytest.approx(1e-4)
    assert h["dynamics"]["noise_variance"] == pytest.approx(1e-3)
    assert h["dynamics"]["inverse_lengthscales"] == [pytest.approx(5.0), pytest.approx(6.0)]


def test_the_fall_is_relative_to_the_later_objective():
    trace = [-100.0, -150.0, -198.0, -200.0]
    assert fit_convergence._fall(trace, 2, 4) == pytest.approx(50.0 / 200.0)
    assert fit_convergence._fall([0.5, 0.0], 1, 2) == pytest.approx(0.5)  # magnitude >= 1



def test_a_floored_noise_is_the_density_at_the_floored_precision(tiny_model):
    from bayesmotion.model.logpost import LogPosterior

    logp = LogPosterior(tiny_model.spec, tiny_model.data)
    params = {k: jnp.asarray(v) for k, v in tiny_model.params.items()}
    idx = fit_convergence.NOISE_ENTRY
    zero = {k: 0.0 for k in idx}
    base = float(logp(params, 1e-8))
    assert float(fit_convergence.floored_noise_logp(logp, zero)(params, 1e-8)) == \
        pytest.approx(base, rel=1e-12)
    floors = {"log_gamma": 1e-3, "log_beta": 2e-3, "log_alpha": 5e-3}
    by_hand = dict(params)
    for k, f in floors.items():  # variance 1/p + floor, written out
        v = 1.0 / np.exp(float(params[k][idx[k]])) + f
        by_hand[k] = params[k].at[idx[k]].set(-np.log(v))
    floored = float(fit_convergence.floored_noise_logp(logp, floors)(params, 1e-8))
    assert floored == pytest.approx(float(logp(by_hand, 1e-8)), rel=1e-10)
    assert floored != pytest.approx(base, rel=1e-6)
    # however large the precision entry, the variance the model sees stays above the floor:
    # the density stops changing with it
    huge = {k: (v.at[idx[k]].set(60.0) if k in idx else v) for k, v in params.items()}
    huger = {k: (v.at[idx[k]].set(80.0) if k in idx else v) for k, v in params.items()}
    fn = fit_convergence.floored_noise_logp(logp, floors)
    assert float(fn(huge, 1e-8)) == pytest.approx(float(fn(huger, 1e-8)), rel=1e-12)
