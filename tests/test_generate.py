"""Generation: rollouts, predictive variance, continuous style, BVH export."""

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.errors import BayesmotionError


def test_variance_is_zero_at_the_observed_start_and_grows(tiny_model):
    r = tiny_model.generate(emotion="happy", n_frames=30, n_samples=64, seed=1)
    o = tiny_model.spec.order
    assert np.all(r.I_var[:o] == 0)
    for space in ("X", "Y", "angles", "positions"):  # (A, T, ...): time is axis 1
        var = getattr(r, f"{space}_var")
        assert np.all(var[:, :o] == 0)
        per_frame = var[:, o:].reshape(var.shape[0], var.shape[1] - o, -1).sum((0, 2))
        assert np.all(per_frame > 0)  # every free frame is uncertain, in every space
        assert per_frame[-5:].mean() > per_frame[0]  # and more so along the rollout
        assert np.all(np.isfinite(getattr(r, space)))
    assert np.all(r.I_var[o:] > 0)
    spread = r.sample_var["I"].sum(-1)
    assert np.all(spread[:o] < 1e-20)  # identical start frames (zero up to rounding)
    assert spread[-5:].mean() > spread[o]  # the samples' spread grows along the rollout


def test_sampled_one_step_matches_the_analytic_predictive(tiny_model):
    o = tiny_model.spec.order
    n = 4000
    r = tiny_model.generate(emotion="sad", n_frames=o + 1, n_samples=n, seed=3)
    x = r.samples["I"][:, o]  # (n, Q)
    mean, var = r.I[o], r.I_var[o]
    se = np.sqrt(var / n)
    assert np.all(np.abs(x.mean(0) - mean) < 4.5 * se)
    ratio = x.var(0) / var
    assert np.all(np.abs(ratio - 1) < 4.5 * np.sqrt(2 / n))


def test_bvh_export_reimports_exactly(tiny_model, tmp_path):
    r = tiny_model.generate(emotion="happy", n_frames=20, n_samples=2)
    for sample in (None, 1):
        paths = r.write_bvh(tmp_path, sample=sample)
        for a, p in enumerate(paths):
            back = bm.read_bvh(p)
            np.testing.assert_array_equal(back.values, r.to_motion(sample)[a].values)
            assert back.fps == r.fps


def test_continuous_style_interpolates_and_flags_extrapolation(tiny_model):
    inside = tiny_model.generate(emotion=[0.5, 0.5], n_frames=10)
    outside = tiny_model.generate(emotion=[1.3, -0.3], n_frames=10)
    assert not inside.extrapolated and outside.extrapolated
    a = tiny_model.generate(emotion="happy", n_frames=10).Y
    b = tiny_model.generate(emotion="sad", n_frames=10).Y
    assert not np.allclose(inside.Y, a) and not np.allclose(inside.Y, b)
    np.testing.assert_allclose(inside.styles["emotion"], [[0.5, 0.5]] * 10)
    np.testing.assert_allclose(outside.styles["emotion"], [[1.3, -0.3]] * 10)
    # the style kernel is linear in each style vector, so from one start the first generated
    # step's mean at any coordinates is that mix of the levels' means, inside the simplex
    # and out of it
    o = tiny_model.spec.order
    start = np.asarray(tiny_model.params["I"])[:o]
    first = {e: tiny_model.generate(emotion=e, n_frames=o + 1, start=start).I[o]
             for e in ("happy", "sad")}
    for w in (0.5, 1.3):
        mix = tiny_model.generate(emotion=[w, 1 - w], n_frames=o + 1, start=start).I[o]
        np.testing.assert_allclose(mix, w * first["happy"] + (1 - w) * first["sad"],
                                   rtol=1e-9, atol=1e-12)
    tr = tiny_model.generate(emotion=bm.Transition("happy", "sad", start=3, length=4),
                             n_frames=10)
    s = tr.styles["emotion"]
    np.testing.assert_allclose(s[:3], [[1, 0]] * 3)
    np.testing.assert_allclose(s[7:], [[0, 1]] * 3)
    assert np.all(np.diff(s[:, 1]) >= 0)



