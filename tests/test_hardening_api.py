"""The public API checks its numbers up front: generate, infer_emotion and sample_posterior
refuse wrong types, ranges and non-finite values with a BayesmotionError (not TypeError,
ValueError or OverflowError from deep inside), and refuse requests whose memory estimate
exceeds the memory available (bayesmotion.validate)."""

import os
import warnings

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion import validate
from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.posterior import ChainTooShortWarning
from bayesmotion.model.generate import Transition

GIB = 2**30


# --------------------------------------------------------------------------- generate
GENERATE_CASES = {
    # keyword arguments: words the message must hold (each raised a raw error or a NaN motion)
    "n_frames=2.5": ({"n_frames": 2.5}, "n_frames must be an integer"),
    "n_frames='10'": ({"n_frames": "10"}, "n_frames must be an integer"),
    "n_frames=True": ({"n_frames": True}, "n_frames must be an integer"),
    "n_frames=10.0": ({"n_frames": 10.0}, "n_frames must be an integer"),
    "n_samples=1.5": ({"n_samples": 1.5}, "n_samples must be an integer"),
    "n_samples=-1": ({"n_samples": -1}, "n_samples must be an integer >= 0"),
    "seed=2**70": ({"seed": 2**70}, "seed must be an integer in [0, 2**32)"),
    "seed=-1": ({"seed": -1}, "seed"),
    "seed=1.5": ({"seed": 1.5}, "seed"),
    "emotion=['happy']": ({"emotion": ["happy"]}, "one level name"),
    "emotion=['happy', 'sad']": ({"emotion": ["happy", "sad"]}, "one level name"),
    "emotion=[1e150, -1e150]": ({"emotion": [1e150, -1e150]}, "within +-1e+06"),
    "emotion=[nan, 1]": ({"emotion": [np.nan, 1.0]}, "finite"),
    "emotion=[inf, 0]": ({"emotion": [np.inf, 0.0]}, "finite"),
    "emotion per frame with a NaN": ({"emotion": np.full((12, 2), np.nan)}, "finite"),
    "emotion ragged": ({"emotion": [[0.5], [0.5, 0.5]]}, "emotion"),
    "couple=[1e7]": ({"couple": [1e7]}, "within"),
    "transition to NaN": ({"emotion": Transition("happy", [np.nan, 1.0], 2, 3)}, "finite"),
    "transition start 2.5": ({"emotion": Transition("happy", "sad", 2.5, 3)}, "start"),
}


@pytest.mark.parametrize("name", list(GENERATE_CASES))
def test_generate_refuses_bad_numbers_with_a_clear_error(tiny_model, name):
    kwargs, words = GENERATE_CASES[name]
    with pytest.raises(BayesmotionError) as info:
        tiny_model.generate(**{"emotion": "happy", "n_frames": 12, **kwargs})
    assert words in str(info.value), str(info.value)


def test_numpy_integers_are_the_same_request_as_python_ints(tiny_model):
    a = tiny_model.generate(emotion="sad", n_frames=12, n_samples=2, seed=3)
    b = tiny_model.generate(emotion="sad", n_frames=np.int64(12), n_samples=np.int32(2),
                            seed=np.uint32(3))
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.samples["positions"], b.samples["positions"])


def test_generate_refuses_a_request_larger_than_the_memory(tiny_model, monkeypatch):
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: 16 * GIB)
    with pytest.raises(BayesmotionError, match=r"needs about .* more than the 16 GiB available"):
        tiny_model.generate(emotion="happy", n_frames=5, n_samples=100_000_000)
    with pytest.raises(BayesmotionError, match="10000000 frames"):
        tiny_model.generate(emotion="happy", n_frames=10_000_000)


def test_memory_checks_off_gives_the_same_rollout(tiny_model, monkeypatch):
    """With the guard off a request is served as if there were no guard."""
    want = tiny_model.generate(emotion="happy", n_frames=12, n_samples=2, seed=1)
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: 1024)
    with pytest.raises(BayesmotionError, match="1 KiB available"):
        tiny_model.generate(emotion="happy", n_frames=12, n_samples=2, seed=1)
    with validate.memory_checks(False):
        got = tiny_model.generate(emotion="happy", n_frames=12, n_samples=2, seed=1)
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.samples["angles"], want.samples["angles"])


