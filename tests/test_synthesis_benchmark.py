"""Helpers of the synthesis 'Turing test' (benchmarks/synthesis.py), without fitting."""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import foot_contacts  # noqa: E402
import noise_floor  # noqa: E402
import synthesis  # noqa: E402
import transition_lengths  # noqa: E402


def test_joint_speed_ignores_the_root_and_wraps_angles():
    v = np.zeros((4, 9))
    v[:, :6] = np.arange(4)[:, None] * 100.0  # the root moves and turns: not limb motion
    v[:, 6] = [179.0, -179.0, -177.0, -175.0]  # crosses the +-180 seam: 2 degrees a frame
    np.testing.assert_allclose(synthesis.joint_speed(v), [2.0 / 3] * 3)


def test_each_judge_never_saw_its_clip():
    rng = np.random.default_rng(0)
    labels = ["a", "b"] * 10
    X = rng.normal(size=(20, 3)) + np.array([[3.0, 0, 0] if l == "a" else [-3.0, 0, 0]
                                             for l in labels])
    X[0] = [-3.0, 0, 0]  # clip 0 is labelled "a" but looks like "b"
    judges = synthesis.held_out_judges(X, labels)
    rate = synthesis.natural_rate(judges, X, labels, np.arange(20))
    assert rate == {"rate": 19 / 20, "n": 20}  # only the odd clip is missed
    # a judge that had seen clip 0 would more likely call it "a"
    assert judges[0].predict_proba(X[:1])[0][list(judges[0].classes).index("a")] < 0.5


def test_targets_are_judged_against_the_natural_rate():
    g = {"natural_rate": {"rate": 0.8}, "synthesized_rate": {"mean": 0.76, "sampled": 0.7},
         "naturalness": {"jerk_ratio": 1.1, "foot_sliding_ratio": 1.3},
         "long_worst": {"latent_range": 1.5, "limb_motion_last_over_first": 0.9, "errors": 0}}
    met = synthesis.targets_met(g)
    assert met == {"rate_mean": True, "rate_sampled": False, "jerk": True,
                   "foot_sliding": False, "long_latent_range": True, "long_limb_motion": True}
    g["long_worst"]["errors"] = 1  # a rollout that diverged fails the range target
    assert not synthesis.targets_met(g)["long_latent_range"]


def test_a_bounded_group_must_come_to_rest_and_is_judged_after_its_clean_up():
    """A bounded group's long rollouts must all come to rest (the largest last/first ratio,
    the 50/50 mix's included); where the run cleaned the clips up, rate, jerk and sliding are
    judged on the cleaned clips, the raw ones only reported."""
    g = {"natural_rate": {"rate": 0.5}, "bounded": True, "mapping_noise_floor": 1e-3,
         "synthesized_rate": {"mean": 0.25, "sampled": 0.25},
         "naturalness": {"jerk_ratio": 1.3, "foot_sliding_ratio": 9.0},
         "clean_up": {"legs": True, "synthesized_rate": {"mean": 0.5, "sampled": 0.45},
                      "naturalness": {"jerk_ratio": 1.1, "foot_sliding_ratio": 0.4}},
         "long_worst": {"latent_range": 1.0, "limb_motion_last_over_first": 0.01,
                        "limb_motion_last_over_first_max": 0.04, "judge_p_last200": 0.3,
                        "errors": 0},
         "fit": {"iterations": 10, "converged": False}}
    assert synthesis.targets_met(g) == {"rate_mean": True, "rate_sampled": True, "jerk": True,
                                        "foot_sliding": True, "long_latent_range": True,
                                        "long_at_rest": True}
    g["long_worst"]["limb_motion_last_over_first_max"] = 0.3  # one rollout keeps moving
    g["clean_up"]["naturalness"]["jerk_ratio"] = 1.25
    g["targets_met"] = met = synthesis.targets_met(g)
    assert not met["long_at_rest"] and not met["jerk"] and met["foot_sliding"]
    (row,) = synthesis.headline_rows({"gesture": g}, {"emotions": {}}, 1000)[:1]
    assert "after the clean-up with legs: judge 0.50 / 0.45, jerk ratio 1.25" in row["note"]
    assert "bounded (floor 0.001), limb motion last/first <= 0.30" in row["note"]
    assert row["note"].endswith("group targets not met: jerk, long_at_rest")
    g.pop("clean_up")  # no clean-up: the raw clips are judged
    assert not synthesis.targets_met(g)["foot_sliding"]


