"""Periodic models (HGPDM(periodic=True)): each recording's end loops back to its matching
phase in the dynamics' training rows; and the look-ahead of guided rollouts
(FittedHGPDM.generate(lookahead=...))."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.model import generate as G
from bayesmotion.model.data import find_loops
from bayesmotion.model.layers import DynamicsIndex
from bayesmotion.model.predict import noise_variances, predict_dynamics

from .test_model import _rewrite, _with_meta


def _cycle(n, period, phase=0.0, noise=0.0, seed=0):
    t = np.arange(n) + phase
    y = np.stack([np.sin(2 * np.pi * t / period), np.cos(2 * np.pi * t / period),
                  0.5 * np.sin(4 * np.pi * t / period)], 1)
    return y + noise * np.random.default_rng(seed).standard_normal(y.shape)


def test_find_loops_finds_the_phase_of_a_cycle_and_refuses_other_motion():
    """A 12-frame cycle recorded for 40 frames loops back a whole number of cycles; a ramp, a
    trial too short for a 5-frame loop and a noisy non-cycle do not loop."""
    cyc = _cycle(40, 12, noise=0.01)
    ramp = np.linspace(0, 3, 30)[:, None] * np.ones((1, 3))
    short = _cycle(6, 12)
    walk = np.cumsum(np.random.default_rng(1).standard_normal((50, 3)), 0)
    Y = (np.concatenate([cyc, ramp, short, walk]),)
    loops, info = find_loops(Y, np.array([40, 30, 6, 50]), 2)
    assert loops[0] >= 0 and info[0]["period"] % 12 == 0 and info[0]["match"] < 0.2
    assert info[0]["period"] == 40 - 2 - loops[0]
    assert loops[1] == -1 and info[1]["match"] > 1  # a ramp never comes back
    assert loops[2] == -1 and info[2] is None  # no 5-frame loop fits in 6 frames
    assert loops[3] == -1 and info[3]["match"] > 1
    # the two actors' poses are matched together: a second actor out of phase breaks the loop
    Y2 = (cyc, _cycle(40, 7, noise=0.01))
    assert find_loops(Y2, np.array([40]), 2)[1][0]["match"] > 2 * info[0]["match"]


@pytest.mark.parametrize("order", [1, 2])
def test_loop_rows_continue_the_end_as_the_matched_window(order):
    """Trial 0 (frames 0-9) loops to k = 3: its extra rows read the wrapped sequence
    8, 9, 5, 6 (order 2; 9, 4 for order 1); trial 1 does not loop and adds nothing."""
    plain = DynamicsIndex([10, 12], order)
    idx = DynamicsIndex([10, 12], order, np.array([3, -1]))
    assert idx.n_loop_rows == order and plain.n_loop_rows == 0
    np.testing.assert_array_equal(idx.out[:plain.out.size], plain.out)
    if order == 2:
        np.testing.assert_array_equal(idx.out[-2:], [5, 6])
        np.testing.assert_array_equal(idx.lag[0][-2:], [9, 5])
        np.testing.assert_array_equal(idx.lag[1][-2:], [8, 9])
    else:
        np.testing.assert_array_equal(idx.out[-1:], [4])
        np.testing.assert_array_equal(idx.lag[0][-1:], [9])
    with pytest.raises(ValueError, match="no 2 frames"):
        DynamicsIndex([10], 2, np.array([7]))
    with pytest.raises(ValueError, match="one frame per trial"):
        DynamicsIndex([10, 12], 2, np.array([3]))


def test_spec_flag_is_checked_and_stored():
    assert bm.HGPDM(periodic=True).to_dict()["periodic"] is True
    assert bm.HGPDM.from_dict({**bm.HGPDM().to_dict(), "periodic": True}).periodic
    d = bm.HGPDM().to_dict()
    del d["periodic"]  # files written before the option: not periodic
    assert bm.HGPDM.from_dict(d).periodic is False
    with pytest.raises(bm.BayesmotionError, match="periodic must be True or False"):
        bm.HGPDM(periodic="yes")


def _synthesis_loops(root, contents):
    """(clips, loops, find_loops info) of the shared Bandai ``contents`` at the synthesis
    benchmark's settings (10 fps, rest frames, canonical side, periodic): the loops a fit of
    that spec gets, without fitting."""
    from bayesmotion.datasets.bandai import load_bandai
    from bayesmotion.model.data import fit_codecs, prepare_data

    data = load_bandai(root, content=list(contents), fps=10.0)
    spec = bm.HGPDM(rest_frames=True, canonical_side=True, periodic=True,
                    interaction_factors=("emotion",),
                    dynamics_factors=("emotion",)).resolved(data)
    md = prepare_data(spec, data, fit_codecs(spec, data))
    loops, info = find_loops(md.Y, md.lengths, spec.order)
    np.testing.assert_array_equal(md.loops, loops)  # what a fit of this spec gets
    return data, loops, info


def test_fifteen_of_the_sixteen_shared_walks_loop(bandai_root):
    """The loops docs/model.md reports for the synthesis benchmark's walk settings (10 fps, rest
    frames, canonical side): every walk recording's end finds a matching earlier window but
    the left-turning sad walk's, whose best match is 1.37 median steps away."""
    from bayesmotion.datasets.bandai import WALK_CONTENTS

    data, loops, info = _synthesis_loops(bandai_root, WALK_CONTENTS)
    names = [t.name for t in data]
    assert len(names) == 16 and int((loops >= 0).sum()) == 15
    lost = names.index("dataset-1_walk-left_sad_001")
    assert loops[lost] == -1 and info[lost]["match"] == pytest.approx(1.37, abs=0.01)
    assert max(i["match"] for k, i in enumerate(info) if k != lost) < 1.0


