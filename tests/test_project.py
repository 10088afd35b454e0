"""Projection of a clip into the model's latents and the Laplace evidence of each emotion level
(bayesmotion.emotion.projection; infer_emotion(..., emotion_starts="vertices"))."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.emotion import projection as project
from bayesmotion.emotion.clip import clip_poses
from bayesmotion.emotion.density import clip_log_density
from bayesmotion.emotion.infer import _largest_prior, _style_setup
from bayesmotion.emotion.projection import (
    STATIC_ARGS,
    _hvps,
    banded_hessian,
    diag_hessian,
    init_latents,
    laplace_log_evidence,
)
from bayesmotion.model.predict import style_vectors

from .conftest import make_tiny_dataset


@pytest.fixture(scope="module")
def tiny_data():
    return make_tiny_dataset()


def _neg_hessian(params, *args, **statics):
    """Dense Hessian of -log p from d products with the identity (the reference)."""
    from jax.flatten_util import ravel_pytree

    d = ravel_pytree(params)[0].size
    return _hvps(params, jnp.eye(d), *args, **statics)


def _setup(model, trial, T, B):
    """Arguments of the clip density for the first T frames of ``trial`` padded to B, with
    latents from the nearest training frames and the emotion free."""
    Ys = [np.asarray(Y)[:T] for Y in clip_poses(model, trial)]
    fixed, conc, inferred = _style_setup(model, {}, None)
    assert inferred == ["emotion"]
    X0, I0, _ = init_latents(model, Ys, B)
    params = {"X": jnp.asarray(X0), "I": jnp.asarray(I0),
              "style:emotion": jnp.asarray([0.3, -0.2][:len(conc["emotion"]) - 1])}
    mask = jnp.asarray(np.arange(B) < T)
    Yp = tuple(jnp.asarray(np.concatenate([Y, np.zeros((B - T, Y.shape[1]))])) for Y in Ys)
    P = model.predictor()
    fixed = dict(zip(fixed, style_vectors(P, list(fixed), list(fixed.values())), strict=True))
    args = (P, Yp, mask, {k: jnp.asarray(v) for k, v in fixed.items()},
            {k: jnp.asarray(v) for k, v in conc.items()})
    statics = {"int_factors": tuple(model.spec.interaction_factors),
               "dyn_factors": tuple(model.spec.dynamics_factors),
               "init_var": float(model.spec.priors.init_var)}
    assert set(statics) == set(STATIC_ARGS)
    return params, args, statics


@pytest.mark.slow
def test_chunked_hessian_matches_differences_and_padding_carries_nothing(tiny_model, tiny_data,
                                                                           monkeypatch):
    from jax.flatten_util import ravel_pytree

    T, B = 8, 12  # the tiny trials have 9 frames; frames 0..11 in 5 residue classes
    params, args, statics = _setup(tiny_model, tiny_data[0], T, B)
    z0, unravel = ravel_pytree(params)
    grad = jax.jit(jax.grad(lambda z: -clip_log_density(args[0], unravel(z), *args[1:],
                                                        **statics)))
    h = 1e-5
    eye = np.eye(z0.size)
    ref = np.stack([(np.asarray(grad(z0 + h * e)) - np.asarray(grad(z0 - h * e))) / (2 * h)
                    for e in eye], 1)  # central differences of the gradient
    H = np.asarray(_neg_hessian(params, *args, **statics))  # 109 products: 2 chunks of 64
    assert H.shape == ref.shape
    scale = np.abs(H).max()
    np.testing.assert_allclose(H, ref, rtol=1e-5, atol=1e-7 * scale)
    np.testing.assert_allclose(H, H.T, rtol=0, atol=1e-10 * scale)
    # the banded reconstruction from A Q_X + (2 o + 1) Q_I + 1 = 6 + 15 + 1 = 22 products
    # gives the same matrix
    calls = []
    real_hvps = project._hvps
    monkeypatch.setattr(project, "_hvps", lambda p, V, *a, **k: calls.append(V.shape[0])
                        or real_hvps(p, V, *a, **k))
    Hb = banded_hessian(params, args, statics)
    np.testing.assert_allclose(Hb, H, rtol=1e-10, atol=1e-10 * scale)
    # the exact diagonal from A Q_X + (o + 1) Q_I + 1 = 6 + 9 + 1 = 16 coloured products (the
    # projection's scaling and the latents' Laplace sd)
    D = diag_hessian(params, args, statics)
    np.testing.assert_allclose(np.asarray(ravel_pytree(D)[0]), np.diag(H), rtol=1e-10,
                               atol=1e-10 * scale)
    # in blocks of HVP_BLOCK = 8 probes, one program for both probe sets: 22 -> 3 calls,
    # 16 -> 2 calls
    assert project.HVP_BLOCK == 8 and calls == [8] * 5
    # the padded frames' latents carry no density: their rows and columns are exactly zero
    pad = {k: (jnp.zeros_like(v).at[..., T:, :].set(1.0) if k in ("X", "I")
               else jnp.zeros_like(v)) for k, v in params.items()}
    rows = np.asarray(ravel_pytree(pad)[0]) > 0
    assert rows.sum() == (B - T) * (2 * 3 + 3) and H.shape == (B * 9 + 1,) * 2
    assert np.all(H[rows] == 0) and np.all(H[:, rows] == 0)


@pytest.mark.slow
def test_laplace_evidence_does_not_depend_on_the_padding(tiny_model, tiny_data):
    """The same clip and latents in a 16-frame and a 32-frame bucket: the same evidence (only
    the real frames' latents are integrated), over d = T (A Q_X + Q_I) + K - 1 coordinates."""
    T = 9
    p16, a16, statics = _setup(tiny_model, tiny_data[1], T, 16)
    p32, a32, _ = _setup(tiny_model, tiny_data[1], T, 32)
    for k in ("X", "I"):
        np.testing.assert_array_equal(np.asarray(p32[k])[..., :T, :],
                                      np.asarray(p16[k])[..., :T, :])
    e16, i16 = laplace_log_evidence(p16, a16, statics, T)
    e32, i32 = laplace_log_evidence(p32, a32, statics, T)
    K = len(tiny_model.levels["emotion"])
    assert i16["dim"] == i32["dim"] == T * (2 * 3 + 3) + K - 1
    assert np.isfinite(e16)
    np.testing.assert_allclose(e32, e16, rtol=1e-9)
    np.testing.assert_allclose(i32["logdet"], i16["logdet"], rtol=1e-9)
    # evidence = log density + d/2 log 2 pi - logdet / 2
    np.testing.assert_allclose(
        e16, i16["log_density"] + 0.5 * i16["dim"] * np.log(2 * np.pi) - 0.5 * i16["logdet"])


def test_vertices_chooses_each_training_trials_level(tiny_model, tiny_data):
    """emotion_starts="vertices": one projection per level with the emotion held at its vertex;
    the level of largest Laplace evidence is chosen, and the style sampler at its latents
    agrees. On the model's own training trials that is the trial's label."""
    K = len(tiny_model.levels["emotion"])
    levels = list(tiny_model.levels["emotion"])
    for label in levels:
        trial = tiny_data[tiny_data.labels("emotion").index(label)]
        ep = bm.infer_emotion(tiny_model, trial, n_steps=60, latent_uncertainty=False,
                              emotion_starts="vertices")
        info = ep.info
        assert info["emotion_starts"] == "vertices"
        assert len(info["level_log_evidence"]) == len(info["level_objectives"]) == K
        p = np.asarray(info["level_probabilities"])
        assert p.shape == (K,) and abs(p.sum() - 1) < 1e-12
        assert levels[int(np.argmax(info["level_log_evidence"]))] == label
        assert ep.label == label
        # the chosen level's projection is then refined with the emotion free
        assert np.isfinite(info["map_objective"]) and info["map_iterations"] >= 1
        T = info["n_frames"]
        assert all(d["dim"] == T * (2 * 3 + 3) for d in info["level_laplace"])


def test_largest_prior():
    np.testing.assert_array_equal(_largest_prior(np.ones(4)), np.full(4, 0.25))
    p = _largest_prior(np.array([8.0, 1.0, 1.0]))
    assert p.shape == (3,) and abs(p.sum() - 1) < 1e-12
    assert p[0] > 0.95 and abs(p[1] - p[2]) < 0.01
    draws = np.random.default_rng(1).dirichlet([2.0, 1.0], 200000)
    np.testing.assert_allclose(_largest_prior(np.array([2.0, 1.0]))[0],
                               np.mean(draws[:, 0] > 0.5), atol=0.01)


def test_vertices_rejects_unknown_mode(tiny_model, tiny_data):
    with pytest.raises(bm.BayesmotionError, match="'vertices'"):
        bm.infer_emotion(tiny_model, tiny_data[0], emotion_starts="vertex")


def test_frame_buckets_bound_the_padding():
    """Clips are padded to few sizes (shared compilations) with at most a quarter of waste."""
    from bayesmotion.shapes import padded_length as _bucket

    sizes = np.array([_bucket(n) for n in range(1, 2049)])
    n = np.arange(1, 2049)
    assert np.all(sizes >= n) and np.all(np.diff(sizes) >= 0)
    assert np.all(sizes[n > 16] < 1.25 * n[n > 16])
    assert _bucket(17) == 20 and _bucket(16) == 16 and _bucket(33) == 40
    assert len(np.unique(sizes[(n > 256) & (n <= 512)])) == 4  # four sizes per doubling


def test_projection_rounds_rescale_and_never_worsen(tiny_model, tiny_data, monkeypatch):
    """minimize_scaled: rounds of at most ``round_iter`` iterations, each a jitted L-BFGS call in
    freshly
    rescaled coordinates, until ``max_iter``; the result never scores worse than its start and
    its fields describe the returned point."""
    from bayesmotion.emotion.projection import _neg_value_and_grad, minimize_scaled
    from bayesmotion.optim import lbfgs

    params, args, statics = _setup(tiny_model, tiny_data[0], 9, 16)
    start = float(_neg_value_and_grad(params, *args, **statics)[0])
    limits = []
    real = project._scaled_lbfgs
    monkeypatch.setattr(project, "_scaled_lbfgs",
                        lambda x, scale, n, *a, **k: limits.append(n) or real(x, scale, n, *a,
                                                                               **k))
    p, res = minimize_scaled(params, args, statics, 12, round_iter=5)
    assert res.status == lbfgs.MAX_ITER and res.message == lbfgs.MESSAGES[lbfgs.MAX_ITER]
    assert limits == [5, 5, 2] and res.nit == 12 and res.nfev >= 12
    assert res.fun < start
    assert res.fun == pytest.approx(float(_neg_value_and_grad(p, *args, **statics)[0]),
                                    rel=1e-12)
    # run to convergence: it stops before the limit, at a point with a small gradient
    limits.clear()
    p, res = minimize_scaled(params, args, statics, 5000)
    assert res.success and res.nit < 5000 and len(limits) == -(-res.nit // 100)
    value = float(_neg_value_and_grad(p, *args, **statics)[0])
    assert res.fun == pytest.approx(value, rel=1e-12) and res.fun < start


@pytest.mark.slow
def test_batched_projections_match_one_at_a_time(tiny_model, tiny_data):
    """minimize_scaled_many with batch=True (jobs of equal shapes under vmap, one program per
    round) returns each job's own result: the objective to rounding, the iteration count and
    status of minimize_scaled on that job alone, with jobs that stop at different rounds
    (batched arithmetic rounds differently, so the paths part in the last digits)."""
    from jax.flatten_util import ravel_pytree

    from bayesmotion.emotion.projection import minimize_scaled, minimize_scaled_many

    params, args, statics = _setup(tiny_model, tiny_data[0], 9, 16)
    other, args2, _ = _setup(tiny_model, tiny_data[3], 9, 16)
    jobs = [(params, args), (other, args2), ({**params, "I": params["I"] + 0.05}, args)]
    short, _, _ = _setup(tiny_model, tiny_data[1], 5, 8)  # another shape: its own group
    jobs.append((short, args[:1] + _setup(tiny_model, tiny_data[1], 5, 8)[1][1:]))
    for max_iter in (12, 400):
        alone = [minimize_scaled(p, a, statics, max_iter, round_iter=5) for p, a in jobs]
        many = minimize_scaled_many(jobs, statics, max_iter, round_iter=5, batch=True)
        seq = minimize_scaled_many(jobs, statics, max_iter, round_iter=5, batch=False)
        for (p0, r0), (p1, r1), (_, r2) in zip(alone, many, seq, strict=True):
            np.testing.assert_allclose(r1.fun, r0.fun, rtol=1e-6)
            if max_iter == 12:
                assert (r1.nit, r1.status) == (r0.nit, r0.status) == (12, 1)
                np.testing.assert_allclose(ravel_pytree(p1)[0], ravel_pytree(p0)[0],
                                           atol=1e-4)
            else:
                assert r0.success and r1.success and r1.nit < 400
            assert r2.fun == r0.fun and r2.nit == r0.nit  # batch=False is the loop itself
        if max_iter == 400:  # the jobs stopped at different iterations, before the limit
            assert len({r.nit for _, r in alone}) > 1 and all(r.nit < 400 for _, r in alone)


@pytest.mark.slow
def test_vertices_answer_does_not_depend_on_batching(tiny_model, tiny_data, monkeypatch):
    """infer_emotion's level projections batched (the accelerator default) or one at a time
    (the CPU default) give the same evidence and label probabilities once the projections
    converge (stopped at an iteration limit, rounding moves where they stop)."""
    from bayesmotion.emotion import projection as proj

    out = {}
    for batched in (False, True):
        monkeypatch.setattr(proj, "batch_jobs", lambda b=batched: b)
        ep = bm.infer_emotion(tiny_model, tiny_data[2], n_steps=40, latent_uncertainty=False,
                              level_starts=2, start_jitter=0.02, max_iter=3000)
        out[batched] = ep
    a, b = out[False].info, out[True].info
    # each level keeps its best start: the same optimum to within 0.1 nats of evidence
    np.testing.assert_allclose(b["level_log_evidence"], a["level_log_evidence"], atol=0.1)
    np.testing.assert_allclose(out[True].label_probabilities, out[False].label_probabilities,
                               atol=0.01)
    assert out[True].label == out[False].label
    assert len(a["level_laplace"][0]["start_objectives"]) == 2


def test_density_parts_sum_to_the_clip_density(tiny_model, tiny_data):
    """The parts the staged start minimises: bottom + upper is the whole -log p; the bottom part
    depends on X* alone, and the upper part with a level's seen cells equals it with every
    cell (the restriction is exact), so the staged stages see the model's density."""
    params, args, statics = _setup(tiny_model, tiny_data[0], 9, 16)
    parts = {q: float(project._neg_part(args[0], params, *args[1:], **statics, part=q))
             for q in project.PARTS}
    assert parts["all"] == pytest.approx(parts["bottom"] + parts["upper"], rel=1e-12)
    g = jax.grad(lambda p: project._neg_part(args[0], p, *args[1:], **statics,
                                             part="bottom"))(params)
    assert np.any(np.asarray(g["X"]) != 0)
    assert not np.any(np.asarray(g["I"])) and not np.any(np.asarray(g["style:emotion"]))
    P = args[0]
    for k in range(P.level_vectors["emotion"].shape[0]):
        fixed = {**args[3], "emotion": jnp.asarray(P.level_vectors["emotion"][k])}
        held = {key: v for key, v in params.items() if key != "style:emotion"}
        Pk = project.seen_predictor(P, fixed, statics["int_factors"], statics["dyn_factors"])
        full = project._neg_part(P, held, args[1], args[2], fixed, {}, **statics, part="upper")
        seen = project._neg_part(Pk, held, args[1], args[2], fixed, {}, **statics,
                                 part="upper")
        assert float(seen) == pytest.approx(float(full), rel=1e-10)


def test_minimizing_some_entries_holds_the_others(tiny_model, tiny_data):
    """minimize_scaled(keys=..., part=...): only the named entries move (the others are returned
    bit for bit), and the part's objective never rises; a part name it does not know is
    refused."""
    params, args, statics = _setup(tiny_model, tiny_data[0], 9, 16)

    def part(p, q):
        return float(project._neg_part(args[0], p, *args[1:], **statics, part=q))

    for keys, q in ((("X",), "bottom"), (("I", "style:emotion"), "upper")):
        p, res = project.minimize_scaled(params, args, statics, 40, keys=keys, part=q)
        for key in params:
            if key not in keys:
                np.testing.assert_array_equal(np.asarray(p[key]), np.asarray(params[key]))
        # the same objective from another compiled program: equal up to rounding (1.3e-12
        # relative seen on this CPU)
        assert res.fun == pytest.approx(part(p, q), rel=1e-10)
        assert res.fun <= part(params, q)
    with pytest.raises(ValueError, match="part"):
        project.minimize_scaled(params, args, statics, 5, part="middle")


def test_staged_start_never_worsens_its_stages(tiny_model, tiny_data):
    """project_levels(staged=True): the bottom stage lowers the bottom term from the nearest
    frames' X* (shared by the levels), each level's joint projection ends at or below its
    staged start, and the evidence is computed at the returned optimum."""
    from bayesmotion.emotion.projection import project_levels, staged_bottom, staged_upper

    trial = tiny_data[0]
    params, args, statics = _setup(tiny_model, trial, 9, 16)
    Ys = [np.asarray(Y)[:9] for Y in clip_poses(tiny_model, trial)]
    P = args[0]
    fixed0 = {**args[3], "emotion": jnp.asarray(P.level_vectors["emotion"][0])}
    args0 = (P, args[1], args[2], fixed0, {})
    held = {k: v for k, v in params.items() if k != "style:emotion"}

    def part(p, q, a=args0):
        return float(project._neg_part(a[0], p, *a[1:], **statics, part=q))

    X = staged_bottom(held, args0, statics, 200)
    assert part({**held, "X": X}, "bottom") < part(held, "bottom")
    out = project_levels(tiny_model, P, Ys, 16, 9, args, statics, 200, ["emotion"],
                         {"emotion": np.ones(P.level_vectors["emotion"].shape[0])},
                         staged=True)
    for k, (p, res, log_ev, info) in enumerate(out):
        fixed = {**args[3], "emotion": jnp.asarray(P.level_vectors["emotion"][k])}
        Pk = project.seen_predictor(P, fixed, statics["int_factors"], statics["dyn_factors"])
        a_k = (Pk, args[1], args[2], fixed, {})
        start = staged_upper({**held, "X": X}, a_k, statics, 200)
        assert res.fun <= part(start, "all", a_k) + 1e-9
        assert res.fun == pytest.approx(part(p, "all", a_k), rel=1e-12)
        assert np.isfinite(log_ev) and info["start_objectives"] == [res.fun]
        # the evidence's log density is the projection's own value, and equals the evidence
        # computed from the density at the returned point
        assert info["log_density"] == -res.fun
        direct, _ = project.laplace_log_evidence(p, a_k, statics, 9)
        assert log_ev == pytest.approx(direct, rel=1e-12, abs=1e-9)
