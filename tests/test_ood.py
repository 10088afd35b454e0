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
    held_out_stats,
    held_out_z2,
    in_distribution_weight,
    recording_distance,
    recording_reference,
    recording_summary,
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
    # the density: log N(r | 0, v) per column, v the held-out predictive variance
    z2, nlpd = held_out_stats(_fit(K, Y), groups)
    var = np.empty(M)
    for g in range(4):
        out, keep = groups == g, groups != g
        k = K[np.ix_(keep, out)]
        var[out] = np.diag(K[np.ix_(out, out)] - k.T @ np.linalg.solve(K[np.ix_(keep, keep)], k))
    np.testing.assert_allclose(nlpd, 0.5 * (want + np.log(2 * np.pi * var)), rtol=1e-8)


def _walk(rng, T=40, amp=1.0, freq=0.3):
    t = np.arange(T)[:, None]
    return amp * np.sin(freq * t + rng.uniform(0, 6, (1, 4))) + rng.normal(0, 0.05, (T, 4))


def test_recording_distance_is_conformal_and_flags_another_action():
    rng = np.random.default_rng(0)
    train = [_walk(rng, amp=rng.uniform(0.9, 1.1)) for _ in range(12)]
    Y = (np.concatenate(train),)
    tof = np.repeat(np.arange(12), 40)
    ref = recording_reference(Y, tof)
    # each training recording's nearest other, by hand
    S = np.stack([recording_summary([y]) for y in train])
    Z = S / S.std(0)
    D = np.sqrt(((Z[:, None] - Z[None]) ** 2).mean(-1))
    np.fill_diagonal(D, np.inf)
    np.testing.assert_allclose(ref["held_out_nearest"], D.min(1))
    assert ref["largest"] == pytest.approx(D.min(1).max())
    same = recording_distance(ref, [_walk(rng)])
    assert same["ratio"] < 1.5 and not same["beyond"]
    assert same["p_value"] == pytest.approx(
        (1 + np.sum(ref["held_out_nearest"] >= same["nearest_distance"])) / 13)
    # a bow: a slow single excursion, not a gait
    t = np.linspace(0, 1, 40)[:, None]
    bow = np.concatenate([np.sin(np.pi * t) * 2.0, np.zeros((40, 3))], axis=1)
    other = recording_distance(ref, [bow])
    assert other["beyond"] and other["ratio"] > 2 and other["p_value"] == pytest.approx(1 / 13)
    assert recording_reference(Y, np.repeat([0, 1], 240)) is None  # too few recordings


def test_in_distribution_weight_takes_the_worse_of_frames_and_recording():
    ref = {"bottom": _reference(1.0, 3.0), "dynamics": _reference(0.5, 2.0)}
    frames = {"bottom": np.r_[np.ones(9), 10.0], "dynamics": np.ones(10)}
    a = assess(ref, frames)
    assert in_distribution_weight(a) == pytest.approx(0.9 / 0.99)
    rec = {"ratio": 1.75, "beyond": True}
    b = assess(ref, frames, rec)
    assert b["out_of_distribution"] and b["score"] == 2.0  # the dynamics ratio is larger
    assert in_distribution_weight(b) == pytest.approx(0.25)
    assert in_distribution_weight(assess(ref, frames, {"ratio": 0.6, "beyond": False})) == \
        pytest.approx(0.9 / 0.99)


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
    with pytest.warns(OutOfDistributionWarning, match="outside the training data") as caught:
        post = bm.infer_emotion(tiny_model, shaken, n_steps=60)
    # the warning points at the caller's line (this file), not into the package
    assert {w.filename for w in caught} == {__file__}
    assert post.out_of_distribution and "OUT OF DISTRIBUTION" in str(post)
    assert post.info["ood"]["score"] > 3 * own.info["ood"]["score"]
    # a spread-out answer: the evidence is shrunk towards the prior
    assert post.info["in_distribution_weight"] < 0.5 < own.info["in_distribution_weight"]
    assert post.entropy > own.entropy + 0.2
    # a motionless clip (the first frame held): the dynamics layer cannot explain it
    still = bm.Trial(tuple(bm.Motion(a.skeleton, np.repeat(a.values[:1], a.n_frames, 0), a.fps,
                                     a.name) for a in trial.actors), dict(trial.labels), "still")
    with pytest.warns(OutOfDistributionWarning):
        post = bm.infer_emotion(tiny_model, still, n_steps=60)
    d = post.info["ood"]["dynamics"]
    assert post.out_of_distribution and d["median_z2"] > d["threshold"]


def test_short_clips_are_compared_with_training_stretches_of_their_length():
    """An online prefix of an ordinary recording: against whole recordings its summary (a
    few frames' mean and sd) looks foreign; against 10-frame stretches it does not."""
    rng = np.random.default_rng(3)
    train = [_walk(rng, T=60, amp=rng.uniform(0.9, 1.1), freq=0.2) for _ in range(10)]
    Y = (np.concatenate(train),)
    tof = np.repeat(np.arange(10), 60)
    prefix = [_walk(rng, T=60, freq=0.2)[:10]]
    whole = recording_distance(recording_reference(Y, tof), prefix)
    windows = recording_reference(Y, tof, window=10)
    assert windows["summaries"].shape[0] == 60  # six 10-frame stretches per recording
    # a stretch is held out with its whole recording
    assert np.all(np.isfinite(windows["held_out_nearest"]))
    short = recording_distance(windows, prefix)
    assert whole["beyond"] and not short["beyond"]
    assert 0 <= short["nearest_recording"] < 10


def test_non_finite_clips_are_out_of_distribution():
    ref = {"bottom": _reference(1.0, 3.0), "dynamics": _reference(0.5, 2.0)}
    a = assess(ref, {"bottom": np.array([np.nan, np.nan, 1.0]), "dynamics": np.ones(3)})
    assert a["out_of_distribution"]
    rng = np.random.default_rng(0)
    Y = (np.concatenate([_walk(rng) for _ in range(4)]),)
    rec = recording_distance(recording_reference(Y, np.repeat(np.arange(4), 40)),
                             [np.full((40, 4), np.nan)])
    assert rec["beyond"] and in_distribution_weight(assess(ref, {"bottom": np.ones(3),
                                                                 "dynamics": np.ones(3)},
                                                           rec)) == 0.0


def test_reference_of_a_model_without_loops_scores_every_frame_after_the_first_o(tiny_model):
    """Without loops the dynamics' rows are every recording's frames after its first o, each
    held out with its recording: the reference equals held_out_stats on that grouping."""
    from bayesmotion.emotion.ood import training_reference

    P = tiny_model.predictor()
    tof = np.asarray(tiny_model.data.trial_of_frame)
    o = tiny_model.spec.order
    starts = np.flatnonzero(np.r_[True, tof[1:] != tof[:-1]])
    first = np.zeros(tof.size, bool)
    for k in range(o):
        first[starts + k] = True
    z2, nlpd = held_out_stats(P.dyn, tof[~first])
    ref = training_reference(P, tof, o)
    np.testing.assert_array_equal(ref["dynamics"]["values"], z2)
    np.testing.assert_array_equal(ref["dynamics_density"]["values"], nlpd)
