"""Out-of-distribution scores: the held-out-recording residuals against a brute-force refit, the
flag's rule, and infer_emotion flagging clips unlike its training data."""

import warnings

import jax.numpy as jnp
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.emotion.ood import (
    OutOfDistributionWarning,
    assess,
    held_out_z2,
)
from bayesmotion.model.predict import LayerFit, pack_lower

from .conftest import make_tiny_dataset


def _fit(K, Y):
    L = np.linalg.cholesky(K)
    Linv = np.linalg.inv(L)
    return LayerFit(pack_lower(jnp.asarray(Linv)), jnp.asarray(np.linalg.solve(K, Y)))


def test_held_out_z2_equals_refitting_without_each_recording():
    rng = np.random.default_rng(0)
    M, D = 12, 3
    x = rng.normal(size=(M, 1))
    K = np.exp(-0.5 * (x - x.T) ** 2 / 0.7) + 0.05 * np.eye(M)  # noisy Gram matrix
    Y = rng.normal(size=(M, D))
    groups = np.repeat([0, 1, 2, 3], 3)
    want = np.empty(M)
    for g in range(4):
        out, keep = groups == g, groups != g
        Kk = K[np.ix_(keep, keep)]
        k = K[np.ix_(keep, out)]
        mean = k.T @ np.linalg.solve(Kk, Y[keep])
        cov = K[np.ix_(out, out)] - k.T @ np.linalg.solve(Kk, k)  # noise included
        want[out] = np.mean((Y[out] - mean) ** 2, axis=1) / np.diag(cov)
    np.testing.assert_allclose(held_out_z2(_fit(K, Y), groups), want, rtol=1e-8)


def _reference(median, threshold):
    return {"median": median, "threshold": threshold, "z2": np.array([])}


def test_flag_needs_the_median_frame_beyond_the_threshold_in_either_layer():
    ref = {"bottom": _reference(1.0, 3.0), "dynamics": _reference(0.5, 2.0)}
    inside = assess(ref, {"bottom": np.array([0.5, 1.0, 10.0]), "dynamics": np.ones(3)})
    assert not inside["out_of_distribution"]
    assert inside["bottom"]["beyond"] == pytest.approx(1 / 3)
    bottom = assess(ref, {"bottom": np.array([4.0, 5.0, 1.0]), "dynamics": np.ones(3)})
    assert bottom["out_of_distribution"] and bottom["bottom"]["ratio"] == pytest.approx(4.0)
    dyn = assess(ref, {"bottom": np.ones(3), "dynamics": np.array([3.0, 3.0, 0.0])})
    assert dyn["out_of_distribution"] and dyn["score"] == pytest.approx(6.0)


@pytest.mark.slow
def test_training_clips_pass_and_foreign_motion_is_flagged(tiny_model):
    trial = make_tiny_dataset().trials[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", OutOfDistributionWarning)  # a training clip: no warning
        own = bm.infer_emotion(tiny_model, trial, n_steps=60)
    assert not own.out_of_distribution and "OUT OF DISTRIBUTION" not in str(own)
    ood = own.info["ood"]
    assert ood["bottom"]["median_z2"] < ood["bottom"]["threshold"]
    # the same skeletons with every channel shaken by 30 degrees: poses no training frame has
    rng = np.random.default_rng(0)
    shaken = bm.Trial(tuple(bm.Motion(a.skeleton, a.values + rng.normal(0, 30, a.values.shape),
                                      a.fps, a.name) for a in trial.actors), dict(trial.labels),
                      "shaken")
    with pytest.warns(OutOfDistributionWarning, match="outside the training data"):
        post = bm.infer_emotion(tiny_model, shaken, n_steps=60)
    assert post.out_of_distribution and "OUT OF DISTRIBUTION" in str(post)
    assert post.info["ood"]["score"] > 3 * own.info["ood"]["score"]
    # a motionless clip (the first frame held): the dynamics layer cannot explain it
    still = bm.Trial(tuple(bm.Motion(a.skeleton, np.repeat(a.values[:1], a.n_frames, 0), a.fps,
                                     a.name) for a in trial.actors), dict(trial.labels), "still")
    with pytest.warns(OutOfDistributionWarning):
        post = bm.infer_emotion(tiny_model, still, n_steps=60)
    d = post.info["ood"]["dynamics"]
    assert post.out_of_distribution and d["median_z2"] > d["threshold"]