def test_by_kind_floors_only_the_bounded_groups():
    cfg = synthesis.BY_KIND
    assert set(cfg.bounded) <= set(cfg.groups) and not set(cfg.bounded) & set(cfg.periodic)
    assert [synthesis.group_floor(n, cfg) for n in cfg.groups] == [
        1e-3 if n in cfg.bounded else 0.0 for n in cfg.groups]
    assert synthesis.group_floor("gesture", synthesis.Settings()) == 0.0


@pytest.mark.parametrize("quick", [False, True])
def test_by_kind_runs_its_own_settings(tmp_path, quick):
    """--by-kind runs BY_KIND (--quick: a small run of the same kinds), never the plain
    settings under the per-kind file's name."""
    out = tmp_path / "k.json"
    synthesis.main(["--by-kind", "--seed", "3", "--root", str(tmp_path / "nowhere"),
                    "--out", str(out)] + (["--quick"] if quick else []))
    cfg = json.loads(out.read_text())["settings"]
    assert cfg["seed"] == 3
    assert cfg["clean_up"] and cfg["handshake_floor"] == 1e-3 and not cfg["extras"]
    assert cfg["bounded"] == (["gesture"] if quick else ["gesture", "gesture-2"])
    assert all(b in cfg["groups"] for b in cfg["bounded"])
    assert cfg["max_iter"] == (synthesis.QUICK.max_iter if quick else 1000)


@pytest.mark.parametrize("bench", [synthesis, foot_contacts, transition_lengths, noise_floor])
def test_missing_data_writes_a_skip_record(tmp_path, bench):
    out = tmp_path / "s.json"
    res = bench.run(True, root=tmp_path / "nowhere", out=out)
    assert "Bandai data not found" in res["skipped"]
    assert json.loads(out.read_text())["skipped"] == res["skipped"]


def test_foot_contacts_scores_are_the_mean_naturalness_ratios():
    from bayesmotion.datasets import load_cmu_handshake
    from bayesmotion.evaluation.naturalness import NaturalnessReference, naturalness

    actors = [a.resample(30.0) for a in load_cmu_handshake().actors]
    ref = NaturalnessReference.from_motions(actors[:1], 30.0)
    got = foot_contacts.scores(actors, ref)
    rows = [naturalness(m, ref) for m in actors]
    assert got["n"] == 2
    for k in foot_contacts.KEYS:
        assert got[k] == pytest.approx((rows[0][k] + rows[1][k]) / 2)
    assert got["foot_sliding_ratio"] == pytest.approx((1.0 + rows[1]["foot_sliding_ratio"]) / 2)


@pytest.mark.parametrize("name", ["synthesis", "foot_contacts", "transition_lengths",
                                  "noise_floor"])
def test_the_benchmark_is_in_the_suite(name):
    import run_all

    assert name in run_all.BENCHMARKS


def test_windowed_probability_scores_consecutive_windows():
    from bayesmotion.baselines import LogisticRegression
    from bayesmotion.datasets import load_cmu_handshake
    from bayesmotion.features import clip_features

    a, b = (m.resample(30.0) for m in load_cmu_handshake().actors)
    wins = [(m, s) for m in (a, b) for s in range(0, 60, 10)]  # 76 frames each
    X = np.stack([clip_features(m.select(slice(s, s + 15))) for m, s in wins])
    judge = LogisticRegression().fit(X, ["a" if m is a else "b" for m, _ in wins])
    starts, p = synthesis.windowed_probability(judge, b, "b", 20)
    np.testing.assert_array_equal(starts, [0, 20, 40])
    col = list(judge.classes).index("b")
    for k, s in enumerate(starts):
        direct = judge.predict_proba(clip_features(b.select(slice(s, s + 20)))[None])[0, col]
        assert p[k] == pytest.approx(direct)