def test_the_neutral_run_and_dash_are_too_short_to_loop(bandai_root):
    """docs/model.md: at 10 fps the neutral run (8 frames) and dash (7) are the only run/dash
    recordings whose end matches no earlier window (best matches about 1.4 median steps
    away); every other run and dash loops."""
    data, loops, info = _synthesis_loops(bandai_root, ("run", "dash"))
    lengths = {t.name: t.n_frames for t in data}
    lost = {t.name for t, l in zip(data, loops, strict=True) if l < 0}
    assert lost == {"dataset-1_run_normal_001", "dataset-1_dash_normal_001"}
    assert lengths["dataset-1_run_normal_001"] == 8 and lengths["dataset-1_dash_normal_001"] == 7
    assert all(i["match"] > 1.3 for t, i in zip(data, info, strict=True) if t.name in lost)


@pytest.fixture(scope="module")
def walk_model(bandai_root):
    """A periodic model of the four Bandai 'walk' clips at 10 fps, 150 iterations."""
    from bayesmotion.datasets.bandai import load_bandai

    data = load_bandai(bandai_root, content=["walk"], fps=10.0)
    ds = bm.MotionDataset(tuple(data.trials), {"emotion": data.levels["emotion"]})
    return bm.HGPDM(rest_frames=True, canonical_side=True, periodic=True).fit(
        ds, max_iter=150, progress=False)


def test_periodic_walks_loop_and_their_files_keep_the_loops(walk_model, tmp_path):
    """Real walks loop (each recording's end matches an earlier phase within one frame's
    step); the log-posterior's dynamics has 2 rows per loop; the model file keeps the loops,
    and a file whose loops are missing, out of range or on a non-periodic model is refused."""
    loops = walk_model.data.loops
    assert loops is not None and np.sum(loops >= 0) >= 3
    lp = walk_model.log_posterior_fn
    assert lp.index.n_loop_rows == 2 * int(np.sum(loops >= 0))
    path = tmp_path / "walk.npz"
    walk_model.save(path)
    back = bm.load(path)
    np.testing.assert_array_equal(back.data.loops, loops)
    a = walk_model.generate(emotion="happy", n_frames=30, lookahead=2.0)
    b = back.generate(emotion="happy", n_frames=30, lookahead=2.0)
    np.testing.assert_array_equal(a.angles, b.angles)
    for name, change in [
            ("missing", lambda k, v: None if k == "loops" else v),
            ("range", lambda k, v: np.full_like(v, 10_000) if k == "loops" else v)]:
        bad = _rewrite(path, tmp_path / f"{name}.npz", change)
        with pytest.raises(bm.ModelFileError, match="loop frames"):
            bm.load(bad)
    bad = _with_meta(path, tmp_path / "flag.npz",
                     lambda m: m["spec"].__setitem__("periodic", False))
    with pytest.raises(bm.ModelFileError, match="not periodic"):
        bm.load(bad)
    json.dumps(walk_model.spec.to_dict())


def test_lookahead_step_lowers_its_objective_within_the_trust_region(tiny_model):
    """lookahead_step's value has a lower two-step objective |z - mu|^2 / 2v + w (Q/2) log
    v_next(z) than the predictive mean mu, from lags on and off the training latents, and
    moves at most LOOKAHEAD_MAX_SD predictive sd; weight 0 returns mu."""
    P = tiny_model.predictor()
    noise = noise_variances(P)["I"]
    I = np.asarray(tiny_model.params["I"])
    s = [jnp.asarray(d[0]) for d in P.dyn_style]  # the first row's style, every factor
    Q = I.shape[1]
    rng = np.random.default_rng(0)

    def mean_var(lags):
        m, v = predict_dynamics(P, lags[:, None, :], [x[None] for x in s])
        return m[0], v[0] + noise

    moved = 0
    for shift in (0.0, 0.5, 1.5, 4.0):
        lags = jnp.asarray(I[[11, 10]] + shift * rng.standard_normal((2, Q)))
        mu, v = mean_var(lags)
        def J(z, w, mu=mu, v=v, lags=lags):
            nxt = mean_var(jnp.concatenate([z[None], lags[:-1]]))[1]
            return jnp.sum((z - mu) ** 2) / (2 * v) + w * 0.5 * Q * jnp.log(nxt)

        for w in (1.0, 10.0):
            z, v2 = G.lookahead_step(P, lags, s, s, w, noise)
            assert float(v2) == pytest.approx(float(v))
            assert float(J(z, w)) <= float(J(mu, w)) + 1e-12
            assert float(jnp.linalg.norm(z - mu)) <= G.LOOKAHEAD_MAX_SD * float(jnp.sqrt(v)) \
                * (1 + 1e-9)
            moved += float(jnp.linalg.norm(z - mu)) > 1e-6 * float(jnp.sqrt(v))
        z0, _ = G.lookahead_step(P, lags, s, s, 0.0, noise)
        np.testing.assert_allclose(z0, mu, rtol=0, atol=1e-12)
    assert moved >= 4  # it does move the step


