"""Registered rollouts: dynamic time warping against an exhaustive reference, and
``generate(dynamics_style="registered")`` blending the levels' own rollouts."""

import itertools

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.data import MotionDataset, Trial
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.registration import blend_timeline, registration, time_warp
from tests.conftest import make_tiny_dataset, synthetic_walk


def _path_cost(ref, other, match):
    return float(sum(np.sum((ref[i] - other[j]) ** 2) for i, j in enumerate(match)))


def _all_matches(La, Lb):
    """Every warp the step pattern allows, by brute force: any first frame of ``other``; then
    per reference frame a step of +1 or +2 frames ((1, 1), (1, 2)), or of 0 right after a +1
    or at the start (the second reference frame of a (2, 1) step); any last frame."""
    out = []
    for d in itertools.product((0, 1, 2), repeat=La - 1):
        if any(d[k] == 0 and k > 0 and d[k - 1] != 1 for k in range(La - 1)):
            continue
        for j0 in range(Lb):
            m = j0 + np.concatenate([[0], np.cumsum(d)])
            if m[-1] < Lb:
                out.append(m)
    return out


@pytest.mark.parametrize("seed", range(4))
def test_time_warp_finds_the_cheapest_warp_of_the_step_pattern(seed):
    rng = np.random.default_rng(seed)
    La, Lb = 6, 9
    ref, other = rng.normal(size=(La, 2)), rng.normal(size=(Lb, 2))
    match = time_warp(ref, other)
    steps = np.diff(match)
    assert set(steps.tolist()) <= {0, 1, 2}
    assert not np.any((steps[:-1] == 0) & (steps[1:] == 0))  # (2, 1) matches two frames at most
    best = min(_path_cost(ref, other, m) for m in _all_matches(La, Lb))
    # equal up to the tie-break, a 1e-9 relative cost per slope change
    assert _path_cost(ref, other, match) == pytest.approx(best, rel=1e-7)


def test_time_warp_recovers_a_known_warp():
    """The same curve traversed at another pace and starting earlier: every reference frame
    is matched to the frame where the other path passes the same point (to a frame)."""
    def curve(p):
        return np.stack([p, np.sin(3 * p), np.cos(2 * p)], axis=1)

    i = np.arange(60)
    ref = curve(i / 59)
    j = np.arange(110)
    phi = 1.1 * (j / 80) ** 1.2 - 0.05
    truth = 80 * ((i / 59 + 0.05) / 1.1) ** (1 / 1.2)
    match = time_warp(ref, curve(phi))
    assert np.max(np.abs(match - truth)) <= 1.0


def test_blend_timeline_refuses_a_blend_that_runs_backwards():
    warps = [np.arange(10.0), 2.0 * np.arange(10.0)]
    np.testing.assert_allclose(blend_timeline(warps, np.array([0.5, 0.5])), 1.5 * np.arange(10))
    with pytest.raises(BayesmotionError, match="backwards"):
        blend_timeline(warps, np.array([2.5, -1.5]))  # 2.5 - 3 < 0 per frame
    with pytest.raises(BayesmotionError, match="positive sum"):
        blend_timeline(warps, np.array([0.5, -0.5]))


def test_registration_reads_both_paths_at_the_same_point_of_the_movement():
    """Two traversals of one curve, the second 1.5 times as fast and starting earlier on it:
    at every frame of the blend both are read at (nearly) the same point of the curve, and
    the blend's pace is the weighted mean of theirs; identical paths are read frame by
    frame."""
    def curve(p):
        return np.stack([np.sin(2 * np.pi * p), np.cos(2 * np.pi * p), p], axis=1)

    ref = curve(np.arange(200) / 100)                  # 1/100 of the curve per frame
    other = curve((np.arange(300) * 1.5 - 20) / 100)   # 1.5/100 per frame, 20 frames earlier
    times = registration([ref, other], np.array([0.5, 0.5]), 0, 100, 10.0)
    p_ref, p_other = times[0] / 100, (times[1] * 1.5 - 20) / 100
    assert np.max(np.abs(p_ref - p_other)) < 0.015     # within 1.5 reference frames
    pace = np.diff(times[0]).mean()                     # reference frames per blend frame
    assert pace == pytest.approx(1 / (0.5 + 0.5 * 1 / 1.5), rel=0.05)
    same = registration([ref, ref], np.array([0.5, 0.5]), 0, 100, 10.0)
    np.testing.assert_allclose(same[0], np.arange(100.0))
    np.testing.assert_allclose(same[1], np.arange(100.0), atol=1e-9)
    rest = np.ones((40, 3))                            # a body at rest: the diagonal
    still = registration([rest, np.ones((80, 3))], np.array([0.5, 0.5]), 0, 40, 10.0)
    np.testing.assert_allclose(still[1] - still[1][0], np.arange(40.0), atol=1e-9)


def test_registration_of_one_path_reads_it_frame_by_frame():
    path = np.random.default_rng(0).normal(size=(20, 3))
    (times,) = registration([path], np.array([1.0]), 0, 20, 10.0)
    np.testing.assert_array_equal(times, np.arange(20.0))


# --------------------------------------------------------------------------- on a fitted model
FPS = 10.0
STYLES = {"calm": (0.8, 12.0), "brisk": (1.25, 30.0)}  # steps per second, leg swing (degrees)


