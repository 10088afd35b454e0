"""Built-in handshakes: the real CMU trial and the derived emotional set."""

import hashlib
from importlib import resources

import numpy as np
import pytest

from bayesmotion import BayesmotionError, read_bvh
from bayesmotion.data.emotion import CMU_BODY_PARTS, channel_categories, unwrapped
from bayesmotion.data.fk import forward_kinematics
from bayesmotion.datasets import load_cmu_handshake, load_handshakes
from bayesmotion.datasets.handshakes import WINDOW, hand_distance, hand_positions

EMOTIONS = ("neutral", "happy", "angry", "sad")
K_C = round(WINDOW[0] * 20)  # contact frame at 20 fps
BUILTIN = resources.files("bayesmotion.datasets") / "builtin"
SHA256 = {"18_01.bvh": "08a783b18cb63314cefe5ea1d953377d0f02de718de4148067a8febd756bdabf",
          "19_01.bvh": "24770906878edfc86d17417360fa9e22edbf2aa1bc926f19dde1848f0c130304"}


@pytest.fixture(scope="module")
def real():
    return load_cmu_handshake()


@pytest.fixture(scope="module")
def ds():
    return load_handshakes()


@pytest.fixture(scope="module")
def fk_hands(real, ds):
    """Right-hand paths of every actor by the package's (JAX) FK, one call per skeleton.

    Returns (real: list of 2 (T, 3), trials: list of 24 lists of 2 (T, 3)).
    """
    motions = [*real.actors, *(m for t in ds for m in t.actors)]
    out = [None] * len(motions)
    groups = {}
    for i, m in enumerate(motions):
        groups.setdefault(id(m.skeleton), []).append(i)
    for idx in groups.values():
        sk = motions[idx[0]].skeleton
        P = np.asarray(forward_kinematics(sk, np.concatenate([motions[i].values for i in idx])))
        splits = np.cumsum([motions[i].n_frames for i in idx])[:-1]
        for i, p in zip(idx, np.split(P[:, sk.index("RightHand")], splits), strict=True):
            out[i] = p
    return out[:2], [out[2 + 2 * k: 4 + 2 * k] for k in range(len(ds))]


def min_distance(pair):
    return float(np.linalg.norm(pair[0] - pair[1], axis=-1).min())


# ---------------------------------------------------------------------------- the data
def test_builtin_files_are_the_documented_cmu_files():
    for name, digest in SHA256.items():
        assert hashlib.sha256((BUILTIN / name).read_bytes()).hexdigest() == digest
        assert digest in (BUILTIN / "ACKNOWLEDGEMENT.md").read_text()
    assert "NSF EIA-0196217" in (BUILTIN / "ACKNOWLEDGEMENT.md").read_text()


def test_load_cmu_handshake_is_the_shared_recording(real, cmu_files):
    assert real.n_actors == 2 and real.n_frames == 303 and real.fps == 120.0
    assert real.labels == {"source": "cmu"}
    for actor, stem in zip(real.actors, ("18_01", "19_01"), strict=True):
        shared = read_bvh(next(f for f in cmu_files if f.stem == stem))
        np.testing.assert_array_equal(actor.values, shared.values[1:])  # T-pose dropped
        assert actor.skeleton.same_layout(shared.skeleton)
        np.testing.assert_array_equal(actor.skeleton.offsets, shared.skeleton.offsets)


def test_load_cmu_handshake_resampled(real):
    low = load_cmu_handshake(fps=20)
    assert low.fps == 20 and low.n_frames == 51
    np.testing.assert_array_equal(low.actors[1].values, real.actors[1].values[::6])


def test_hand_positions_equal_the_package_fk(real, fk_hands):
    for actor, ref in zip(real.actors, fk_hands[0], strict=True):
        np.testing.assert_allclose(hand_positions(actor), ref, atol=1e-10)


def test_real_hands_meet_around_frame_123(real, fk_hands):
    d = np.linalg.norm(fk_hands[0][0] - fk_hands[0][1], axis=-1)
    assert 118 <= int(np.argmin(d)) <= 128  # SOURCE.md: frames 120-125 of the file
    assert d.min() == pytest.approx(6.6553, abs=1e-3)  # CMU units (~37 cm between wrists)
    np.testing.assert_allclose(hand_distance(real), d, atol=1e-10)


# ---------------------------------------------------------------------------- the set
def test_layout(ds):
    assert len(ds) == 24 and ds.n_actors == 2 and ds.fps == 20.0
    assert ds.levels == {"emotion": EMOTIONS, "couple": ("c1", "c2"),
                         "repetition": ("0", "1", "2")}
    cells = {(t.labels["emotion"], t.labels["couple"], t.labels["repetition"]) for t in ds}
    assert len(cells) == 24
    assert {t.n_frames for t in ds} == {34}
    assert all(np.isfinite(m.values).all() for t in ds for m in t.actors)


def test_couple_two_swaps_the_roles(ds, real):
    c1, c2 = ds.filter(couple="c1")[0], ds.filter(couple="c2")[0]
    for k in range(2):
        assert c1.actors[k].skeleton is real.actors[k].skeleton
        assert c2.actors[k].skeleton is real.actors[1 - k].skeleton