def test_the_generate_estimate_bounds_the_rollouts_arrays(tiny_model):
    """The estimate (its formula in generate_memory's docstring) is an upper bound of the
    arrays a rollout returns, and grows linearly in frames and in samples + 1."""
    r = tiny_model.generate(emotion="happy", n_frames=20, n_samples=3, seed=0)
    arrays = [v for v in vars(r).values() if isinstance(v, np.ndarray)]
    arrays += list(r.samples.values()) + list(r.sample_var.values())
    held = sum(a.nbytes for a in arrays)
    J = sum(tiny_model.skeleton(a).n_joints for a in range(2))
    est = validate.generate_memory(20, 3, J, 54, 4)
    assert held <= est
    assert validate.generate_memory(40, 3, J, 54, 4) == 2 * est
    assert validate.generate_memory(20, 7, J, 54, 4) == 2 * est


# --------------------------------------------------------------------------- infer_emotion
INFER_CASES = {
    "seed=2**70": ({"seed": 2**70}, "seed"),
    "seed=-3": ({"seed": -3}, "seed"),
    "n_walkers=1.5": ({"n_walkers": 1.5}, "n_walkers"),
    "n_walkers=0": ({"n_walkers": 0}, "n_walkers"),
    "n_steps=-1": ({"n_steps": -1}, "n_steps"),
    "n_steps=2.0": ({"n_steps": 2.0}, "n_steps"),
    "n_draws=0": ({"n_draws": 0}, "n_draws"),
    "couple=[nan]": ({"couple": [np.nan]}, "finite"),
    "couple=['c1']": ({"couple": ["c1"]}, "one level name"),
    "styles a string": ({"styles": "c1"}, "styles must be a dict"),
    "styles value 1e9": ({"styles": {"couple": [1e9]}}, "within"),
    "prior negative": ({"prior": [1.0, -1.0]}, "positive"),
    "prior NaN": ({"prior": [1.0, np.nan]}, "finite"),
    "likelihood_power inf": ({"likelihood_power": np.inf}, "likelihood_power"),
}


@pytest.mark.parametrize("name", list(INFER_CASES))
def test_infer_emotion_refuses_bad_numbers_before_reading_the_clip(tiny_model, monkeypatch,
                                                                  name):
    import bayesmotion.emotion.infer as infer

    def no_work(*a, **k):
        raise AssertionError("the clip was read before the arguments were checked")

    monkeypatch.setattr(infer, "_infer_one", no_work)
    kwargs, words = INFER_CASES[name]
    clip = np.zeros((2, 12, tiny_model.data.Y[0].shape[1]))
    with pytest.raises(BayesmotionError) as info:
        bm.infer_emotion(tiny_model, clip, **kwargs)
    assert words in str(info.value), str(info.value)


def test_infer_emotion_refuses_a_clip_larger_than_the_memory(tiny_model, tmp_path,
                                                            monkeypatch):
    """The clip's frames come from its BVH header (at the model's rate) before it is read."""
    import bayesmotion.emotion.infer as infer

    reached = []
    monkeypatch.setattr(infer, "_infer_one", lambda *a, **k: reached.append(1))
    clips = []
    for a in range(2):
        motion = bm.load_cmu_handshake().actors[a].select(slice(0, 240))
        clips.append(bm.write_bvh(motion, tmp_path / f"a{a}.bvh"))
    T = validate.clip_frames(clips, tiny_model.fps)
    assert T == 10  # 2 s at the model's 5 fps
    need = validate.infer_memory(T, 54, 4, 64, 150)
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: need - 1)
    with pytest.raises(BayesmotionError, match="inferring the emotion of a 10-frame clip"):
        bm.infer_emotion(tiny_model, clips)
    assert not reached
    with validate.memory_checks(False):
        bm.infer_emotion(tiny_model, clips)
    assert reached == [1]
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: need)
    bm.infer_emotion(tiny_model, clips)
    assert reached == [1, 1]


