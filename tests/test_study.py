"""The interpolation study (benchmarks/study_interpolation.py) at reduced size, and its helpers."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import study_interpolation as study  # noqa: E402

from bayesmotion.data.emotion import EmotionStyle  # noqa: E402


def test_spearman_matches_scipy_and_is_zero_for_constant_input():
    rng = np.random.default_rng(0)
    for _ in range(20):
        x, y = rng.standard_normal(6), rng.integers(0, 3, 6).astype(float)  # ties in y
        if np.ptp(y) == 0:
            continue
        np.testing.assert_allclose(study.spearman(x, y), spearmanr(x, y).statistic, rtol=1e-12)
    assert study.spearman([0, 0.5, 1], [2.0, 2.0, 2.0]) == 0.0


def test_scaled_style_runs_from_identity_to_the_fitted_style():
    style = EmotionStyle(speed=1.3, amplitude={"arms": 1.5, "legs": 0.8},
                         posture={"Spine": (4.0, -2.0, 0.0)})
    zero, one, half = (study.scaled_style(style, s) for s in (0.0, 1.0, 0.5))
    assert zero.speed == 1.0 and set(zero.amplitude.values()) == {1.0}
    assert zero.posture["Spine"] == (0.0, 0.0, 0.0)
    assert one.speed == pytest.approx(1.3) and one.amplitude["legs"] == pytest.approx(0.8)
    assert one.posture["Spine"] == pytest.approx((4.0, -2.0, 0.0))
    assert half.speed == pytest.approx(np.sqrt(1.3))          # ratios interpolate geometrically
    assert half.posture["Spine"] == pytest.approx((2.0, -1.0, 0.0))


class _Frames:
    """A stand-in clip: ``n_frames`` and ``select`` over a 1-D signal."""

    def __init__(self, values):
        self.values = np.asarray(values, dtype=float)
        self.n_frames = self.values.size

    def select(self, frames):
        return _Frames(self.values[frames])


class _FirstFrame:
    """A stand-in ranking function that reads only a window's first frame: as phase-dependent
    as a score can be."""

    def score(self, clip):
        return float(clip.values[0])


def test_cycle_strength_does_not_depend_on_where_in_its_cycle_a_clip_starts():
    cfg = study.Settings(fps=10.0, gen_frames=40)
    stride = round(study.STRIDE_SECONDS * cfg.fps)
    assert study.cycle_window(cfg) == 40 - stride == 28
    t = np.arange(200)
    scores, single = [], []
    for shift in range(stride):                     # the same periodic clip, started anywhere
        clip = _Frames(np.sin(2 * np.pi * (t + shift) / stride) + 3.0)
        score, n = study.cycle_strength(_FirstFrame(), clip, cfg, range(stride))
        assert n == stride
        scores.append(score)
        single.append(_FirstFrame().score(clip))
    np.testing.assert_allclose(scores, 3.0, atol=1e-12)
    assert np.ptp(single) > 1.9                    # one window's score moves by the amplitude
    # by default every start the clip allows; a clip shorter than a window is scored whole
    clip = _Frames(np.arange(40.0))
    assert study.cycle_strength(_FirstFrame(), clip, cfg) == (np.mean(np.arange(13.0)), 13)
    assert study.cycle_strength(_FirstFrame(), _Frames([5.0, 6.0]), cfg) == (5.0, 1)


def test_missing_data_writes_a_skip_record(tmp_path):
    out = tmp_path / "study.json"
    res = study.run(True, root=tmp_path / "absent", out=out)
    assert "skipped" in res
    assert json.loads(out.read_text())["skipped"] == res["skipped"]


def _finite(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and np.isfinite(x)


@pytest.mark.slow
def test_quick_study_scores_every_method_at_every_s(bandai_root, tmp_path):
    out = tmp_path / "study.json"
    res = study.run(True, root=bandai_root, out=out)
    saved = json.loads(out.read_text())                        # strict JSON (no NaN)
    assert saved["mode"] == "quick" and saved["methods"] == list(study.METHODS)
    assert saved["s_values"] == list(study.S_VALUES)
    (pair,) = saved["pairs"]
    assert set(pair["methods"]) == set(study.METHODS)
    for method, block in pair["methods"].items():
        assert [o["s"] for o in block["outputs"]] == list(study.S_VALUES), method
        for o in block["outputs"]:
            assert "error" not in o, (method, o)
            assert 0.0 <= o["classifier"]["p_target"] <= 1.0
            assert _finite(o["strength"]["raw"]) and _finite(o["strength"]["normalised"])
            for k in study.NATURALNESS_KEYS:
                assert _finite(o["naturalness"][k]), (method, o["s"], k)
            inf = o["infer_emotion"]
            assert inf == "not run at this s" or _finite(inf["target_mean"])
        s = block["summary"]
        for k in ("strength_spearman", "strength_monotonicity", "strength_calibration_error",
                  "extrapolation_gain", "mean_jerk_ratio", "mean_foot_sliding_ratio"):
            assert _finite(s[k]), (method, k)
    # the H-GPDM extrapolates off the simplex only at s = 1.25
    flags = [o["extrapolated"] for o in pair["methods"]["hgpdm"]["outputs"]]
    assert flags == [s > 1 for s in study.S_VALUES]
    # Amaya at s = 0 is the identity transform: the real neutral clip's scores, strength 0
    amaya0, real0 = pair["methods"]["amaya"]["outputs"][0], pair["real"]["neutral"]
    assert amaya0["strength"]["normalised"] == pytest.approx(0.0, abs=1e-9)
    assert amaya0["classifier"]["p_target"] == pytest.approx(real0["classifier"]["p_target"])
    assert pair["real"]["emotion"]["strength"]["normalised"] == pytest.approx(1.0)
    # the feature axis runs from the real neutral clip (0) to the real emotional clip (1)
    assert pair["real"]["neutral"]["feature_axis"] == pytest.approx(0.0, abs=1e-12)
    assert pair["real"]["emotion"]["feature_axis"] == pytest.approx(1.0)
    assert amaya0["feature_axis"] == pytest.approx(0.0, abs=1e-9)
    for method, block in pair["methods"].items():
        s = block["summary"]
        inside = [o["feature_axis"] for o in block["outputs"] if o["s"] <= 1]
        assert s["feature_axis"] == pytest.approx(inside), method
        assert s["axis_spearman"] == pytest.approx(study.spearman(study.S_VALUES[:5], inside))
        assert s["axis_calibration_error"] == pytest.approx(
            np.mean(np.abs(np.array(inside) - np.array(study.S_VALUES[:5]))))
    # the real clips' windows: both measures per window, the spread is their range
    for which in ("neutral", "emotion"):
        ph = pair["phase_sensitivity"][which]
        assert ph["offsets"] == list(study.PHASE_OFFSETS)
        assert ph["strength_spread"] == pytest.approx(np.ptp(ph["strength"]))
        assert ph["feature_axis_spread"] == pytest.approx(np.ptp(ph["feature_axis"]))
    data = study.load_walks(bandai_root, study.QUICK.fps)  # the first window, scored directly
    ref = study.NaturalnessReference.from_motions([t.actors[0] for t in data], study.QUICK.fps)
    sc = study.fit_scorers(data, "walk", "happy", ref, None, study.QUICK, {})
    n = study.QUICK.gen_frames
    first = study.score(study.clip(data, "walk", "happy").select(slice(0, n)), "happy", sc,
                        False)
    assert ph["strength"][0] == pytest.approx(first["strength"]["normalised"])
    assert ph["feature_axis"][0] == pytest.approx(first["feature_axis"])
    assert saved["phase_sensitivity"]["n_clips"] == saved["phase_sensitivity"]["n_scorings"] == 2
    # one pair: the summary is that pair's; the verdict follows the criteria
    c = study.CRITERIA
    for method in study.METHODS:
        agg, one = saved["summary"][method], pair["methods"][method]["summary"]
        assert agg["strength_spearman"] == pytest.approx(one["strength_spearman"])
        assert agg["interpolates_emotion"] == (
            agg["strength_spearman"] >= c["spearman_min"]
            and agg["strength_monotonicity"] >= c["monotonicity_min"]
            and agg["strength_calibration_error"] <= c["calibration_error_max"])
        assert method in saved["conclusion"]
    # the cycle-averaged strength: 0 and 1 at the real clips, Amaya's identity at 0, and the
    # mean of the windows' scores, normalised by the real clips' cycle averages
    assert pair["real"]["neutral"]["cycle_strength"]["normalised"] == pytest.approx(0.0,
                                                                                 abs=1e-9)
    assert pair["real"]["emotion"]["cycle_strength"]["normalised"] == pytest.approx(1.0)
    w = study.cycle_window(study.QUICK)
    real = study.clip(data, "walk", "happy")
    windows = [sc.strength.score(real.select(slice(o, o + w)))
               for o in range(real.n_frames - w + 1)]
    assert pair["real"]["emotion"]["cycle_strength"]["raw"] == pytest.approx(np.mean(windows))
    assert amaya0["cycle_strength"]["normalised"] == pytest.approx(0.0, abs=1e-9)
    for method, block in pair["methods"].items():
        s = block["summary"]
        inside = [o["cycle_strength"]["normalised"] for o in block["outputs"] if o["s"] <= 1]
        assert s["cycle_strength_normalised"] == pytest.approx(inside), method
        assert s["cycle_strength_spearman"] == pytest.approx(
            study.spearman(study.S_VALUES[:5], inside))
        speeds = [o["joint_speed"] for o in block["outputs"] if o["s"] <= 1]
        assert s["joint_speed"] == pytest.approx(speeds) and min(speeds) > 0
        blend = [(1 - x) * speeds[0] + x * speeds[-1] for x in study.S_VALUES[:5]]
        assert s["speed_vs_blend_mixed"] == pytest.approx(
            np.mean(np.array(speeds[1:4]) / np.array(blend[1:4])))
        assert saved["summary"][method]["interpolates_emotion_cycle_strength"] == (
            study.meets_criteria(saved["summary"][method], "cycle_strength"))
    for which in ("neutral", "emotion"):  # both real quick clips hold two strides of starts
        ph = pair["phase_sensitivity"][which]
        assert ph["cycle_strength_spread"] == pytest.approx(np.ptp(ph["cycle_strength_halves"]))
    # strength, cycle-averaged strength per method; real windows (both), H-GPDM dynamics
    assert len(res["headline"]) == 2 * len(study.METHODS) + 3
    dyn = saved["hgpdm_dynamics"]
    assert {r["trial"] for r in dyn["rows"]} == {t.name for t in study.training_set(
        data, study.QUICK)} and len(dyn["rows"]) == 2 * 2  # 2 trials x 2 levels
    for r in dyn["rows"]:
        assert _finite(r["error_per_step"]) and r["predicted_rms_per_step"] > 0
    for o in pair["methods"]["hgpdm"]["outputs"]:
        assert _finite(o["latent_distance"]) and o["latent_distance"] >= 0
    h = pair["methods"]["hgpdm"]["summary"]
    assert h["latent_distance_mixed"] == pytest.approx(np.mean(
        [o["latent_distance"] for o in pair["methods"]["hgpdm"]["outputs"] if 0 < o["s"] < 1]))
    assert h["axis_vertex_error"] == pytest.approx(
        (abs(h["feature_axis"][0]) + abs(h["feature_axis"][-1] - 1)) / 2)
    table = study.markdown_table(saved).splitlines()
    assert len(table) == 2 + len(study.METHODS) + 2  # header, rule, methods, blank, conclusion
    for method, row in zip(study.METHODS, table[2:], strict=False):
        verdict = "yes" if saved["summary"][method]["interpolates_emotion"] else "no"
        assert row.startswith(f"| {method} | 1 |") and row.endswith(f"| {verdict} |")


def test_the_readme_table_is_the_committed_full_study_output():
    """The results page's study table must be the one rendered from results/study_interpolation.json
    (python benchmarks/study_interpolation.py --table), not typed by hand."""
    root = Path(__file__).resolve().parents[1]
    path = root / "benchmarks" / "results" / "study_interpolation.json"
    assert path.exists(), f"{path} is committed with the repository"
    result = json.loads(path.read_text())
    assert result["mode"] == "full", "the committed study result must come from a full run"
    assert study.markdown_table(result) in (root / "docs" / "results.md").read_text()


def test_gait_phase_advances_once_per_stride_on_a_real_walk(bandai_root):
    """The phase of a real walk runs forward at a walking cadence, on the whole clip and on the
    model's cropped trials, and phase 0 / pi is the left / right foot leading; the phase start
    puts every frame's interaction latents on the unit circle at that phase."""
    from bayesmotion.features.pose import semantic_positions

    data = study.load_walks(bandai_root, 15.0)
    walk = study.clip(data, "walk", "neutral")
    strides = np.diff(np.unwrap(study.gait_phase(walk))) * walk.fps / (2 * np.pi)  # per second
    assert np.mean(strides > 0) > 0.9
    assert 0.4 < np.median(strides) < 2.5                 # 0.4-2.5 strides per second
    cfg = study.Settings(contents=("walk", "walk-left"), emotions=("happy",))
    train = study.training_set(data, cfg)
    for t in train:
        m = t.actors[0]
        phi = study.gait_phase(m)
        assert np.mean(np.diff(np.unwrap(phi)) > 0) > 0.9, t.name
        p = semantic_positions(m.positions(), m.skeleton)
        fwd = np.cross(p["l_hip"] - p["r_hip"], [0.0, 1.0, 0.0])
        lead = np.sum((p["l_foot"] - p["r_foot"]) * fwd, 1)
        assert np.all(lead[np.abs(phi) < 0.5] > 0) and np.all(lead[np.abs(phi) > 2.6] < 0)
    spec = study.HGPDM(latent_dim=cfg.latent_dim, interaction_dim=cfg.interaction_dim,
                       interaction_factors=("emotion",), dynamics_factors=("emotion",))
    params = study.phase_init(spec, train, 0)
    I = params["I"]
    phi = np.concatenate([study.gait_phase(t.actors[0]) for t in train])
    assert I.shape == (phi.size, cfg.interaction_dim)
    np.testing.assert_allclose(np.linalg.norm(I[:, :2], axis=1), 1.0, atol=5e-3)
    np.testing.assert_allclose(np.angle(np.exp(1j * (np.arctan2(I[:, 1], I[:, 0]) - phi))), 0.0,
                               atol=1e-2)
    assert np.abs(I[:, 2]).max() < 5e-3
    assert params["log_alpha"][0] == pytest.approx(np.log(np.mean(I**2)))