def test_nearest_dynamics_follows_the_nearest_level_and_maps_at_the_coordinates(tiny_model):
    """``dynamics_style="nearest"``: the latent path is the rollout of the level nearest the
    coordinates (the same start), and the poses are that path mapped down at the requested
    coordinates; at a level both styles are one rollout."""
    import jax.numpy as jnp

    from bayesmotion.model.generate import map_down_mean, resolve_style
    from bayesmotion.model.predict import style_vectors

    m, o, T = tiny_model, tiny_model.spec.order, 12
    start = np.asarray(m.params["I"])[:o]
    for level in ("happy", "sad"):
        a = m.generate(emotion=level, n_frames=T, start=start)
        b = m.generate(emotion=level, n_frames=T, start=start, dynamics_style="nearest")
        for field in ("I", "Y", "positions", "positions_var"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    P = m.predictor()
    for w, nearest in ((0.7, "happy"), (0.3, "sad"), (0.5, "happy")):  # a tie: the first
        coords = [w, 1 - w]
        near = m.generate(emotion=coords, n_frames=T, start=start, dynamics_style="nearest")
        path = m.generate(emotion=nearest, n_frames=T, start=start)
        np.testing.assert_array_equal(near.I, path.I)
        np.testing.assert_allclose(near.styles["emotion"], [coords] * T)
        int_f = m.spec.interaction_factors
        int_s = tuple(style_vectors(P, int_f, [resolve_style(
            m, f, coords if f == "emotion" else m.levels[f][0], T) for f in int_f]))
        Y = np.stack([np.asarray(y) for _, y in map_down_mean(P, jnp.asarray(near.I), int_s,
                                                              m.n_actors)])
        np.testing.assert_allclose(near.Y, Y, rtol=1e-9, atol=1e-12)
        assert not np.allclose(near.Y, path.Y)  # the mapping carries the other level
        requested = m.generate(emotion=coords, n_frames=T, start=start)
        assert not np.allclose(requested.I[o:], near.I[o:])
    # a matched transition's segments run with it too: its source up to the switch
    tr = m.generate(emotion=bm.Transition([0.7, 0.3], "sad", 6, 2, match=True), n_frames=T,
                    start=start, dynamics_style="nearest")
    src = m.generate(emotion=[0.7, 0.3], n_frames=T, start=start, dynamics_style="nearest")
    np.testing.assert_array_equal(tr.I[:6], src.I[:6])
    # per frame along time-varying coordinates (a smoothstep switches the dynamics halfway)
    from bayesmotion.model.generate import dynamics_coords

    c = np.array([[1.0, 0.0], [0.6, 0.4], [0.5, 0.5], [0.4, 0.6], [1.3, -0.3]])
    np.testing.assert_array_equal(dynamics_coords(c, "nearest"),
                                  [[1, 0], [1, 0], [1, 0], [0, 1], [1, 0]])
    assert dynamics_coords(c, "requested") is c
    with pytest.raises(BayesmotionError, match="dynamics_style must be one of"):
        m.generate(emotion=[0.5, 0.5], n_frames=T, dynamics_style="closest")
    with pytest.raises(BayesmotionError, match="dynamics_style must be one of"):
        m.generate(emotion="happy", n_frames=T, dynamics_style=None)

def test_generate_rejects_bad_styles(tiny_model):
    with pytest.raises(BayesmotionError, match="unknown emotion"):
        tiny_model.generate(emotion="furious")
    with pytest.raises(BayesmotionError, match="2 entries"):
        tiny_model.generate(emotion=[1, 0, 0])
    with pytest.raises(BayesmotionError, match="start"):
        tiny_model.generate(emotion="happy", start=np.zeros((5, 5)))


@pytest.mark.slow
def test_mean_rollout_reproduces_training_trial_and_stays_alive(handshake_model,
                                                                handshake_data):
    m = handshake_model
    nrmse = []
    for r_idx in (0, 5, 10):
        rec = m.trials[r_idx]
        roll = m.generate(emotion=rec.labels["emotion"], couple=rec.labels["couple"],
                          n_frames=rec.n_frames, start=r_idx)
        Y = np.stack([np.asarray(y)[m.trial_slices()[r_idx]] for y in m.data.Y])
        nrmse.append(np.sqrt(np.mean((roll.Y - Y) ** 2) / np.mean(Y.var(1))))
    print("NRMSE of mean rollouts vs their training trials:", np.round(nrmse, 3))
    assert max(nrmse) < 0.5
    long = m.generate(emotion="happy", couple="c1", n_frames=1000)
    assert np.all(np.isfinite(long.positions))
    train_energy = np.mean([np.mean(np.diff(np.asarray(y), axis=0) ** 2) for y in m.data.Y])
    late = np.mean(np.diff(long.Y[:, -300:], axis=1) ** 2)
    print("motion energy, last 300 of 1000 frames / training:", late / train_energy)
    assert 0.1 < late / train_energy < 10  # neither a fixed point nor an explosion
    assert np.abs(long.Y).max() < 20 * np.abs(np.concatenate(m.data.Y)).max()


@pytest.mark.slow
def test_generated_handshakes_bring_the_hands_together(handshake_model):
    real = bm.load_cmu_handshake()
    from bayesmotion.datasets.handshakes import hand_distance

    d_real = hand_distance(real).min()
    for e in handshake_model.levels["emotion"]:
        r = handshake_model.generate(emotion=e, couple="c1", n_frames=17)
        j = r.skeletons[0].index("RightHand")
        d = np.linalg.norm(r.positions[0, :, j] - r.positions[1, :, j], axis=-1).min()
        print(f"{e}: min right-hand distance {d:.2f} (real {d_real:.2f})")
        assert d < 1.5 * d_real


def test_mean_rollout_variance_equals_the_per_step_predictive(tiny_model):
    """The mean rollout computes its one-step variances after the scan, in one batch; they must
    equal each step's predictive variance at the lags it actually used."""
    import jax.numpy as jnp

    from bayesmotion.model.predict import noise_variances, predict_dynamics

    r = tiny_model.generate(emotion="sad", n_frames=25)
    P, o = tiny_model.predictor(), tiny_model.spec.order
    styles = [jnp.asarray(r.styles[f][o:]) for f in tiny_model.spec.dynamics_factors]
    for t in range(o, 25):
        lags = jnp.asarray(np.stack([r.I[t - 1 - k] for k in range(o)])[:, None, :])
        mean, var = predict_dynamics(P, lags, [s[t - o:t - o + 1] for s in styles])
        np.testing.assert_allclose(r.I[t], np.asarray(mean)[0], rtol=1e-9, atol=1e-12)
        expected = float(var[0] + noise_variances(P)["I"])
        np.testing.assert_allclose(r.I_var[t], expected, rtol=1e-9)


def test_sampled_rollouts_map_down_by_the_same_means(tiny_model):
    """Sampled rollouts are mapped down by means alone (``map_down_mean``, no per-frame O(N^2)
    variances); those means must be the ones ``map_down`` gives with its variances."""
    import jax.numpy as jnp

    from bayesmotion.model.generate import map_down, map_down_mean
    from bayesmotion.model.predict import style_vectors

    r = tiny_model.generate(emotion="happy", n_frames=30, n_samples=2, seed=3)
    P, A = tiny_model.predictor(), tiny_model.n_actors
    f = tiny_model.spec.interaction_factors
    int_s = tuple(style_vectors(P, f, [r.styles[k] for k in f]))
    I = jnp.asarray(r.samples["I"][1])
    full, _ = map_down(P, I, int_s, A)
    means = map_down_mean(P, I, int_s, A)
    for a in range(A):
        np.testing.assert_allclose(np.asarray(means[a][0]), np.asarray(full[a][0]), rtol=1e-12,
                                   atol=1e-12)
        np.testing.assert_allclose(np.asarray(means[a][1]), np.asarray(full[a][1]), rtol=1e-12,
                                   atol=1e-12)
        np.testing.assert_allclose(r.samples["Y"][1, a], np.asarray(full[a][1]), rtol=1e-12,
                                   atol=1e-12)
    assert not np.allclose(r.samples["I"][0], r.samples["I"][1])


def test_the_predictor_is_conditioned_once_per_model(tiny_model):
    assert tiny_model.predictor() is tiny_model.predictor()
    other = tiny_model.with_params(tiny_model.params)
    assert other.predictor() is not tiny_model.predictor()


def test_interval_coverage_counts_per_horizon():
    """Hand-built case: 10 fps, 2 observed frames, errors of 0.5 sd in the first second and
    3 sd afterwards -> inside both intervals in the first second, inside neither later."""
    from bayesmotion.evaluation.evaluate import interval_coverage

    T = 32
    mean = np.zeros((2, T, 3, 3))
    var = np.full_like(mean, 4.0)
    truth = np.where(np.arange(T)[None, :, None, None] < 12, 1.0, 6.0) * np.ones_like(mean)
    truth[:, :2] = 0.0
    c = interval_coverage(truth, mean, var, fps=10.0, n_observed=2)
    assert c["first_second"] == {"0.5": 1.0, "0.9": 1.0}
    assert c["by_horizon"][1] == {"from_s": 1.0, "to_s": 2.0, "0.5": 0.0, "0.9": 0.0}
    assert c["by_horizon"][-1]["to_s"] == 3.0  # the last, partial bin ends at the last frame
    assert c["overall"]["0.9"] == 10 / 30
    # an error of 1 sd: outside the 50% interval (0.674 sd), inside the 90% one (1.645 sd)
    c = interval_coverage(np.full_like(mean, 2.0), mean, var, n_observed=2)
    assert c["overall"] == {"0.5": 0.0, "0.9": 1.0}
    with pytest.raises(BayesmotionError, match="share one shape"):
        interval_coverage(truth[:, :5], mean, var)


def test_mean_only_path_gives_the_mean_rollout_of_the_full_path(tiny_model):
    """``with_var=False`` (dynamics scan and top-down mapping without the O(N^2) variances)
    must reproduce the means of the path with variances, and skip the variances."""
    import jax
    import jax.numpy as jnp

    from bayesmotion.model.generate import _map_and_decode, dynamics_rollout
    from bayesmotion.model.predict import style_vectors

    r = tiny_model.generate(emotion="sad", n_frames=25)
    P, o = tiny_model.predictor(), tiny_model.spec.order
    fd, fi = tiny_model.spec.dynamics_factors, tiny_model.spec.interaction_factors
    dyn_s = tuple(style_vectors(P, fd, [r.styles[k][o:] for k in fd]))
    int_s = tuple(style_vectors(P, fi, [r.styles[k] for k in fi]))
    key = jax.random.PRNGKey(0)
    I_mean, var = dynamics_rollout(P, jnp.asarray(r.I[:o]), dyn_s, key, 25 - o, False,
                                   with_var=False)
    assert var is None
    np.testing.assert_allclose(np.asarray(I_mean), r.I[o:], rtol=1e-12, atol=1e-12)
    trial = int(r.start.split("training trial ")[1].split()[0])
    out = _map_and_decode(tiny_model, P, jnp.asarray(r.I), int_s, trial, with_var=False)
    assert set(out) == {"X", "Y", "angles", "positions"}
    for k in out:
        np.testing.assert_allclose(out[k], getattr(r, k), rtol=1e-10, atol=1e-10)


def test_unknown_style_factors_and_untrained_levels_are_refused(tiny_model):
    """A misspelt factor is not ignored, and a level with no training trials (whose rollout
    would collapse to zero after the start frames) is refused."""
    from .conftest import make_tiny_dataset

    with pytest.raises(BayesmotionError, match="no style factor \\['contnet'\\]"):
        tiny_model.generate(emotion="happy", n_frames=10, contnet="walk")
    ds = make_tiny_dataset()
    wider = bm.HGPDM(latent_dim=3, interaction_dim=3).fit(
        bm.MotionDataset(ds.trials, {"emotion": ("happy", "sad", "angry"), "couple": ("c1",)}),
        max_iter=3, progress=False)
    with pytest.raises(BayesmotionError, match="\\['angry'\\] have no training trials"):
        wider.generate(emotion="angry", n_frames=10)
    with pytest.raises(BayesmotionError, match="no training trials"):
        wider.generate(emotion=[0.5, 0.0, 0.5], n_frames=10)
    r = wider.generate(emotion=[0.5, 0.5, 0.0], n_frames=10)  # trained levels only: fine
    assert np.all(np.isfinite(r.positions))


def test_transition_weights_at_the_window_edges(tiny_model):
    from bayesmotion.model.generate import Transition, resolve_style

    w = resolve_style(tiny_model, "emotion", Transition("happy", "sad", 3, 4), 10)[:, 1]
    np.testing.assert_allclose(w[:4], 0.0)  # up to and including frame start
    np.testing.assert_allclose(w[7:], 1.0)  # from frame start + length on
    assert np.all(np.diff(w[3:8]) > 0)
    w0 = resolve_style(tiny_model, "emotion", Transition("happy", "sad", 3, 0), 6)[:, 1]
    np.testing.assert_array_equal(w0, [0, 0, 0, 1, 1, 1])  # length 0 switches at start
    with pytest.raises(BayesmotionError, match="length must be >= 0"):
        resolve_style(tiny_model, "emotion", Transition("happy", "sad", 3, -1), 6)


def _predictions(P, rng, styles):
    """Dynamics and interaction predictive means and variances at random inputs."""
    from bayesmotion.model import predict

    o, _, q = P.dyn_lags.shape
    lags = rng.normal(size=(o, 7, q))
    I = rng.normal(size=(7, P.I.shape[1]))
    S = [np.broadcast_to(np.asarray(s, float), (7, len(s))) for s in styles]
    return (*predict.predict_dynamics(P, lags, S), *predict.predict_interaction(P, I, S))


@pytest.mark.parametrize("which", ["tiny", "unequal_cells"])
def test_blocked_conditioning_predicts_what_the_dense_one_does(tiny_model, which):
    """With one-hot training styles the style layers are conditioned cell by cell; every
    prediction (one-hot, mixed and extrapolated styles) must equal the dense conditioning's."""
    from bayesmotion import HGPDM
    from bayesmotion.model import predict

    from .conftest import make_tiny_dataset

    m = tiny_model
    if which == "unequal_cells":  # 2 happy and 3 sad trials: cells of unequal size (padding)
        ds = make_tiny_dataset()
        keep = [t for t in ds.trials if t.labels["emotion"] == "sad"]
        keep += [t for t in ds.trials if t.labels["emotion"] == "happy"][:2]
        ds = bm.MotionDataset(keep, ds.levels)
        m = HGPDM(latent_dim=3, interaction_dim=3).fit(ds, max_iter=5, progress=False)
    blocked, dense = predict.condition(m), predict.condition(m, blocked=False)
    assert blocked.dyn.rows is not None and blocked.inter.rows is not None
    assert dense.dyn.rows is None and dense.inter.rows is None
    if which == "unequal_cells":
        assert not np.asarray(blocked.inter.mask).all()  # the smaller cell is padded
    for seed, emotion in enumerate(([1.0, 0.0], [0.0, 1.0], [0.3, 0.7], [1.4, -0.4])):
        styles = [[1.0], emotion]  # couple (one level), emotion
        got = _predictions(blocked, np.random.default_rng(seed), styles)
        want = _predictions(dense, np.random.default_rng(seed), styles)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-8,
                                       atol=1e-10 * float(np.max(np.abs(w))))


