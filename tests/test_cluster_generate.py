"""Posterior-predictive generation on a Dask cluster (Posterior.generate(client=...)): the same
rollouts, samples and variance parts as in this process, the model loaded once per worker,
and bad arguments refused before any task is sent."""

import warnings

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.posterior import ChainTooShortWarning

distributed = pytest.importorskip("dask.distributed", reason="dask.distributed not installed")

SPACES = ("I", "X", "Y", "angles", "positions")


@pytest.fixture(scope="module")
def post(tiny_model):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        return bm.sample_posterior(tiny_model, n_steps=60, progress=False)


def _same(a, b):
    for s in SPACES:
        for f in (s, f"{s}_var"):
            np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-9, atol=1e-10,
                                       err_msg=f)
        for part in ("within", "between"):
            np.testing.assert_allclose(a.variance_parts[s][part], b.variance_parts[s][part],
                                       rtol=1e-9, atol=1e-10, err_msg=f"{s} {part}")
    assert a.samples.keys() == b.samples.keys()
    for k in a.samples:
        np.testing.assert_allclose(a.samples[k], b.samples[k], rtol=1e-9, atol=1e-10,
                                   err_msg=k)
    np.testing.assert_array_equal(a.draws, b.draws)


@pytest.mark.slow
def test_cluster_rollouts_equal_local_ones(post, client):
    kw = {"emotion": "happy", "n_frames": 12, "n_samples": 2, "n_draws": 4, "seed": 7}
    local = post.generate(**kw)
    remote = post.generate(**kw, client=client)
    _same(local, remote)
    assert remote.samples["positions"].shape[0] == 8  # 2 samples for each of 4 draws
    # the model travelled as file bytes and each worker that ran a draw loaded it once
    loaded = client.run(lambda: len(__import__("bayesmotion.model.distributed",
                                               fromlist=["_MODELS"])._MODELS))
    assert set(loaded.values()) <= {0, 1} and sum(loaded.values()) >= 1
    # mean rollouts only (n_samples = 0): the per-draw means are the samples
    _same(post.generate(emotion="sad", n_frames=10, n_draws=3),
          post.generate(emotion="sad", n_frames=10, n_draws=3, client=client))


@pytest.mark.slow
def test_workers_start_and_close_their_own_cluster(post, monkeypatch):
    import dask.distributed as dd

    made = []

    class Recording(dd.LocalCluster):
        def __init__(self, *args, **kwargs):
            made.append({"kwargs": kwargs, "closed": False})
            super().__init__(*args, **kwargs)

        def close(self, *args, **kwargs):
            made[-1]["closed"] = True
            return super().close(*args, **kwargs)

    monkeypatch.setattr(dd, "LocalCluster", Recording)
    kw = {"emotion": "sad", "n_frames": 10, "n_samples": 1, "n_draws": 2, "seed": 1}
    _same(post.generate(**kw), post.generate(**kw, workers=2))
    assert len(made) == 1 and made[0]["closed"]  # one cluster of its own, closed at the end
    assert made[0]["kwargs"]["n_workers"] == 2 and made[0]["kwargs"]["threads_per_worker"] == 1


def test_bad_arguments_are_refused_before_any_task(post, client):
    with pytest.raises(BayesmotionError, match="emotion"):
        post.generate(emotion="bored", n_frames=10, n_draws=2, client=client)
    with pytest.raises(BayesmotionError, match="workers must be an integer"):
        post.generate(emotion="sad", n_frames=10, n_draws=2, workers=0)