@pytest.fixture(scope="module")
def walk_model():
    """Two styles of a synthetic walk, two recordings each starting at different phases."""
    base = make_tiny_dataset().trials[0].actors[0]
    trials = []
    for e, (hz, swing) in STYLES.items():
        for r, skip in enumerate((0, 3)):
            w = synthetic_walk(base, FPS, 40 + skip, hz, swing)
            trials.append(Trial((w.select(slice(skip, None)),), {"emotion": e}, f"{e}{r}"))
    data = MotionDataset(tuple(trials), {"emotion": tuple(STYLES)})
    return bm.HGPDM(latent_dim=3, interaction_dim=3).fit(data, max_iter=150, progress=False)


def _swing(rollout) -> float:
    """Peak-to-peak of the left hip's flexion over the rollout's second half."""
    (m,) = rollout.to_motion()
    sk = m.skeleton
    j = sk.index("LeftUpLeg")
    col = sk.channel_offsets[j] + sk.channels[j].index("Xrotation")
    x = m.values[m.n_frames // 2:, col]
    return float(np.ptp(x))


def test_registered_rollout_at_a_level_is_the_plain_rollout(walk_model):
    a = walk_model.generate(emotion="brisk", n_frames=30)
    b = walk_model.generate(emotion="brisk", n_frames=30, dynamics_style="registered")
    np.testing.assert_array_equal(a.Y, b.Y)
    np.testing.assert_array_equal(a.angles, b.angles)


def test_registered_interpolation_is_monotone_and_proportionate(walk_model):
    s = np.linspace(0.0, 1.0, 5)
    swing = np.array([_swing(walk_model.generate(emotion=[1 - v, v], n_frames=60,
                                                 dynamics_style="registered")) for v in s])
    assert np.all(np.diff(swing) > 0), swing
    lin = swing[0] + s * (swing[-1] - swing[0])
    assert np.max(np.abs(swing - lin)) < 0.15 * (swing[-1] - swing[0]), swing
    # the pure styles keep their training swings' order and size (each the swing of both legs
    # about the base pose: 2 x swing degrees peak to peak)
    assert swing[0] == pytest.approx(2 * 12.0, rel=0.3)
    assert swing[-1] == pytest.approx(2 * 30.0, rel=0.3)


def test_registered_blend_keeps_its_swing_in_every_stride(walk_model):
    """The ends swing at different paces; blended without their phases aligned, the legs'
    swings would cancel in some strides. Registered, every stride of the 50/50 rollout swings
    at least 3/4 of the ends' mean swing."""
    ends = [_swing(walk_model.generate(emotion=e, n_frames=60)) for e in ("calm", "brisk")]
    (m,) = walk_model.generate(emotion=[0.5, 0.5], n_frames=60,
                               dynamics_style="registered").to_motion()
    sk = m.skeleton
    j = sk.index("LeftUpLeg")
    x = m.values[:, sk.channel_offsets[j] + sk.channels[j].index("Xrotation")]
    stride = int(np.ceil(FPS / STYLES["calm"][0]))  # the slower style's stride
    windows = [np.ptp(x[a:a + stride]) for a in range(20, len(x) - stride)]
    assert min(windows) >= 0.75 * np.mean(ends), (min(windows), ends)


def test_registered_rollout_blends_samples_and_variances(walk_model):
    r = walk_model.generate(emotion=[0.5, 0.5], n_frames=40, n_samples=3, seed=2,
                            dynamics_style="registered")
    assert r.samples["angles"].shape == (3, 1) + r.angles.shape[1:]
    assert np.all(np.isfinite(r.samples["positions"])) and np.all(np.isfinite(r.positions))
    o = walk_model.spec.order
    n = r.n_observed  # frames read only from every level's observed start frames
    assert 0 <= n <= o
    for var in (r.I_var, r.X_var[0], r.Y_var[0], r.angles_var[0], r.positions_var[0]):
        per_frame = var.reshape(var.shape[0], -1).sum(1)
        assert np.all(per_frame[:n] == 0) and np.all(per_frame[o:] > 0)
    assert "registered blend" in r.start and "calm" in r.start and "brisk" in r.start
    ext = walk_model.generate(emotion=[-0.25, 1.25], n_frames=40, dynamics_style="registered")
    assert ext.extrapolated and np.all(np.isfinite(ext.angles))


def test_registered_rollout_refuses_what_it_cannot_blend(walk_model):
    with pytest.raises(BayesmotionError, match="constant coordinates"):
        walk_model.generate(emotion=bm.Transition("calm", "brisk", start=5, length=5),
                            n_frames=20, dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="trial index or None"):
        walk_model.generate(emotion=[0.5, 0.5], n_frames=20, start="prior",
                            dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="largest weight"):
        walk_model.generate(emotion=[0.2, 0.8], n_frames=20, start=0,
                            dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="backwards"):
        walk_model.generate(emotion=[-3.0, 4.0], n_frames=20, dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="no level any weight"):
        walk_model.generate(emotion=[0.0, 0.0], n_frames=20, dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="at most 4000 frames"):
        walk_model.generate(emotion=[0.5, 0.5], n_frames=4001, dynamics_style="registered")
    with pytest.raises(BayesmotionError, match="at least 2 frames"):
        registration([np.ones((1, 2)), np.ones((5, 2))], np.array([0.5, 0.5]), 0, 1, 10.0)
    with pytest.raises(BayesmotionError, match="dynamics_style must be one of"):
        walk_model.generate(emotion="calm", n_frames=20, dynamics_style="blended")