@pytest.mark.parametrize("emotion", [[1.0, 0.0], [0.0, 1.0], [0.3, 0.7]])
def test_restricting_to_the_cells_a_style_sees_changes_no_prediction(tiny_model, emotion):
    """restrict_to_styles drops the cells whose style factor is exactly 0 for every new input:
    one-hot styles keep one cell, a mixture keeps both; predictions equal the full ones."""
    from bayesmotion.model import predict

    P = tiny_model.predictor()
    styles = [[1.0], emotion]
    S = [np.broadcast_to(np.asarray(s, float), (7, len(s))) for s in styles]
    R = predict.restrict_to_styles(P, S, S)
    n_cells = 1 if 0.0 in emotion else 2
    assert R.dyn.Linv.shape[0] == R.inter.Linv.shape[0] == n_cells
    assert R.I.shape[0] == n_cells * P.inter.rows.shape[1]
    for seed in range(2):
        got = _predictions(R, np.random.default_rng(seed), styles)
        want = _predictions(P, np.random.default_rng(seed), styles)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-12,
                                       atol=1e-13 * float(np.max(np.abs(w))))


def test_generate_with_restricted_cells_equals_the_full_predictor(tiny_model, monkeypatch):
    """The public rollout (mean, every variance, sampled rollouts) is the same with and without
    the cell restriction, for a transition between the two emotions and for one emotion."""
    import bayesmotion.model.generate as G

    for emotion in ("sad", G.Transition("happy", "sad", 4, 5)):
        got = tiny_model.generate(emotion=emotion, n_frames=14, n_samples=3)
        monkeypatch.setattr(G, "restrict_to_styles", lambda P, d, i: P)
        want = tiny_model.generate(emotion=emotion, n_frames=14, n_samples=3)
        monkeypatch.undo()
        for k in ("I", "I_var", "X", "X_var", "Y_var", "positions", "positions_var"):
            w = getattr(want, k)
            np.testing.assert_allclose(getattr(got, k), w, rtol=1e-10,
                                       atol=1e-12 * max(float(np.max(np.abs(w))), 1e-300))
        np.testing.assert_allclose(got.samples["positions"], want.samples["positions"],
                                   rtol=1e-10, atol=1e-12 * np.abs(want.samples["positions"]).max())


