"""Emotion-style inference: API, accuracy on training clips, online sharpening, errors."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.errors import SkeletonMismatchError

from .conftest import make_tiny_dataset


@pytest.fixture(scope="module")
def tiny_data():
    return make_tiny_dataset()


def test_infers_the_label_of_training_trials(tiny_model, tiny_data):
    labels = tiny_data.labels("emotion")
    for trial in tiny_data.take([labels.index("happy"), labels.index("sad")]):
        ep = bm.infer_emotion(tiny_model, trial, n_steps=300)
        assert ep.label == trial.labels["emotion"]
        assert ep.probabilities.sum() == pytest.approx(1.0)
        lo, hi = ep.interval(0.9)
        assert np.all(lo <= ep.mean) and np.all(ep.mean <= hi)
        assert "\n" not in str(ep) and ep.label in str(ep)
        assert ep.idata.posterior["emotion"].shape[-1] == 2
        assert ep.latents["I"].shape == (trial.n_frames, 3)
        assert np.all(ep.latents["I_sd"] > 0)


def test_clip_from_bvh_files_at_another_frame_rate(tiny_model, tiny_data, tmp_path):
    trial = tiny_data[tiny_data.labels("emotion").index("sad")]
    paths = []
    for a, m in enumerate(trial.actors):
        paths.append(bm.write_bvh(m.resample(30.0), tmp_path / f"a{a}.bvh"))
    ep = bm.infer_emotion(tiny_model, paths, n_steps=300)
    assert ep.info["n_frames"] == pytest.approx(trial.n_frames, abs=1)
    assert ep.label == trial.labels["emotion"]


def test_online_inference_sharpens(tiny_model, tiny_data):
    ents = [e.entropy for e in bm.infer_online(tiny_model, tiny_data[0], start=4, step=4,
                                                n_steps=300)]
    assert len(ents) >= 2
    assert ents[-1] <= ents[0]


def test_mismatched_skeleton_names_missing_joints(tiny_model, tiny_data):
    m = tiny_data[0].actors[0]
    sk = m.skeleton
    names = list(sk.names)
    names[names.index("RightHand")] = "RHand"
    bad = bm.Motion(bm.Skeleton(names, sk.parents, sk.offsets, sk.channels, sk.end_sites),
                    m.values, m.fps)
    with pytest.raises(SkeletonMismatchError, match="RightHand"):
        bm.infer_emotion(tiny_model, [bad, tiny_data[0].actors[1]])


def test_array_clips_are_checked(tiny_model):
    with pytest.raises(bm.BayesmotionError, match="columns"):
        bm.infer_emotion(tiny_model, np.zeros((2, 10, 3)))
    with pytest.raises(bm.BayesmotionError, match="more than"):
        bm.infer_emotion(tiny_model, np.stack([np.asarray(y)[:2] for y in tiny_model.data.Y]))


@pytest.mark.slow
def test_unknown_couple_is_inferred_with_the_emotion(handshake_model, handshake_data):
    # From the prior-mean start alone the projection explained the neutral c1 trial as angry
    # (P = 0.75) with the wrong couple; one start per couple level finds the right optimum.
    ds = handshake_data
    for emotion, couple in [("neutral", "c1"), ("happy", "c2")]:
        trial = ds.filter(emotion=emotion, couple=couple, repetition="0")[0]
        ep = bm.infer_emotion(handshake_model, trial, n_steps=200, latent_uncertainty=False)
        assert ep.couple_levels == tuple(handshake_model.levels["couple"])
        couple_mean = ep.couple_samples.reshape(-1, len(ep.couple_levels)).mean(0)
        assert ep.couple_levels[int(np.argmax(couple_mean))] == couple
        assert ep.label == emotion, str(ep)
