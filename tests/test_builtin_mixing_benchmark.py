"""benchmarks/builtin_mixing.py's pieces, without sampling: its chains are keyed on the model,
the variant and the default sampler, and a kept chain resumes into the same file."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import builtin_mixing  # noqa: E402
import posterior_convergence  # noqa: E402
import run_all  # noqa: E402
import style_shear  # noqa: E402


def test_it_is_in_the_suite():
    assert "builtin_mixing" in run_all.BENCHMARKS
    assert set(builtin_mixing.VARIANTS) <= set(style_shear.VARIANTS)


def test_the_chain_key_changes_with_the_model_the_variant_and_the_sampler(tiny_model,
                                                                          monkeypatch):
    key = builtin_mixing.chain_key(tiny_model, "default")
    assert key == builtin_mixing.chain_key(tiny_model, "default")
    assert key != builtin_mixing.chain_key(tiny_model, "previous")
    moved = tiny_model.with_params({**tiny_model.params,
                                    "log_beta": np.asarray(tiny_model.params["log_beta"]) + 1e-9})
    assert key != builtin_mixing.chain_key(moved, "default")
    monkeypatch.setattr(posterior_convergence, "SAMPLER_VERSION", "another sampler")
    assert key != builtin_mixing.chain_key(tiny_model, "default")


@pytest.mark.slow
def test_a_kept_chain_is_resumed_not_redrawn(tiny_model, tmp_path):
    import emcee

    path = str(tmp_path / "chain.h5")
    first = style_shear.sample(tiny_model, 160, 0, "previous", path)
    chain = emcee.backends.HDFBackend(path, read_only=True, name="mcmc").get_chain()
    again = style_shear.sample(tiny_model, 160, 0, "previous", path)
    assert np.array_equal(chain, emcee.backends.HDFBackend(path, read_only=True,
                                                           name="mcmc").get_chain())
    assert again["min_ess_bulk"] == first["min_ess_bulk"]
    assert chain.shape[0] == 160