def test_switch_window_is_ranked_among_the_jerkier_sides_windows():
    """The switch window is ranked among the windows of its width on the jerkier side: a
    spike outranks every one of them, a switch as jerky as a flat side outranks none; the
    90th percentile is of the windows' ratios to the side's mean; a side shorter than a
    window gives None."""
    width = 8
    flat = np.full(35, 4.0)
    out = synthesis._side_windows(flat, 16.0, 4.0, width)
    assert out["jerk_switch_rank"] == 1.0
    assert out["jerk_side_windows_q90"] == pytest.approx(1.0)
    assert out["n_side_windows"] == 35 - width + 1
    assert synthesis._side_windows(flat, 4.0, 4.0, width)["jerk_switch_rank"] == 0
    side = np.random.default_rng(0).uniform(1, 3, 35)
    ref = side.mean()
    out = synthesis._side_windows(side, 2.0, ref, width)
    ratios = np.array([np.sqrt(side[k:k + width].mean() / ref)
                       for k in range(side.size - width + 1)])
    assert out["jerk_side_windows_q90"] == pytest.approx(np.quantile(ratios, 0.9))
    assert out["jerk_switch_rank"] == pytest.approx(np.mean(ratios < np.sqrt(2.0 / ref)))
    assert synthesis._side_windows(np.ones(5), 2.0, 1.0, width)["jerk_switch_rank"] is None


def test_transition_row_measures_the_rollout_it_names(tiny_model):
    """A happy -> sad transition on the tiny model: each window's probabilities are the judge's
    on that window of the same (seeded) rollout; the jerkier side's ratio is the smaller of the
    ratios to each side; the latent jump and distance are finite and positive; the summary
    takes the worst emotion of each measure."""
    from bayesmotion.baselines import LogisticRegression
    from bayesmotion.features import clip_features
    from bayesmotion.model.generate import Transition
    from tests.conftest import make_tiny_dataset

    data = make_tiny_dataset()
    judge = LogisticRegression().fit(np.stack([clip_features(t.actors[0]) for t in data]),
                                     [t.labels["emotion"] for t in data])
    T, L, W = 40, 6, 8
    row = synthesis.transition_row(tiny_model, judge, "happy", "sad", T, L, W, 3, 0.0)
    roll = tiny_model.generate(emotion=Transition("happy", "sad", T // 2 - L // 2, L),
                               n_frames=T, seed=3)
    m = roll.to_motion()[0]
    col = list(judge.classes).index("sad")
    for c, p in zip(row["window_centres"], row["p_target"], strict=True):
        a = c - W // 2
        assert p == pytest.approx(judge.predict_proba(
            clip_features(m.select(slice(a, a + W)))[None])[0, col])
    assert row["jerk_switch_over_jerkier_side"] == pytest.approx(
        min(row["jerk_switch_over_before"], row["jerk_switch_over_after"]))
    assert 0 <= row["jerk_switch_rank"] <= 1 and row["n_side_windows"] >= 1
    assert row["latent_step_switch_max_over_median"] > 0
    assert 0 <= row["latent_distance_switch_max"] < np.inf
    matched = synthesis.transition_row(tiny_model, judge, "happy", "sad", T, L, W, 3, 0.0, True)
    assert "the target continues training trial" in matched["start"]
    assert "continues" not in row["start"]
    assert matched["switch"] == T // 2 - L // 2
    # a searched switch is measured where it came: as the same rollout asked to switch there
    searched = synthesis.transition_row(tiny_model, judge, "happy", "sad", T, L, W, 3, 0.0,
                                        True, within=6)
    s0 = T // 2 - L // 2
    assert s0 <= searched["switch"] <= s0 + 6
    there = synthesis.transition_row(tiny_model, judge, "happy", "sad",
                                     T + 2 * (searched["switch"] - s0), L, W, 3, 0.0, True)
    assert there["switch"] == searched["switch"]
    # the two rollouts agree up to the switch window's end, so do the measures read there
    assert searched["jerk_switch_over_before"] == pytest.approx(there["jerk_switch_over_before"],
                                                                rel=1e-9)
    block = {"sad": row, "angry": {**row, "p_target_last_window": 0.1,
                                   "jerk_switch_over_jerkier_side": 9.0,
                                   "jerk_switch_rank": 1.0},
             "happy": {"error": "refused"}}
    s = synthesis.transition_summary(block)
    assert s["errors"] == 1
    assert s["jerk_switch_over_jerkier_side"]["worst"] == 9.0
    assert s["jerk_switch_rank"]["worst"] == 1.0
    head = transition_lengths._headline({"length": L, "lookahead": 0.0, "matched": False,
                                         "summary": s})
    assert head["value"] == 1.0 and head["met"] is False
    assert s["p_target_last_window"]["worst"] == min(0.1, row["p_target_last_window"])


def test_a_transition_meets_the_no_jump_target_only_where_every_emotion_takes(tmp_path):
    """The switch window's rank alone is met by a transition that never reaches its target;
    the headline also asks every emotion's p(target) in the last window to reach 0.5, and
    ``rescore`` rewrites a stored file's headlines that way without measuring again."""
    def row(rank, p):
        return {"p_target_last_window": p, "jerk_switch_over_jerkier_side": 1.0,
                "jerk_switch_rank": rank, "jerk_side_windows_q90": 1.1,
                "jerk_switch_over_elsewhere": 1.0, "latent_step_switch_max_over_median": 1.0,
                "latent_distance_switch_max": 0.1}

    taken = {"happy": row(0.6, 0.87), "sad": row(0.3, 0.93)}
    stuck = {"happy": row(0.4, 0.09), "sad": row(0.3, 0.93)}
    runs = [{"length": 10, "lookahead": 10.0, "matched": m, "within": w, "emotions": b,
             "summary": synthesis.transition_summary(b)}
            for m, w, b in ((True, 12, taken), (False, 0, stuck))]
    heads = [transition_lengths._headline(r) for r in runs]
    assert [h["met"] for h in heads] == [True, False]
    assert heads[1]["value"] == 0.4  # the rank is fine: the happy walk never became happy
    assert "switch searched over 12 frames" in heads[0]["metric"]
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"runs": runs, "headline": [], "targets": {}}))
    out = transition_lengths.rescore(path)
    assert [h["met"] for h in out["headline"]] == [True, False] and "rescored_utc" in out
    assert json.loads(path.read_text())["runs"] == runs



