"""Command line: help, bad inputs give one readable line and exit code 2, the demo's files."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.app.cli import main
from tests._browser import browser_check


def run(*args):
    return subprocess.run([sys.executable, "-m", "bayesmotion", *args], capture_output=True,
                          text=True, timeout=600)


def test_help_lists_commands_and_examples():
    r = run("--help")
    assert r.returncode == 0
    listed = re.findall(r"^  (\w+)\s{2,}\S", r.stdout.split("Commands:")[1].split("\n\n")[0],
                        flags=re.M)
    assert listed == ["demo", "fit", "sample", "generate", "infer", "evaluate", "view"]
    r = run("generate", "--help")
    assert "example: bayesmotion generate" in r.stdout


def one_line_error(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert err[0].startswith("error: ") and err[1].startswith("hint: ") and len(err) == 2
    assert "Traceback" not in "\n".join(err)
    return err[0]


def test_bad_inputs_give_one_line_errors(capsys, tmp_path, tiny_model):
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    assert "no such model file" in one_line_error(capsys, ["sample", str(tmp_path / "x.npz"),
                                                           "--out", str(tmp_path / "p.nc")])
    junk = tmp_path / "junk.npz"
    junk.write_text("not a model")
    assert "not a bayesmotion model" in one_line_error(
        capsys, ["generate", str(junk), "--out", str(tmp_path)])
    assert "unknown emotion 'furious'" in one_line_error(
        capsys, ["generate", str(model), "--emotion", "furious", "--out", str(tmp_path)])
    assert "no such file" in one_line_error(capsys, ["infer", str(model), "missing.bvh"])
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    assert "line" in one_line_error(capsys, ["infer", str(model), str(bad)])
    one_bvh = tmp_path / "one.bvh"
    from bayesmotion import load_cmu_handshake, write_bvh

    write_bvh(load_cmu_handshake().actors[0].select(slice(0, 20)), one_bvh)
    assert "2 actor" in one_line_error(capsys, ["infer", str(model), str(one_bvh)])
    assert "no such file or folder" in one_line_error(
        capsys, ["fit", str(tmp_path / "nowhere"), "--out", str(tmp_path / "m2.npz")])
    assert "unknown built-in" in one_line_error(
        capsys, ["fit", "builtin:dances", "--out", str(tmp_path / "m2.npz")])


@pytest.mark.slow
def test_generate_writes_bvh_and_reports(capsys, tmp_path, tiny_model):
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    assert main(["generate", str(model), "--emotion", "0.5,0.5", "--frames", "12",
                 "--samples", "1", "--out", str(tmp_path / "gen")]) == 0
    assert len(list((tmp_path / "gen").glob("*.bvh"))) == 4
    assert main(["generate", str(model), "--emotion", "happy", "--frames", "12", "--samples",
                 "1", "--sample-memory", "8", "--out", str(tmp_path / "gen_path")]) == 0
    assert len(list((tmp_path / "gen_path").glob("*.bvh"))) == 4
    assert main(["generate", str(model), "--emotion", "happy", "--frames", "12", "--samples",
                 "1", "--pin-feet", "--out", str(tmp_path / "gen_pinned")]) == 0
    pinned = bm.load_rollout(tmp_path / "gen_pinned" / "happy_rollout.npz")
    plain = tiny_model.generate(emotion="happy", n_frames=12, n_samples=1).pin_feet()
    np.testing.assert_allclose(pinned.angles, plain.angles, atol=1e-6)
    assert main(["generate", str(model), "--emotion", "happy", "--frames", "12", "--samples",
                 "1", "--pin-legs", "--out", str(tmp_path / "gen_legs")]) == 0
    legs = bm.load_rollout(tmp_path / "gen_legs" / "happy_rollout.npz")
    np.testing.assert_allclose(legs.angles, tiny_model.generate(
        emotion="happy", n_frames=12, n_samples=1).pin_feet(legs=True).angles, atol=1e-6)
    assert main(["generate", str(model), "--emotion", "happy", "--frames", "12",
                 "--lookahead", "5", "--out", str(tmp_path / "gen_guided")]) == 0
    guided = bm.load_rollout(tmp_path / "gen_guided" / "happy_rollout.npz")
    np.testing.assert_allclose(guided.I, tiny_model.generate(emotion="happy", n_frames=12,
                                                             lookahead=5.0).I, atol=1e-9)
    assert main(["generate", str(model), "--emotion", "0.7,0.3", "--frames", "12",
                 "--dynamics-style", "nearest", "--out", str(tmp_path / "gen_nearest")]) == 0
    near = bm.load_rollout(tmp_path / "gen_nearest" / "0.7_0.3_rollout.npz")
    np.testing.assert_allclose(near.Y, tiny_model.generate(
        emotion=[0.7, 0.3], n_frames=12, dynamics_style="nearest").Y, atol=1e-9)
    assert main(["generate", str(model), "--emotion", "0.7,0.3", "--frames", "12",
                 "--dynamics-style", "registered", "--out", str(tmp_path / "gen_reg")]) == 0
    reg = bm.load_rollout(tmp_path / "gen_reg" / "0.7_0.3_rollout.npz")
    np.testing.assert_allclose(reg.Y, tiny_model.generate(
        emotion=[0.7, 0.3], n_frames=12, dynamics_style="registered").Y, atol=1e-9)
    assert "lookahead must be a finite number >= 0" in one_line_error(
        capsys, ["generate", str(model), "--lookahead", "-1", "--out", str(tmp_path)])
    assert "--sample-memory must be an integer in [0, 256]" in one_line_error(
        capsys, ["generate", str(model), "--sample-memory", "-1", "--out", str(tmp_path)])
    assert "n_samples is 0" in one_line_error(
        capsys, ["generate", str(model), "--sample-memory", "8", "--out", str(tmp_path)])
    clips = [str(p) for p in sorted((tmp_path / "gen").glob("*mean_actor*.bvh"))]
    assert len(clips) == 2
    capsys.readouterr()
    assert main(["infer", str(model), *clips, "--json", "--likelihood-power", "0.5"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["likelihood_power"] == 0.5 and out["label"] in out["levels"]
    assert out["unseen_levels"] == {}  # carried; one couple, both emotions in training
    assert "likelihood_power" in one_line_error(
        capsys, ["infer", str(model), *clips, "--likelihood-power", "0"])
    assert out["emotion_starts"] == "vertices"  # the default
    assert main(["infer", str(model), *clips, "--json", "--emotion-starts", "levels"]) == 0
    many = json.loads(capsys.readouterr().out)
    assert main(["infer", str(model), *clips, "--json", "--emotion-starts", "nearest"]) == 0
    near = json.loads(capsys.readouterr().out)
    assert many["emotion_starts"] == "levels" and near["emotion_starts"] == "nearest"
    # the nearest-frame start is among the level starts: the best optimum is never worse
    assert many["map_objective"] <= near["map_objective"] + 1e-9
    assert out["level_starts"] == 1  # the default
    assert main(["infer", str(model), *clips, "--json", "--level-starts", "2",
                 "--start-jitter", "0.02"]) == 0
    assert json.loads(capsys.readouterr().out)["level_starts"] == 2
    assert "--level-starts" in one_line_error(
        capsys, ["infer", str(model), *clips, "--level-starts", "0"])
    assert "--level-starts > 1 needs" in one_line_error(
        capsys, ["infer", str(model), *clips, "--level-starts", "2", "--emotion-starts",
                 "nearest"])
    assert out["start_jitter"] == 0.0  # the default
    assert main(["infer", str(model), *clips, "--json", "--start-jitter", "0.02"]) == 0
    assert json.loads(capsys.readouterr().out)["start_jitter"] == 0.02
    assert out["staged_start"] is False  # the default
    assert main(["infer", str(model), *clips, "--json", "--staged-start"]) == 0
    staged = json.loads(capsys.readouterr().out)
    assert staged["staged_start"] is True
    assert staged["map_objective"] != out["map_objective"]  # another start, another path
    assert "--start-jitter" in one_line_error(
        capsys, ["infer", str(model), *clips, "--start-jitter", "-1"])
    assert "--level-starts > 1 needs --start-jitter > 0" in one_line_error(
        capsys, ["infer", str(model), *clips, "--level-starts", "3"])
    assert out["max_iter"] == 400  # infer_emotion's default
    assert main(["infer", str(model), *clips, "--json", "--max-iter", "3"]) == 0
    short = json.loads(capsys.readouterr().out)
    # three iterations per projection stop far from the default's optimum
    assert short["max_iter"] == 3 and short["map_objective"] > out["map_objective"]


@pytest.mark.slow
@pytest.mark.optimized
def test_demo_quick_writes_every_file(tmp_path):
    out = tmp_path / "demo"
    r = run("demo", "--quick", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    for name in ("report.html", "summary.json", "model.npz", "posterior.nc"):
        assert (out / name).stat().st_size > 0, name
    assert len(list(out.glob("*.gif"))) == 4
    assert len(list((out / "bvh").glob("*.bvh"))) == 8
    s = json.loads((out / "summary.json").read_text())
    for key in ("fit", "posterior", "generation", "interpolation", "inference"):
        assert key in s
    # the fit says whether it converged, and the report why the demo stops where it does
    assert s["fit"]["convergence_note"].startswith(
        "converged after" if s["fit"]["converged"] else "not converged: stopped at its "
                                                        "iteration limit after 150 iterations")
    if not s["fit"]["converged"]:
        assert "quick demo stops its fit at 150 iterations" in (out / "report.html").read_text()
    assert {"max_rhat", "min_ess_bulk", "mean_acceptance"} <= set(s["posterior"])
    # the quick posterior (hyperparameters, styles held at the MAP) converges in its budget
    assert s["posterior"]["style_vectors"] == "held at the MAP"
    assert s["posterior"]["max_rhat"] <= 1.05 and s["posterior"]["min_ess_bulk"] >= 400
    assert "style vectors held at the MAP" in (out / "report.html").read_text()
    assert 0 <= s["inference"]["accuracy"] <= 1
    assert 0 <= s["inference"]["hpd90_covers_truth"] <= 1
    assert 0 <= s["interpolation"]["hpd90_coverage"] <= 1
    first = s["inference"]["position_coverage_first_second"]
    assert 0 <= first["0.5"] <= first["0.9"] <= 1
    bins = s["inference"]["position_coverage_by_horizon"]
    assert bins[0]["from_s"] == 0 and len(bins) >= 2
    on = s["online"]
    assert on["fractions"] == [0.25, 0.5, 1.0] and len(on["mean_coordinate_entropy"]) == 3
    assert np.all(np.isfinite(on["mean_coordinate_entropy"]))
    assert on["entropy_decreases"] == (on["mean_coordinate_entropy"][-1]
                                       < on["mean_coordinate_entropy"][0])
    assert s["seconds_total"] > 0
    # the report's viewer: the four emotions' posterior-predictive handshakes and the five
    # interpolation steps, working in a real browser
    seen = browser_check(out / "report.html", tmp_path)
    assert seen["errors"] == [] and seen["options"] == 4 + 5
    assert seen["played"] and seen["turned"] and seen["switched"]


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::bayesmotion.inference.posterior.ChainTooShortWarning")
def test_full_demo_samples_the_whole_posterior(tmp_path, monkeypatch):
    """The full demo samples the style vectors with the hyperparameters (one chain, the one the
    generation uses) and says so, on a tiny configuration."""
    import bayesmotion.app.demo as demo

    tiny = {**demo.SETTINGS["full"], "fps": 5.0, "max_iter": 10, "n_steps": 20, "n_draws": 1,
            "n_samples": 1, "infer_steps": 10, "gif_stride": 4}
    monkeypatch.setitem(demo.SETTINGS, "full", tiny)
    s = demo.run_demo(tmp_path / "out", quick=False)
    p = s["posterior"]
    assert p["style_vectors"] == "sampled" and p["n_steps"] == 20
    # the couple's and the emotions' style coordinates beside the 12 hyperparameters
    assert p["n_coordinates"] > 12 and {"max_rhat", "min_ess_bulk"} <= set(p)
    report = (tmp_path / "out" / "report.html").read_text()
    assert "The whole posterior over the hyperparameters and the training style vectors" in report
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["posterior"][
        "n_steps"] == 20


@pytest.mark.slow
def test_sample_output_is_tidy(tmp_path, tiny_model):
    """Labelled progress bars; the run's pace and time left as one line; the package's warning
    as one line; no dependency's deprecation notice (arviz announces its refactor with a
    FutureWarning when imported)."""
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    r = run("sample", str(model), "--steps", "30", "--out", str(tmp_path / "p.nc"))
    assert r.returncode == 0, r.stderr[-2000:]
    assert "emcee, sampling (" in r.stderr
    said = [x for x in r.stderr.replace("\r", "\n").splitlines() if x.startswith("emcee: ")]
    assert len(said) == 1 and re.fullmatch(r"emcee: \S+ s per step over \d+ steps; the \d+ "
                                           r"steps left take about \S+ (s|min|h)", said[0])
    assert re.search(r"30 steps in \S+ (s|min|h)$", r.stdout.strip())
    lines = [x for x in r.stderr.replace("\r", "\n").splitlines()
             if x.strip() and not x.startswith(("emcee, ", "emcee: ", "MAP fit"))]  # the bars
    assert lines == [x for x in lines if x.startswith("warning: ")]  # nothing else on stderr
    assert any("shorter than 50 autocorrelation times" in x for x in lines)
    assert "FutureWarning" not in r.stderr and "ArviZ" not in r.stderr
    debug = run("--debug", "sample", str(model), "--steps", "30", "--out",
                str(tmp_path / "q.nc"))
    assert "ChainTooShortWarning" in debug.stderr  # --debug: every warning as Python shows it


def test_sample_passes_its_sampler_flags(tmp_path, tiny_model, monkeypatch):
    import bayesmotion.app.cli as cli

    seen = {}

    def fake(model, **kw):
        seen.update(kw)
        raise RuntimeError("stop")  # stop before sampling: only the arguments are checked

    monkeypatch.setattr(cli, "sample_posterior", fake)
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    for flags, want in (([], (False, False, None, False)), (["--hmc"], (True, False, None, False)),
                        (["--factorise"], (False, True, None, False)),
                        (["--no-independence"], (False, False, False, False)),
                        (["--fix-styles"], (False, False, None, True))):
        seen.clear()
        assert main(["sample", str(model), "--out", str(tmp_path / "p.nc"), *flags]) != 0
        assert (seen["hmc"], seen["factorise"], seen["independence"],
                seen["fix_styles"]) == want


def test_fit_says_whether_it_converged(capsys, tmp_path):
    """`bayesmotion fit` reports the fit's convergence in words (optim.minimize's
    convergence_note): a fit stopped at its iteration limit says so."""
    out = tmp_path / "m.npz"
    assert main(["fit", "builtin:handshakes", "--fps", "5", "--max-iter", "3",
                 "--latent-dim", "2", "--interaction-dim", "2", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "not converged: stopped at its iteration limit after 3 iterations" in printed
    assert out.stat().st_size > 0


def test_fit_takes_a_mapping_noise_floor(capsys, tmp_path):
    out = tmp_path / "m.npz"
    assert main(["fit", "builtin:handshakes", "--fps", "5", "--max-iter", "3",
                 "--latent-dim", "2", "--interaction-dim", "2", "--mapping-noise-floor",
                 "0.01", "--out", str(out)]) == 0
    m = bm.load(out)
    assert m.spec.mapping_noise_floor == 0.01
    for k in ("gamma", "beta"):  # the noise variance is the floor plus the stored free part
        free = np.exp(-m.params["log_" + k][2])
        assert 1 / m.hyperparameters[k][2] == pytest.approx(0.01 + free, rel=1e-12)