def test_hands_meet_in_every_trial(fk_hands):
    d_real = min_distance(fk_hands[0])
    ratios = np.array([min_distance(pair) / d_real for pair in fk_hands[1]])
    assert np.all(np.abs(ratios - 1) < 0.2), ratios


def test_reach_compensation_moves_the_actors_little(ds, real):
    """At contact (frame K_C at 20 fps) each root is within 2.5 units (14 cm) of the recording."""
    k = int(np.argmin(hand_distance(real)))
    for t in ds:
        subjects = (0, 1) if t.labels["couple"] == "c1" else (1, 0)
        for m, s in zip(t.actors, subjects, strict=True):
            shift = m.values[K_C, [0, 2]] - real.actors[s].values[k, [0, 2]]
            assert np.linalg.norm(shift) < 2.5, t.name
            # height kept: no vertical shift, and the bounce of happy is zero at contact
            assert m.values[K_C, 1] == pytest.approx(real.actors[s].values[k, 1], abs=1e-9)


def test_actors_approach_then_part(ds):
    for t in ds:
        xz = [m.values[:, [0, 2]] for m in t.actors]
        gap = np.linalg.norm(xz[0] - xz[1], axis=-1)
        assert gap[0] > gap[K_C] + 5 and gap[-1] > gap[K_C] + 3, t.name
        # the warped clock stays inside the recording: the roots still move at both ends
        assert np.abs(np.diff(xz[0][:2], axis=0)).sum() > 0.05
        assert np.abs(np.diff(xz[0][-2:], axis=0)).sum() > 0.05


def test_window_ends_before_the_root_gimbal_lock(ds):
    """Subject 18's Hips Z/X angles jump by ~70 deg per frame when he turns away; not here."""
    for t in ds:
        for m in t.actors:
            assert np.abs(np.diff(m.values[:, 3:6], axis=0)).max() < 20, t.name


def test_seed_determinism():
    a, b, c = load_handshakes(seed=3), load_handshakes(seed=3), load_handshakes(seed=4)
    for ta, tb, tc in zip(a, b, c, strict=True):
        for ma, mb, mc in zip(ta.actors, tb.actors, tc.actors, strict=True):
            assert np.array_equal(ma.values, mb.values)
            assert not np.allclose(ma.values, mc.values)


def arm_stats(m):
    """Mean angular speed (deg/s) and mean std about the mean (deg) of the arm channels."""
    v = unwrapped(m)[:, channel_categories(m.skeleton, CMU_BODY_PARTS) == "arms"]
    return np.abs(np.diff(v, axis=0)).mean() * m.fps, v.std(axis=0).mean()


@pytest.mark.parametrize("couple", ["c1", "c2"])
def test_emotions_change_speed_and_amplitude_as_documented(ds, couple):
    speed, amp = {}, {}
    for e in EMOTIONS:
        s = np.array([arm_stats(m) for t in ds.filter(emotion=e, couple=couple)
                      for m in t.actors])
        speed[e], amp[e] = s.mean(axis=0)
    assert min(speed["happy"], speed["angry"]) > 1.1 * speed["neutral"] > 1.1 * speed["sad"]
    assert amp["angry"] > amp["happy"] > amp["neutral"] > amp["sad"]


def test_full_frame_rate():
    ds = load_handshakes(fps=120, n_repetitions=1)
    assert len(ds) == 8 and {t.n_frames for t in ds} == {199}
    d_real = hand_distance(load_cmu_handshake()).min()
    for t in ds:
        assert abs(hand_distance(t).min() / d_real - 1) < 0.2


def test_full_window_length_follows_speed():
    ds = load_handshakes(n_repetitions=1, window="full")
    n = {t.labels["emotion"]: t.n_frames for t in ds.filter(couple="c1")}
    assert n["sad"] > n["neutral"] > n["happy"] > n["angry"]
    d_real = hand_distance(load_cmu_handshake()).min()
    assert all(abs(hand_distance(t).min() / d_real - 1) < 0.2 for t in ds)


@pytest.mark.parametrize("kwargs, match", [
    ({"seed": -1}, "seed"), ({"seed": 1.5}, "seed"), ({"fps": 0}, "fps"),
    ({"n_repetitions": 0}, "n_repetitions"), ({"window": "hug"}, "window")])
def test_bad_arguments(kwargs, match):
    with pytest.raises(BayesmotionError, match=match):
        load_handshakes(**kwargs)


def test_every_trial_ends_in_motion(ds):
    """What docs/model.md says of the built-in set: 24 windows of 34 frames, each actor's limb
    motion over the last 3 frames 0.77-1.33 times its trial's mean (median 0.89), so no
    recording shows a handshake at rest."""
    ratios = []
    for trial in ds:
        assert trial.n_frames == 34
        for actor in trial.actors:
            d = np.diff(actor.values[:, 6:], axis=0)  # the rotation channels below the root
            speed = np.abs((d + 180.0) % 360.0 - 180.0).mean(-1)
            ratios.append(speed[-3:].mean() / speed.mean())
    assert len(ds) == 24 and len(ratios) == 48
    assert min(ratios) == pytest.approx(0.77, abs=0.005)
    assert max(ratios) == pytest.approx(1.33, abs=0.005)
    assert np.median(ratios) == pytest.approx(0.89, abs=0.005)