def test_the_walks_transitions_have_a_headline_row_naming_their_kind():
    """The run's walk transitions are judged in its headline as transition_lengths judges
    each kind (every emotion's switch-window rank and p(target)), named by the run's settings:
    the matched, searched transition by default; a result stored before ``transition_match``
    existed made smoothsteps and is named so when rescored."""
    def row(rank, p):
        return {"p_target_last_window": p, "jerk_switch_over_jerkier_side": 1.0,
                "jerk_switch_rank": rank, "jerk_side_windows_q90": 1.1,
                "jerk_switch_over_elsewhere": 1.0, "latent_step_switch_max_over_median": 1.0,
                "latent_distance_switch_max": 0.1}

    g = {"natural_rate": {"rate": 0.6}, "synthesized_rate": {"mean": 0.75, "sampled": 0.7},
         "naturalness": {"jerk_ratio": 1.1, "foot_sliding_ratio": 1.1},
         "long_worst": {"latent_range": 1.2, "limb_motion_last_over_first": 1.0,
                        "judge_p_last200": 0.5, "errors": 0},
         "fit": {"iterations": 10, "converged": False},
         "transitions": {"happy": row(0.84, 0.87), "angry": row(0.57, 0.72),
                         "sad": {"error": "refused"}}}
    g["targets_met"] = synthesis.targets_met(g)
    settings = dataclasses.asdict(synthesis.Settings())
    rows = synthesis.headline_rows({"walks": g}, {"emotions": {}}, 1000, settings)
    trans = [r for r in rows if "switch window" in r["metric"]]
    assert len(trans) == 1 and rows.index(trans[0]) == 1  # after the group's row
    assert trans[0]["metric"].startswith(
        "walks, matched transition, 10-frame blend, switch searched over 12 frames, "
        "look-ahead 10:")
    # the failed emotion leaves the row unmet: every emotion must take
    assert (trans[0]["value"], trans[0]["met"]) == (0.84, False)
    g["transitions"]["sad"] = row(0.31, 0.93)
    (trans,) = [r for r in synthesis.headline_rows({"walks": g}, {"emotions": {}}, 1000,
                                                   settings) if "switch window" in r["metric"]]
    assert trans["met"] is True and "sad: jerk 1.00x" in trans["note"]
    old = {k: v for k, v in settings.items() if not k.startswith("transition_")
           or k == "transition_length"}
    assert synthesis.run_transition_name(old) == "20-frame transition, look-ahead 10"
    # without settings (or without transitions) there is no such row
    assert not [r for r in synthesis.headline_rows({"walks": g}, {"emotions": {}}, 1000)
                if "switch window" in r["metric"]]