# --------------------------------------------------------------------------- sample_posterior
SAMPLE_CASES = {
    "n_steps=1.5": ({"n_steps": 1.5}, "n_steps must be an integer"),
    "n_steps=-1": ({"n_steps": -1}, "n_steps must be an integer >= 1"),
    "n_walkers=0": ({"n_walkers": 0}, "n_walkers"),
    "n_walkers=8.5": ({"n_walkers": 8.5}, "n_walkers"),
    "burn=-1": ({"burn": -1}, "burn"),
    "burn=2.5": ({"burn": 2.5}, "burn"),
    "thin=0": ({"thin": 0}, "thin"),
    "seed=2**70": ({"seed": 2**70}, "seed"),
    "n_chains=0": ({"n_chains": 0, "method": "nuts"}, "n_chains"),
    "ball=nan": ({"ball": np.nan}, "ball"),
    "ball=0": ({"ball": 0.0}, "ball"),
    "gamma_every=0": ({"gamma_every": 0, "factorise": True}, "gamma_every"),
    "gamma_every=2.5": ({"gamma_every": 2.5, "factorise": True}, "gamma_every"),
    "method='hmc'": ({"method": "hmc"}, "method must be"),
}


@pytest.mark.parametrize("name", list(SAMPLE_CASES))
def test_sample_posterior_refuses_bad_numbers_before_any_work(tiny_model, monkeypatch, name):
    def no_target(*a, **k):
        raise AssertionError("the sampler was set up before the arguments were checked")

    monkeypatch.setattr("bayesmotion.inference.sample.Target", no_target)
    kwargs, words = SAMPLE_CASES[name]
    with pytest.raises(BayesmotionError) as info:
        bm.sample_posterior(tiny_model, **{"n_steps": 100, "progress": False, **kwargs})
    assert words in str(info.value), str(info.value)


def test_a_negative_step_count_is_named_as_such():
    """n_steps=-1 reached the independence move's check, whose message ended '... stored in
    None' without a backend file; it is refused first, as the number it is."""
    with pytest.raises(BayesmotionError) as info:
        bm.sample_posterior(None, n_steps=-1, progress=False)
    assert str(info.value) == "n_steps must be an integer >= 1, got -1"


def test_sample_posterior_memory_guard_and_its_switch(tiny_model, monkeypatch):
    """Refused with the estimate before the conditional MAP; check_memory=False (or
    memory_checks(False)) runs the very chain an unguarded run gives."""
    kw = dict(n_steps=4, burn=1, thin=1, progress=False, seed=2, independence=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        want = bm.sample_posterior(tiny_model, **kw)
        monkeypatch.setattr(validate, "available_memory", lambda *a, **k: 2**20)
        with pytest.raises(BayesmotionError, match=r"sampling 4 steps of \d+ walkers .* 1 MiB"):
            bm.sample_posterior(tiny_model, **kw)
        got = bm.sample_posterior(tiny_model, **kw, check_memory=False)
        with validate.memory_checks(False):
            again = bm.sample_posterior(tiny_model, **kw)
    np.testing.assert_array_equal(got.chains, want.chains)
    np.testing.assert_array_equal(again.chains, want.chains)
    # the chain term of the estimate covers the chain the run returned
    W, S, ndim = want.chains.shape[0], 4, want.chains.shape[-1]
    assert validate.sample_memory(W, S, ndim, 0, 0) >= want.chains.nbytes


# --------------------------------------------------------------------------- the helpers
def test_available_memory_reads_meminfo_then_sysconf(tmp_path):
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24684092 kB\nMemFree:  100 kB\n"
                       "MemAvailable:   20299172 kB\n")
    no_cgroup = str(tmp_path / "none")
    assert validate.available_memory(str(meminfo), no_cgroup) == 20299172 * 1024
    want = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    got = validate.available_memory(str(tmp_path / "absent"), no_cgroup)
    assert abs(got - want) < 0.05 * want  # free pages move between the two reads
    cgroup = tmp_path / "cg"
    cgroup.mkdir()
    (cgroup / "memory.max").write_text(f"{4 * GIB}\n")
    (cgroup / "memory.current").write_text(f"{GIB}\n")
    assert validate.available_memory(str(meminfo), str(cgroup)) == 3 * GIB
    (cgroup / "memory.max").write_text("max\n")
    assert validate.available_memory(str(meminfo), str(cgroup)) == 20299172 * 1024


