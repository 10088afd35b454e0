"""Verbs and adverbs: RBF interpolation against SciPy, exactness, time warps, synthesis."""

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

import bayesmotion as bm
from bayesmotion.baselines.rose import (
    emotion_coordinates,
    fit_rbf,
    fit_verb,
    time_denormalise,
    time_normalise,
)


@pytest.fixture
def scattered():
    rng = np.random.default_rng(0)
    return rng.uniform(-1, 1, size=(9, 3)), rng.normal(size=(9, 4)), rng.uniform(-1, 1, (20, 3))


@pytest.mark.parametrize("kernel", ["cubic", "thin_plate", "linear", "gaussian"])
def test_exact_at_the_examples(scattered, kernel):
    X, Y, _ = scattered
    np.testing.assert_allclose(fit_rbf(X, Y, kernel, epsilon=1.3)(X), Y, atol=1e-10)


@pytest.mark.parametrize("kernel", ["cubic", "thin_plate", "linear", "gaussian"])
def test_linear_functions_are_reproduced_everywhere(scattered, kernel):
    X, _, Xq = scattered
    A, c = np.array([[1.0, -2.0], [0.5, 3.0], [-1.0, 0.0]]), np.array([4.0, -1.0])
    f = fit_rbf(X, X @ A + c, kernel, epsilon=0.7)
    np.testing.assert_allclose(f(Xq), Xq @ A + c, atol=1e-9)
    np.testing.assert_allclose(f.c, 0.0, atol=1e-9)            # no radial part needed


@pytest.mark.parametrize("ours, theirs", [("cubic", "cubic"), ("thin_plate", "thin_plate_spline"),
                                          ("linear", "linear"), ("gaussian", "gaussian")])
def test_matches_scipy_rbf_interpolator(scattered, ours, theirs):
    X, Y, Xq = scattered
    ref = RBFInterpolator(X, Y, kernel=theirs, epsilon=1.3, degree=1)(Xq)
    np.testing.assert_allclose(fit_rbf(X, Y, ours, epsilon=1.3)(Xq), ref, rtol=1e-8, atol=1e-8)