def test_guided_rollouts_and_their_arguments(tiny_model):
    """lookahead=0 is the plain rollout; a guided mean rollout is finite and deterministic,
    its samples differ and are seeded; bad weights and sample_memory are refused."""
    plain = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2, seed=3)
    zero = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2, seed=3,
                               lookahead=0)
    np.testing.assert_array_equal(plain.I, zero.I)
    np.testing.assert_array_equal(plain.samples["I"], zero.samples["I"])
    g1 = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2, seed=3, lookahead=5)
    g2 = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2, seed=3, lookahead=5)
    assert np.all(np.isfinite(g1.I)) and not np.allclose(g1.I, plain.I)
    np.testing.assert_array_equal(g1.samples["I"], g2.samples["I"])
    assert not np.allclose(g1.samples["I"][0], g1.samples["I"][1])
    for bad in (-1.0, float("nan"), True, "10"):
        with pytest.raises(bm.BayesmotionError, match="lookahead must be"):
            tiny_model.generate(n_frames=10, lookahead=bad)
    with pytest.raises(bm.BayesmotionError, match="sample_memory"):
        tiny_model.generate(n_frames=10, n_samples=1, sample_memory=4, lookahead=1.0)
    assert jax.numpy.isfinite(g1.I_var).all()


def test_posterior_generation_passes_the_lookahead(tiny_model):
    """Posterior.generate(lookahead=...) rolls out each draw guided: with one draw, the
    fitted model's guided rollout under that draw's predictor."""
    import warnings

    from bayesmotion.inference.posterior import ChainTooShortWarning
    from bayesmotion.model.generate import generate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)  # 6 steps: only its draws matter
        post = bm.sample_posterior(tiny_model, n_steps=6, progress=False, seed=0)
    r = post.generate(emotion="happy", n_frames=15, n_draws=1, lookahead=4.0)
    one = generate(tiny_model, "happy", None, 15, 0, None, 0, predictor=post.predictor(0),
                   lookahead=4.0)
    np.testing.assert_allclose(r.I, one.I, atol=1e-12)
    plain = post.generate(emotion="happy", n_frames=15, n_draws=1)
    assert not np.allclose(r.I, plain.I)


def test_out_of_distribution_reference_holds_out_the_loop_rows_with_their_recording(
        walk_model):
    """A periodic model's dynamics has the loop rows besides every recording's frames after
    the first o: the reference scores all of them, each held out with its own recording, and
    every value is finite and reproducible. Without the loops the rows and recordings do not
    match, which is refused rather than scored."""
    from bayesmotion.emotion.ood import held_out_stats, training_reference

    P = walk_model.predictor()
    tof = np.asarray(walk_model.data.trial_of_frame)
    o, loops = walk_model.spec.order, walk_model.data.loops
    n_rows = P.dyn.A.shape[0]
    # the rows' recordings built by hand: each recording's frames after its first o, then o
    # loop rows for each looped recording, in recording order
    first = np.zeros(tof.size, bool)
    for s in np.flatnonzero(np.r_[True, tof[1:] != tof[:-1]]):
        first[s:s + o] = True
    groups = np.r_[tof[~first], np.repeat(np.flatnonzero(loops >= 0), o)]
    assert groups.size == n_rows
    z2, nlpd = held_out_stats(P.dyn, groups)
    ref = training_reference(P, tof, o, loops=loops)
    np.testing.assert_array_equal(ref["dynamics"]["values"], z2)
    np.testing.assert_array_equal(ref["dynamics_density"]["values"], nlpd)
    for name in ("dynamics", "dynamics_density"):
        assert ref[name]["values"].shape == (n_rows,)
        assert np.all(np.isfinite(ref[name]["values"]))
    again = training_reference(P, tof, o, loops=loops)
    np.testing.assert_array_equal(again["dynamics_density"]["values"],
                                  ref["dynamics_density"]["values"])
    with pytest.raises(bm.BayesmotionError, match="one recording per training row"):
        training_reference(P, tof, o)
    with pytest.raises(bm.BayesmotionError, match="one recording per training row"):
        held_out_stats(P.dyn, tof[:n_rows - 1])
    with pytest.raises(bm.BayesmotionError, match="loops must hold one frame per trial"):
        training_reference(P, tof, o, loops=loops[:-1])
    with pytest.raises(bm.BayesmotionError, match="each recording's frames together"):
        training_reference(P, np.r_[tof[1:], tof[:1]], o, loops=loops)