@pytest.mark.slow
def test_dynamics_cross_prediction_and_the_phase_start_on_a_short_fit(bandai_root):
    """One row of dynamics_cross_prediction recomputed by hand from the trial's latents (lags
    I_{t-1}, I_{t-2}); a fit from the phase start runs and names its result file."""
    from dataclasses import replace

    from bayesmotion.model.predict import predict_dynamics, style_vectors

    data = study.load_walks(bandai_root, 15.0)
    cfg = replace(study.QUICK, max_iter=3, latent_init="phase")
    assert study.result_name(cfg) == "study_interpolation_phase_latents"
    train = study.training_set(data, cfg)
    model = study.fit_hgpdm(train, cfg)
    out = study.dynamics_cross_prediction(model, train)
    I = model.latents(0)["I"]
    o = model.spec.order
    lags = np.stack([I[o - 1 - k:len(I) - 1 - k] for k in range(o)])
    levels = list(model.levels["emotion"])
    P = model.predictor()
    for level in levels:
        onehot = np.tile(np.eye(len(levels))[levels.index(level)], (len(I) - o, 1))
        mean, _ = predict_dynamics(P, lags, style_vectors(P, ["emotion"], [onehot]))
        want = (np.linalg.norm(np.asarray(mean) - I[o:], axis=1).mean()
                / np.linalg.norm(I[o:] - I[o - 1:-1], axis=1).mean())
        (row,) = [r for r in out["rows"] if r["trial"] == train[0].name and r["level"] == level]
        assert row["error_per_step"] == pytest.approx(want, rel=1e-9)
        assert row["own"] == (level == train[0].labels["emotion"])