def test_the_estimates_follow_their_documented_formulas():
    N, L, Q = 680, 4, 18
    assert validate.fit_memory(N, L, Q) == 8 * (8 * L * N * N + 24 * N * Q)
    assert validate.sample_memory(54, 600, 26, N, L) == (8 * 3 * 54 * 600 * 26
                                                         + validate.fit_memory(N, L)
                                                         + 8 * 3 * 27 * L * N * N)
    assert validate.generate_memory(60, 4, 62, N, L) == 8 * 5 * 60 * (12 * 3 * 62 + L * N)
    # samples conditioned on their path add one buffer of W cross-covariance rows each
    assert (validate.generate_memory(60, 4, 62, N, L, sample_memory=16)
            - validate.generate_memory(60, 4, 62, N, L)) == 8 * 4 * 16 * (N + 3 * 16)
    assert (validate.generate_memory(10, 4, 62, N, L, sample_memory=64)
            - validate.generate_memory(10, 4, 62, N, L)) == 8 * 4 * 10 * (N + 3 * 10)
    assert validate.infer_memory(40, N, L, 64, 150, 3) == 8 * (8 * L * 40 * N
                                                               + 3 * 64 * 150 * 3)


def test_bvh_header_agrees_with_the_reader(tmp_path):
    from importlib import resources

    motion = bm.load_cmu_handshake().actors[0]
    path = bm.write_bvh(motion, tmp_path / "a.bvh")
    frames, dt = validate.bvh_header(path)
    assert frames == motion.n_frames and abs(1 / dt - motion.fps) < 1e-6 * motion.fps
    with resources.as_file(resources.files("bayesmotion.datasets") / "builtin"
                           / "18_01.bvh") as p:
        assert validate.bvh_header(p) == (304, pytest.approx(1 / 120, rel=1e-4))
    (tmp_path / "no_motion.bvh").write_text("HIERARCHY\nROOT Hips\n{\n}\n")
    assert validate.bvh_header(tmp_path / "no_motion.bvh") is None
    fifo = tmp_path / "fifo.bvh"
    os.mkfifo(fifo)
    assert validate.bvh_header(fifo) is None  # refused without opening (would block)


def test_clip_frames_match_the_resampled_clip(tiny_model, tmp_path):
    """The count the memory guard uses is within one frame of the clip infer_emotion reads."""
    from bayesmotion.emotion.clip import clip_poses

    h = bm.load_cmu_handshake()
    for n in (37, 120, 241):
        paths = [bm.write_bvh(h.actors[a].select(slice(0, n)), tmp_path / f"{n}_{a}.bvh")
                 for a in range(2)]
        true = clip_poses(tiny_model, paths)[0].shape[0]
        assert abs(validate.clip_frames(paths, tiny_model.fps) - true) <= 1
    assert validate.clip_frames(np.zeros((2, 33, 5)), 5.0) == 33


@pytest.mark.parametrize("value, words", [(2.5, "integer"), (True, "integer"), ("3", "integer"),
                                          (-1, ">= 0"), (11, "in [0, 10]")])
def test_integer_refuses_what_is_not_one(value, words):
    with pytest.raises(BayesmotionError, match=words.replace("[", r"\[").replace("]", r"\]")):
        validate.integer(value, "k", low=0, high=10 if value == 11 else None)
    assert validate.integer(np.int16(7), "k", low=0) == 7