def _handshakes(ratios: dict) -> dict:
    rows = {e: {"min_hand_distance": 6.7, "latent_range": 1.2, "motion_last_over_first": v,
                "finite": True} if v is not None else {"error": "diverged"}
            for e, v in ratios.items()}
    return {"fit": {"iterations": 10, "converged": False}, "real_min_hand_distance": 6.6,
            "emotions": rows}


def test_handshakes_must_come_to_rest_in_every_emotion():
    rows = synthesis.headline_rows({}, _handshakes({"neutral": 0.0, "happy": 0.72,
                                                    "angry": 1.01, "sad": 0.01}), 1000)
    rest = rows[-1]
    assert rest["metric"].startswith("built-in handshakes: emotions whose 1000-frame rollout")
    assert (rest["value"], rest["unit"], rest["met"]) == (2, "of 4", False)
    assert rest["note"].startswith("still moving: happy 0.72, angry 1.01;")
    rows = synthesis.headline_rows({}, _handshakes({"neutral": 0.0, "sad": 0.05}), 1000)
    assert (rows[-1]["value"], rows[-1]["met"]) == (2, True)  # the limit itself is at rest
    assert rows[-1]["note"].startswith("still moving: none;")
    # an emotion whose rollout failed is neither at rest nor a pass
    rows = synthesis.headline_rows({}, _handshakes({"neutral": 0.0, "sad": None}), 1000)
    assert (rows[-1]["value"], rows[-1]["unit"], rows[-1]["met"]) == (1, "of 2", False)
    assert "failed: sad" in rows[-1]["note"]
    # a ratio that was not finite (NaN in memory, null once stored) is not at rest either
    for bad in (float("nan"), "null"):
        hs = _handshakes({"neutral": 0.0, "sad": bad})
        if bad == "null":
            hs = json.loads(json.dumps(hs).replace('"null"', "null"))
        rows = synthesis.headline_rows({}, hs, 1000)
        assert (rows[-1]["value"], rows[-1]["met"]) == (1, False)
        assert rows[-1]["note"].startswith("still moving: sad n/a;")
        assert "motion last/first 200 frames 0.00-0.00;" in rows[-2]["note"]
    # every rollout failed: the rest row still says so
    rows = synthesis.headline_rows({}, _handshakes({"neutral": None, "sad": None}), 1000)
    assert len(rows) == 1
    assert (rows[0]["value"], rows[0]["unit"], rows[0]["met"]) == (0, "of 2", False)
    assert "failed: neutral, sad" in rows[0]["note"]


def test_rescore_rebuilds_the_headline_and_keeps_the_measurements(tmp_path):
    stored = json.loads((synthesis.RESULTS / "synthesis.json").read_text())
    path = tmp_path / "synthesis.json"
    path.write_text(json.dumps(stored))
    synthesis.main(["--rescore", "--out", str(path)])
    new = json.loads(path.read_text())
    for key in ("groups", "handshakes", "settings", "machine", "timing_s"):
        assert new[key] == stored[key]
    old_rows = [r for r in stored["headline"] if "comes to rest" not in r["metric"]]
    assert new["headline"][:len(old_rows)] == old_rows  # the other rows are rebuilt as run
    ratios = [r["motion_last_over_first"] for r in stored["handshakes"]["emotions"].values()]
    rest = new["headline"][-1]
    assert rest["value"] == sum(v <= 0.05 for v in ratios)
    assert rest["met"] == all(v <= 0.05 for v in ratios)
    assert "rescored_utc" in new
    assert new["targets"] == {**synthesis.TARGETS, **stored["targets"]}  # as judged
    (tmp_path / "skipped.json").write_text(json.dumps({"status": "skipped"}))
    with pytest.raises(SystemExit, match="no measurements to rescore"):
        synthesis.rescore(tmp_path / "skipped.json")


def test_every_builtin_handshake_trial_ends_in_motion():
    """docs/model.md (long rollouts): each built-in trial is a window that ends mid-handshake,
    so the data hold no rest after a handshake: each actor's limb motion (the benchmark's
    joint_speed) over the last 3 frames is 0.77-1.33 times its trial's mean, median 0.89."""
    from bayesmotion.datasets import load_handshakes

    speeds = [synthesis.joint_speed(m.values) for t in load_handshakes() for m in t.actors]
    ratios = [s[-3:].mean() / s.mean() for s in speeds]
    assert len(ratios) == 48
    np.testing.assert_allclose([min(ratios), np.median(ratios), max(ratios)],
                               [0.7726, 0.8948, 1.3317], atol=5e-4)