@pytest.mark.slow
def test_periodic_and_lookahead_settings_reach_the_fit_and_the_rollouts(bandai_root):
    """--periodic fits a model whose walks loop; --lookahead W rolls the H-GPDM out with
    generate(lookahead=W), so gen_hgpdm's motion is that rollout's, and differs from W = 0's;
    the result file is named for both settings."""
    from dataclasses import replace

    cfg = replace(study.QUICK, max_iter=3, periodic=True, lookahead=10.0)
    assert study.result_name(cfg) == "study_interpolation_periodic_lookahead"
    assert study.result_name(replace(cfg, lookahead=0.0)) == "study_interpolation_periodic"
    train = study.training_set(study.load_walks(bandai_root, 15.0), cfg)
    model = study.fit_hgpdm(train, cfg)
    assert model.spec.periodic and np.sum(model.data.loops >= 0) >= 1
    content, emotion = cfg.contents[0], cfg.emotions[0]
    motion, info = study.gen_hgpdm(model, train, content, emotion, 0.75, cfg)
    levels = list(model.levels["emotion"])
    coords = 0.25 * np.eye(len(levels))[0] + 0.75 * np.eye(len(levels))[levels.index(emotion)]
    start = next(i for i, t in enumerate(train)  # s > 0.5: the emotional clip's start
                 if t.labels["content"] == content and t.labels["emotion"] == emotion)
    want = model.generate(emotion=coords, n_frames=cfg.gen_frames, start=start, lookahead=10.0)
    assert info["start"] == want.start
    np.testing.assert_array_equal(motion.values, want.to_motion()[0].values)
    plain, _ = study.gen_hgpdm(model, train, content, emotion, 0.75, replace(cfg, lookahead=0.0))
    assert not np.allclose(plain.values, motion.values)
    # --dynamics-style nearest reaches the rollouts and the file's name
    near_cfg = replace(cfg, dynamics_style="nearest")
    assert study.result_name(near_cfg) == "study_interpolation_periodic_lookahead_nearest_dynamics"
    assert study.result_name(study.synthesis_setup(replace(near_cfg, latent_init="shared"))) == (
        "study_interpolation_shared_latents_synthesis_setup_nearest_dynamics")
    near, _ = study.gen_hgpdm(model, train, content, emotion, 0.75, near_cfg)
    want = model.generate(emotion=coords, n_frames=cfg.gen_frames, start=start, lookahead=10.0,
                          dynamics_style="nearest")
    np.testing.assert_array_equal(near.values, want.to_motion()[0].values)
    assert not np.allclose(near.values, motion.values)


