"""Matched transitions (bayesmotion.model.transition): the match, the blend, the splice."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.transition import blend_offsets, match_frame, target_frames


def test_blend_offsets_are_the_quintic_through_the_stated_ends():
    rng = np.random.default_rng(0)
    x0, v0 = rng.normal(size=5), rng.normal(size=5)
    v0[:2] = -np.sign(x0[:2]) * np.abs(v0[:2])  # towards zero: kept
    L = 7
    got = blend_offsets(x0, v0, L)
    assert got.shape == (L, 5)
    # reference: solve for the quintic's six coefficients from its six end conditions
    for d in range(5):
        v = v0[d] if x0[d] * v0[d] <= 0 else 0.0  # away from zero: taken as 0
        M = np.array([[1, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 2, 0, 0, 0],
                      [1, L, L**2, L**3, L**4, L**5], [0, 1, 2 * L, 3 * L**2, 4 * L**3, 5 * L**4],
                      [0, 0, 2, 6 * L, 12 * L**2, 20 * L**3]], dtype=float)
        c = np.linalg.solve(M, [x0[d], v, 0, 0, 0, 0])
        t = np.arange(1, L + 1)
        np.testing.assert_allclose(got[:, d], np.polyval(c[::-1], t), atol=1e-12)
    np.testing.assert_allclose(got[-1], 0.0, atol=1e-12)
    assert blend_offsets(x0, v0, 0).shape == (0, 5)


def _poses(model, r, first, lo, hi):
    return np.stack([np.asarray(model.data.Y[a][first + lo:first + hi])
                     for a in range(model.n_actors)])


def test_match_finds_a_target_training_window_exactly(tiny_model):
    m = tiny_model
    sad = {"emotion": np.array([0.0, 1.0]), "couple": np.array([1.0])}
    frames = target_frames(m, sad)
    assert [m.trials[r].labels["emotion"] for r, _ in frames] == ["sad"] * len(frames)
    r, first = frames[1]
    last = _poses(m, r, first, 3, 6)  # frames 3, 4, 5 of that trial
    assert match_frame(m, last, sad) == (r, 5, 0.0)


def test_matched_rollout_is_the_source_then_the_matched_target_blended(tiny_model):
    m = tiny_model
    o, n, s = m.spec.order, 14, 6
    cut = m.generate(emotion=bm.Transition("happy", "sad", s, 0, match=True), n_frames=n)
    src = m.generate(emotion="happy", n_frames=s)
    np.testing.assert_array_equal(cut.positions[:, :s], src.positions)
    np.testing.assert_array_equal(cut.Y[:, :s], src.Y)
    sad = {"emotion": np.array([0.0, 1.0]), "couple": np.array([1.0])}
    r, j, _ = match_frame(m, src.Y[:, s - o - 1:s], sad)
    I0 = m.latents(r)["I"][j - o + 1:j + 1]
    tgt = m.generate(emotion="sad", n_frames=n - s + o, start=I0)
    np.testing.assert_allclose(cut.Y[:, s:], tgt.Y[:, o:], atol=1e-12)
    np.testing.assert_allclose(cut.I[s:], tgt.I[o:], atol=1e-12)
    assert f"training trial {r}" in cut.start and f"after its frame {j}" in cut.start
    np.testing.assert_array_equal(cut.styles["emotion"][:s], [[1.0, 0.0]] * s)
    np.testing.assert_array_equal(cut.styles["emotion"][s:], [[0.0, 1.0]] * (n - s))
    assert not cut.extrapolated
    beyond = m.generate(emotion=bm.Transition([1.3, -0.3], "sad", s, 0, match=True), n_frames=n)
    assert beyond.extrapolated  # a source off the simplex is said so
    # with a blend the offset decays to nothing over its length, and the switch is smoother
    L = 4
    blend = m.generate(emotion=bm.Transition("happy", "sad", s, L, match=True), n_frames=n)
    np.testing.assert_array_equal(blend.Y[:, :s], src.Y)
    np.testing.assert_allclose(blend.Y[:, s + L:], tgt.Y[:, o + L:], atol=1e-12)
    expected = blend_offsets(src.Y[:, s - 1] - tgt.Y[:, o - 1],
                             (src.Y[:, s - 1] - src.Y[:, s - 2])
                             - (tgt.Y[:, o - 1] - tgt.Y[:, o - 2]), L)
    np.testing.assert_allclose(blend.Y[:, s:s + L] - tgt.Y[:, o:o + L],
                               np.swapaxes(expected, 0, 1), atol=1e-12)
    jump = lambda r: np.abs(np.diff(r.Y[:, s - 2:s + 1], 2, axis=1)).max()  # noqa: E731
    assert jump(blend) < jump(cut)


def test_matched_rollout_samples_are_matched_path_by_path(tiny_model):
    m = tiny_model
    s, n = 6, 12
    r = m.generate(emotion=bm.Transition("happy", "sad", s, 3, match=True), n_frames=n,
                   n_samples=2, seed=4)
    src = m.generate(emotion="happy", n_frames=s, n_samples=2, seed=4)
    assert r.samples["positions"].shape == (2,) + r.positions.shape and r.n_frames == n
    np.testing.assert_array_equal(r.samples["Y"][:, :, :s], src.samples["Y"])
    assert np.all(np.isfinite(r.samples["positions"]))
    # each path continues from the target training frame that matches its own last poses,
    # drawn with its own seed: the sad rollout started at that frame's latents
    o = m.spec.order
    sad = {"emotion": np.eye(2)[m.level_index("emotion", "sad")]}
    slices = m.trial_slices()
    for k in range(2):
        trial, j, _ = match_frame(m, src.samples["Y"][k][:, s - o - 1:s], sad)
        I0 = np.asarray(m.params["I"][slices[trial]])[j - o + 1:j + 1]
        alone = m.generate(emotion="sad", n_frames=n - s + o, n_samples=1, start=I0,
                           seed=4 + 1 + k)
        np.testing.assert_allclose(r.samples["I"][k, s:], alone.samples["I"][0, o:],
                                   rtol=1e-12, atol=1e-12)


def test_a_searched_switch_comes_where_the_poses_match_best(tiny_model):
    """``within``: the switch frame is the one in ``start .. start + within`` whose last poses a
    target training frame matches best (checked against every frame of the window one by
    one), never worse matched than the switch at ``start``; the rollout from there is the
    matched transition that starts at that frame."""
    m = tiny_model
    o, n, s0, W = m.spec.order, 16, 5, 6
    src = m.generate(emotion="happy", n_frames=s0 + W)
    sad = {"emotion": np.array([0.0, 1.0]), "couple": np.array([1.0])}
    dist = {s: match_frame(m, src.Y[:, s - o - 1:s], sad)[2] for s in range(s0, s0 + W + 1)}
    best = min(dist, key=dist.get)
    assert best != s0  # the window has a better match than its first frame
    searched = m.generate(emotion=bm.Transition("happy", "sad", s0, 2, match=True, within=W),
                          n_frames=n)
    switch = int(np.argmax(searched.styles["emotion"][:, 1] == 1.0))
    assert switch == best and dist[best] <= dist[s0]
    assert f"from frame {best} " in searched.start
    at = m.generate(emotion=bm.Transition("happy", "sad", best, 2, match=True), n_frames=n)
    np.testing.assert_allclose(searched.Y, at.Y, atol=1e-12)
    np.testing.assert_allclose(searched.I, at.I, atol=1e-12)
    # within=0 is the switch at start
    zero = m.generate(emotion=bm.Transition("happy", "sad", s0, 2, match=True, within=0),
                      n_frames=n)
    plain = m.generate(emotion=bm.Transition("happy", "sad", s0, 2, match=True), n_frames=n)
    np.testing.assert_array_equal(zero.Y, plain.Y)
    # sampled paths search their own switch frames and stay whole
    r = m.generate(emotion=bm.Transition("happy", "sad", s0, 2, match=True, within=W),
                   n_frames=n, n_samples=2, seed=3)
    assert r.samples["Y"].shape[-2] == n and np.all(np.isfinite(r.samples["positions"]))


@pytest.mark.parametrize("kwargs, words", [
    ({"emotion": bm.Transition("happy", [0.0, 1.0], 6, 2, match=True)}, "level name"),
    ({"emotion": bm.Transition("happy", "sad", 6, 2, match=True, within=6)}, "within must be"),
    ({"emotion": bm.Transition("happy", "sad", 6, 2, match=True, within=-1)}, "within must be"),
    ({"emotion": bm.Transition("happy", "sad", 6, 2, match=True, within=2.0)},
     "within must be"),
    ({"emotion": bm.Transition("happy", "sad", 6, 2, within=3)}, "needs match=True"),
    ({"emotion": bm.Transition("happy", "sad", 2, 2, match=True)}, "start must be"),
    ({"emotion": bm.Transition("happy", "sad", 12, 2, match=True)}, "start must be"),
    ({"emotion": bm.Transition("happy", "sad", 6, -1, match=True)}, "length"),
    ({"emotion": bm.Transition("happy", "sad", 6, 2, match=True),
      "couple": bm.Transition("c1", "c1", 6, 2, match=True)}, "at most one"),
])
def test_bad_matched_transitions_are_refused(tiny_model, kwargs, words):
    with pytest.raises(BayesmotionError, match=words):
        tiny_model.generate(n_frames=12, **kwargs)


def test_the_per_draw_generator_refuses_a_matched_transition(tiny_model):
    """Posterior draws go through ``generate`` itself, which would read the Transition as a
    plain switch: it refuses instead."""
    from bayesmotion.model.generate import generate

    with pytest.raises(BayesmotionError, match="matched Transition"):
        generate(tiny_model, emotion=bm.Transition("happy", "sad", 6, 2, match=True),
                 n_frames=12)