def test_learned_style_vectors_keep_the_dense_conditioning():
    """Learned (non one-hot) style vectors couple the cells: no block structure to use."""
    from bayesmotion import HGPDM
    from bayesmotion.model import predict

    from .conftest import make_tiny_dataset

    m = HGPDM(latent_dim=2, interaction_dim=2).fit(make_tiny_dataset(), max_iter=3,
                                                   optimize_style=("emotion",), progress=False)
    P = predict.condition(m)
    assert P.dyn.rows is None and P.inter.rows is None


def test_the_rollout_mean_step_equals_the_dynamics_predictive_mean(tiny_model):
    from bayesmotion.model import predict

    P = tiny_model.predictor()
    rng = np.random.default_rng(5)
    o, _, q = P.dyn_lags.shape
    styles = [np.ones((4, 1)), np.array([[1.0, 0.0], [0.0, 1.0], [0.3, 0.7], [1.4, -0.4]])]
    step, rows = predict.dynamics_mean_stepper(P, styles)
    for t in range(4):
        lags = rng.normal(size=(o, q))
        want = predict.predict_dynamics_mean(P, lags[:, None, :], [s[t:t + 1] for s in styles])
        np.testing.assert_allclose(np.asarray(step(lags, rows[t])), np.asarray(want[0]),
                                   rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("n", [50, 257, 300])
def test_packed_lower_triangular_products_equal_the_dense_product(n):
    from bayesmotion.model import predict

    rng = np.random.default_rng(n)
    L = np.tril(rng.normal(size=(n, n)))
    k = rng.normal(size=(n, 7))
    got = np.concatenate(predict.lower_parts(predict.pack_lower(L), k))
    np.testing.assert_allclose(got, L @ k, rtol=1e-12, atol=1e-12 * np.abs(L @ k).max())
    fit = predict.LayerFit(predict.pack_lower(L), np.zeros((n, 1)))
    np.testing.assert_allclose(np.asarray(predict.whitened_norms(fit, k)),
                               np.sum((L @ k) ** 2, 0), rtol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("memory", [16, 5])
def test_path_conditioned_steps_equal_the_gp_refitted_on_the_path(tiny_model, memory):
    """Each step of a path-conditioned sample is the dynamics GP's predictive given the
    training rows *and* the last ``memory`` steps of the path as noisy observations: checked
    against that GP assembled densely from scratch (the drawn normal recovered from the
    returned step and variance must be the one the step's key draws)."""
    import jax
    import jax.numpy as jnp

    from bayesmotion.gp import kernels
    from bayesmotion.model import layers
    from bayesmotion.model.generate import dynamics_rollout
    from bayesmotion.model.predict import noise_variances, style_vectors

    P, o = tiny_model.predictor(), tiny_model.spec.order
    n = 12
    fd = tiny_model.spec.dynamics_factors
    # the emotion moving between the levels step by step (more than one cell counts, and each
    # buffered step keeps its own style), the first level of any other factor
    s = np.linspace(0.15, 0.9, n)[:, None]
    coords = [np.hstack([1 - s, s]) if f == "emotion"
              else np.tile(np.eye(len(tiny_model.levels[f]))[0], (n, 1)) for f in fd]
    assert "emotion" in fd
    dyn_s = tuple(style_vectors(P, fd, coords))
    I0 = tiny_model.latents(0)["I"][:o]
    key = jax.random.PRNGKey(7)
    I, v = dynamics_rollout(P, jnp.asarray(I0), dyn_s, key, n, True, memory=memory)
    I, v = np.asarray(I), np.asarray(v)
    z = np.asarray(jax.vmap(lambda k: jax.random.normal(k, (I.shape[1],)))(
        jax.random.split(key, n)))
    noise = float(noise_variances(P)["I"])
    a = P.alpha
    U = [np.asarray(u) for u in P.dyn_lags]  # training inputs, o arrays (M, Q)
    S = [np.asarray(s) for s in P.dyn_style]
    K = np.asarray(kernels.dynamics_kernel(U, U, S, S, a)) + noise * np.eye(U[0].shape[0])
    resid = K @ np.asarray(P.dyn.A)  # training outputs less the autoregressive mean
    path = np.concatenate([I0, I])
    for t in range(n):
        lo = max(0, t - memory)
        lags = [path[o + s - 1 - l:o + s - l] for s in range(lo, t + 1) for l in range(o)]
        Ux = [np.concatenate([U[l]] + [lags[(s - lo) * o + l] for s in range(lo, t)])
              for l in range(o)]
        Sx = [np.concatenate([s] + [np.asarray(d)[[s_]] for s_ in range(lo, t)])
              for s, d in zip(S, dyn_s, strict=True)]
        x = [lags[(t - lo) * o + l] for l in range(o)]
        sx = [np.asarray(d)[[t]] for d in dyn_s]
        ar = lambda ls: np.asarray(layers.ar_mean(jnp.stack(ls), P.ar))
        y = np.concatenate([resid] + [path[[o + s]] - ar([lags[(s - lo) * o + l]
                                                           for l in range(o)])
                                      for s in range(lo, t)])
        Kx = np.array(kernels.dynamics_kernel(Ux, Ux, Sx, Sx, a))
        Kx += noise * np.eye(Kx.shape[0])
        Kx[U[0].shape[0]:, U[0].shape[0]:] += 1e-10 * float(a[0]) * np.eye(t - lo)
        kx = np.asarray(kernels.dynamics_kernel(Ux, x, Sx, sx, a))[:, 0]
        mean = kx @ np.linalg.solve(Kx, y) + ar(x)[0]
        var = float(np.asarray(kernels.dynamics_diag(x, sx, a))[0]
                    - kx @ np.linalg.solve(Kx, kx)) + noise
        np.testing.assert_allclose(v[t], var, rtol=1e-5)
        np.testing.assert_allclose((I[t] - mean) / np.sqrt(var), z[t], rtol=1e-5, atol=1e-6)


def test_sample_memory_is_checked_and_zero_keeps_the_independent_draws(tiny_model):
    """``sample_memory`` must be an integer in [0, 256], with samples; 0 draws each step given
    the training data alone (the step-by-step sampler), so its first free step equals every
    memory's and its later steps differ from a path-conditioned sample with the same keys."""
    for bad in (-1, 2.5, True, 257):
        with pytest.raises(BayesmotionError,
                           match="sample_memory must be an integer in \\[0, 256\\]"):
            tiny_model.generate(emotion="happy", n_frames=10, n_samples=1, sample_memory=bad)
    with pytest.raises(BayesmotionError, match="n_samples is 0"):
        tiny_model.generate(emotion="happy", n_frames=10, sample_memory=8)
    o = tiny_model.spec.order
    a = tiny_model.generate(emotion="happy", n_frames=12, n_samples=3, seed=4, sample_memory=0)
    b = tiny_model.generate(emotion="happy", n_frames=12, n_samples=3, seed=4, sample_memory=8)
    np.testing.assert_allclose(a.samples["I"][:, :o + 1], b.samples["I"][:, :o + 1],
                               rtol=1e-12, atol=1e-12)
    assert not np.allclose(a.samples["I"][:, o + 2:], b.samples["I"][:, o + 2:])
    np.testing.assert_array_equal(a.I, b.I)  # the mean rollout does not sample