def test_synthesis_setup_is_the_synthesis_benchmarks_walk_fit(bandai_root):
    """--synthesis-setup takes the synthesis benchmark's walk settings (its frame rate,
    look-ahead, loops; HGPDM's default latent dimensions; rest frames on the canonical side)
    and trains on whole clips; outputs keep the default's 4 s; its file has its own name."""
    import synthesis

    from bayesmotion.model.spec import HGPDM

    syn = synthesis.Settings()
    cfg = study.synthesis_setup(study.Settings())
    assert cfg.fps == syn.fps and cfg.lookahead == syn.lookahead and "walks" in syn.periodic
    assert cfg.periodic and cfg.rest_frames
    assert (cfg.latent_dim, cfg.interaction_dim) == (HGPDM.latent_dim, HGPDM.interaction_dim)
    default = study.Settings()
    assert cfg.gen_frames / cfg.fps == default.gen_frames / default.fps
    assert cfg.infer_frames / cfg.fps == default.infer_frames / default.fps
    assert study.result_name(cfg) == "study_interpolation_synthesis_setup"
    assert study.result_name(study.synthesis_setup(study.QUICK)) == (
        "study_interpolation_synthesis_setup")
    assert study.synthesis_setup(cfg) == cfg
    data = study.load_walks(bandai_root, cfg.fps)
    train = study.training_set(data, cfg)
    whole = {t.name: t.n_frames for t in data}
    assert len(train) == 16 and all(t.n_frames == whole[t.name] for t in train)


