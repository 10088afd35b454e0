"""JAX's compiled programs are dropped when the process's memory mappings near the kernel's
limit (bayesmotion._config.release_compiled_programs): XLA maps memory for every compiled
program, and a loop that compiles for each new shape crashed at ``vm.max_map_count`` with
"Cannot allocate memory" while gigabytes were free."""

import sys

import jax
import jax.numpy as jnp
import pytest

from bayesmotion import _config


def _compiled_entries(f) -> int:
    return f._cache_size()


def test_counts_this_process_maps(tmp_path):
    got = _config.memory_maps()
    if not sys.platform.startswith("linux"):
        assert got is None
        return
    used, limit = got
    assert 0 < used < limit
    # new mappings count: 20 files' (the kernel does not merge them with their neighbours;
    # other threads may map or unmap a few meanwhile)
    import contextlib
    import mmap

    with contextlib.ExitStack() as stack:
        for k in range(20):
            path = tmp_path / f"page{k}"
            path.write_bytes(b"\0" * mmap.PAGESIZE)
            f = stack.enter_context(open(path, "r+b"))
            stack.enter_context(mmap.mmap(f.fileno(), mmap.PAGESIZE))
        assert _config.memory_maps()[0] >= used + 15


@pytest.mark.parametrize("used, released", [(100, False), (600, True)])
def test_releases_only_above_the_threshold(used, released):
    f = jax.jit(lambda x: x * 2)
    f(jnp.ones(3))
    f(jnp.ones(4))
    assert _compiled_entries(f) == 2
    did = _config.release_compiled_programs(0.5, maps=lambda: (used, 1000))
    assert did is released
    assert _compiled_entries(f) == (0 if released else 2)
    assert float(f(jnp.ones(3))[0]) == 2.0  # compiles again when used next


def test_unknown_maps_release_nothing():
    assert _config.release_compiled_programs(0.5, maps=lambda: None) is False


@pytest.mark.slow
def test_leave_one_out_checks_between_folds(monkeypatch, tiny_model):
    """Every fold starts with the check (a run of many folds of other sizes stays bounded)."""
    import bayesmotion.evaluation.evaluate as ev
    from tests.conftest import make_tiny_dataset

    calls = []
    monkeypatch.setattr(ev, "release_compiled_programs", lambda: calls.append(1) or False)
    ds = make_tiny_dataset()
    ev.leave_one_out(ds, tiny_model, refit_iter=2, n_steps=20, baselines=False,
                     calibrate=False, infer_kwargs={"max_iter": 20})
    assert len(calls) == len(ds)


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bayesmotion.inference.posterior.ChainTooShortWarning")
def test_fits_samplers_and_inference_check_before_they_compile(monkeypatch, tiny_model):
    """A notebook or program that fits, samples and infers in a loop keeps its maps bounded too:
    each of the three entry points checks before it compiles anything."""
    import bayesmotion as bm
    import bayesmotion.emotion.infer as infer
    import bayesmotion.inference.sample as sample
    import bayesmotion.model.fit as fit
    from tests.conftest import make_tiny_dataset

    calls = []
    for module in (fit, sample, infer):
        monkeypatch.setattr(module, "release_compiled_programs",
                            lambda m=module.__name__: calls.append(m) or False)
    ds = make_tiny_dataset()
    bm.HGPDM().fit(ds, max_iter=2, progress=False)
    bm.sample_posterior(tiny_model, n_steps=4, n_walkers=40, progress=False)
    bm.infer_emotion(tiny_model, ds.trials[0], n_steps=4, max_iter=2)
    assert calls == [fit.__name__, sample.__name__, infer.__name__]