def test_hand_solved_one_dimensional_cubic():
    # points 0, 1, 2 with values 0, 1, 0: Φ = [[0,1,8],[1,0,1],[8,1,0]], Π = [1, x].
    # Σc = 0 and Σc·x = 0 force c = (k, -2k, k); the interpolation rows then read
    # x=0: -2k + 8k + a0 + 0·a1 = 6k + a0 = 0; x=1: k + k + a0 + a1 = 2k + a0 + a1 = 1;
    # x=2: 8k - 2k + a0 + 2a1 = 6k + a0 + 2a1 = 0  ->  a1 = 0, a0 = -6k, -4k = 1, k = -1/4.
    f = fit_rbf([[0.0], [1.0], [2.0]], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(f.c[:, 0], [-0.25, 0.5, -0.25], atol=1e-12)
    np.testing.assert_allclose(f.a[:, 0], [1.5, 0.0], atol=1e-12)
    x = 0.5   # y = -0.25·0.125 + 0.5·0.125 - 0.25·3.375 + 1.5
    assert f([x])[0] == pytest.approx(-0.25 * 0.125 + 0.5 * 0.125 - 0.25 * 3.375 + 1.5)


def test_singular_system_is_reported():
    with pytest.raises(bm.BayesmotionError, match="singular"):
        fit_rbf([[0.0, 0.0], [0.0, 0.0], [1.0, 1.0]], [1.0, 2.0, 3.0])
    with pytest.raises(bm.BayesmotionError, match="unknown RBF kernel"):
        fit_rbf([[0.0]], [1.0], kernel="quintic")


def test_emotion_coordinates():
    got = emotion_coordinates(["normal", "happy", "sad", "happy"], ["happy", "sad"], "normal",
                              strength=[1, 1, 0.5, 0.25])
    np.testing.assert_array_equal(got, [[0, 0], [1, 0], [0, 0.5], [0.25, 0]])
    with pytest.raises(bm.BayesmotionError, match="'proud' is neither 'normal'"):
        emotion_coordinates(["proud"], ["happy"], "normal")


def test_time_warps_are_exact_on_piecewise_linear_signals():
    T = 31
    keys = [0, 10, 30]
    ref = [0.0, 0.5, 1.0]
    sig = np.interp(np.arange(T), keys, [0.0, 5.0, 7.0])[:, None]      # kinks only at keys
    norm = time_normalise(sig, 21, keys, ref)
    np.testing.assert_allclose(norm[:, 0], np.interp(np.linspace(0, 1, 21), ref, [0, 5, 7]))
    np.testing.assert_allclose(time_denormalise(norm, T, keys, ref), sig, atol=1e-12)
    lin = np.arange(12.0)[:, None] * [1.0, -2.0]
    np.testing.assert_allclose(time_denormalise(time_normalise(lin, 5), 12), lin, atol=1e-12)


SKELETON = bm.Skeleton(["root", "arm"], [-1, 0], [[0, 0, 0], [1, 0, 0]],
                       [("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation",
                         "Xrotation"), ("Zrotation",)])


def ramp(T, start, slope):
    """Every channel linear in time (so every linear warp is exact)."""
    t = np.arange(T, dtype=float)[:, None]
    return bm.Motion(SKELETON, np.broadcast_to(start + slope * t, (T, 7)), 30.0)


def test_verb_reproduces_examples_and_interpolates_linearly():
    rng = np.random.default_rng(1)
    starts, slopes = rng.normal(size=(3, 7)), rng.normal(size=(3, 7)) * 0.1
    examples = [ramp(T, a, b) for T, a, b in zip((25, 31, 40), starts, slopes, strict=True)]
    points = [[0.0], [0.5], [1.0]]
    verb = fit_verb(examples, points, n_samples=50)
    for m, p in zip(examples, points, strict=True):
        out = verb.synthesize(p)
        assert out.n_frames == m.n_frames
        np.testing.assert_allclose(out.values, m.values, atol=1e-9)
    # same length, channels linear in the adverb: the verb is that linear function
    flat = [ramp(30, s * np.ones(7), 0.01 * (1 + s)) for s in (0.0, 1.0, 3.0)]
    verb = fit_verb(flat, [[0.0], [1.0], [3.0]])
    np.testing.assert_allclose(verb.synthesize([2.0]).values, ramp(30, 2.0, 0.03).values,
                               atol=1e-9)


def test_keyframe_warp_puts_interpolated_keys_in_between():
    # each example has a kink at its key frame; halfway, the kink moves halfway in time
    def kinked(T, key):
        v = np.zeros((T, 7))
        v[:, 6] = np.interp(np.arange(T), [0, key, T - 1], [0.0, 90.0, 0.0])
        return bm.Motion(SKELETON, v, 30.0)
    a, b = kinked(41, 10), kinked(41, 30)
    verb = fit_verb([a, b], [[0.0], [1.0]], n_samples=81, keytimes=[[0, 10, 40], [0, 30, 40]])
    mid = verb.synthesize([0.5])
    assert mid.n_frames == 41 and np.argmax(mid.values[:, 6]) == 20
    assert mid.values[20, 6] == pytest.approx(90.0)
    np.testing.assert_allclose(verb.synthesize([0.0]).values, a.values, atol=1e-9)


def test_rotations_are_unwrapped_and_turn_aligned():
    v1 = np.zeros((20, 7))
    v1[:, 6] = 179.0
    v2 = v1.copy()
    v2[:, 6] = -179.0                                  # the same arm angle as +181
    verb = fit_verb([bm.Motion(SKELETON, v1, 30.0), bm.Motion(SKELETON, v2, 30.0)],
                    [[0.0], [1.0]])
    assert verb.synthesize([0.5]).values[0, 6] == pytest.approx(180.0)


def test_verb_input_errors():
    with pytest.raises(bm.BayesmotionError, match="keytimes must be"):
        fit_verb([ramp(10, 0, 1), ramp(12, 0, 1)], [[0.0], [1.0]], keytimes=[[0, 9], [0, 10]])
    with pytest.raises(bm.BayesmotionError, match="one frame rate"):
        fit_verb([ramp(10, 0, 1), ramp(10, 0, 1).replace(fps=60.0)], [[0.0], [1.0]])