def test_infer_summary_and_rescore_on_the_stored_synthesis_setup_result(tmp_path):
    """infer_summary reads infer_emotion's answers at s = 0, 0.5, 1 (target coordinate, mean
    |coordinate - s|, the 50/50 label as target / source / other); --rescore adds such
    summaries to a stored result from its own outputs, refusing one whose stored summaries
    its outputs do not reproduce."""
    outs = {s: {"infer_emotion": {"target_mean": m, "label": lab}}
            for s, m, lab in [(0.0, 0.1, "neutral"), (0.5, 0.2, "sad"), (1.0, 0.7, "happy")]}
    got = study.infer_summary(outs, "happy")
    assert got["infer_target_mean_at_0.5"] == 0.2 and got["infer_label_at_half"] == "other"
    assert got["infer_calibration_error"] == pytest.approx((0.1 + 0.3 + 0.3) / 3)
    assert study.infer_summary({0.0: outs[0.0], 1.0: outs[1.0]}, "happy") == {}
    src = study.RESULTS / "study_interpolation_synthesis_setup.json"
    stored = json.loads(src.read_text())
    keys = [k for k in stored["summary"]["hgpdm"] if k.startswith("infer_")
            and k != "infer_spearman"]
    assert {"infer_calibration_error", "infer_labels_at_half"} <= set(keys)
    stripped = json.loads(src.read_text())
    for pair in stripped["pairs"]:
        for res in pair["methods"].values():
            for k in [k for k in res["summary"] if k in keys or k == "infer_label_at_half"]:
                del res["summary"][k]
    for agg in stripped["summary"].values():
        for k in keys:
            agg.pop(k, None)
    path = tmp_path / "stripped.json"
    path.write_text(json.dumps(stripped))
    back = study.rescore(path)
    for k in keys:
        assert back["summary"]["hgpdm"][k] == stored["summary"]["hgpdm"][k], k
    labels = back["summary"]["hgpdm"]["infer_labels_at_half"]
    assert sum(labels.values()) == 12
    stripped["summary"]["rbf"]["axis_spearman"] += 0.01  # a summary its outputs do not give
    path.write_text(json.dumps(stripped))
    with pytest.raises(SystemExit, match="summary rbf axis_spearman"):
        study.rescore(path)
