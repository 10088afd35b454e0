"""The command line's contract for bad input: exit 2 within 5 s, one error line and a hint on
stderr, and nothing written (the working folder's contents are the same before and after).

Each case is a reported failure or its neighbour: numbers out of range (a 23 GB fit at
--fps 1e9, an XLA abort at --samples 100000000, MemoryError after minutes at --frames 10000000
or --steps 10000000, --max-iter -5 and --fps 0 that exited 0), output paths that cannot be
written (found before the fit, not after), a Latin-1 labels.csv, and a model evaluated on data
it was not fitted on. The memory guard compares its estimate with the memory available, which
is fixed here at 16 GiB (``available_memory`` patched) so that the outcome does not depend on
the machine running the tests.
"""

import contextlib
import hashlib
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from bayesmotion import validate
from bayesmotion.app.cli import main

LIMIT_S = 5.0
GIB = 2**30


@pytest.fixture(autouse=True)
def sixteen_gib(monkeypatch):
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: 16 * GIB)


@pytest.fixture(scope="module")
def saved_model(tiny_model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.npz"
    tiny_model.save(path)
    return path


@pytest.fixture
def work(tmp_path, saved_model):
    """A working folder holding the model, a file, a folder and a Latin-1 labelled dataset."""
    shutil.copyfile(saved_model, tmp_path / "m.npz")
    (tmp_path / "afile").write_text("not a folder\n")
    (tmp_path / "adir").mkdir()
    _latin1_dataset(tmp_path / "latin")
    return tmp_path


def _latin1_dataset(folder):
    from bayesmotion import load_cmu_handshake, write_bvh

    folder.mkdir()
    h = load_cmu_handshake()
    for a, name in enumerate(("a.bvh", "b.bvh")):
        write_bvh(h.actors[a].select(slice(0, 30)), folder / name)
    (folder / "labels.csv").write_bytes("file,emotion,trial,actor\na.bvh,fröhlich,t1,0\n"
                                        "b.bvh,fröhlich,t1,1\n".encode("latin-1"))


def snapshot(folder) -> dict:
    """Every path under ``folder`` with a hash of its bytes (folders: None)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for d in dirs:
            out[os.path.relpath(os.path.join(root, d), folder)] = None
        for f in files:
            p = os.path.join(root, f)
            out[os.path.relpath(p, folder)] = hashlib.sha256(Path(p).read_bytes()).hexdigest()
    return out


def refused(capsys, folder, argv) -> str:
    """Run ``main(argv)`` in ``folder``; check the contract; return the error line."""
    before = snapshot(folder)
    capsys.readouterr()
    with contextlib.chdir(folder):
        t0 = time.perf_counter()
        code = main(argv)
        seconds = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 2 and err[0].startswith("error: ") and err[1].startswith("hint: "), err
    assert "Traceback" not in err[0]
    assert seconds < LIMIT_S, f"{argv}: {seconds:.1f} s"
    assert snapshot(folder) == before, "the command wrote into the folder"
    return err[0]


FIT = ["fit", "builtin:handshakes"]
GEN = ["generate", "m.npz", "--emotion", "happy"]

CASES = {
    # name: (argv, words the error line must hold)
    "fit --fps 1e9": (FIT + ["--fps", "1e9", "--max-iter", "1", "--out", "n.npz"], "--fps"),
    "fit --fps 0": (FIT + ["--fps", "0", "--out", "n.npz"], "--fps must be"),
    "fit --fps -20": (FIT + ["--fps", "-20", "--out", "n.npz"], "--fps must be"),
    "fit --fps nan": (FIT + ["--fps", "nan", "--out", "n.npz"], "--fps must be"),
    "fit --fps inf": (FIT + ["--fps", "inf", "--out", "n.npz"], "--fps must be"),
    "fit --fps above the data's rate": (FIT + ["--fps", "500", "--out", "n.npz"],
                                        "data's own frame rate (120 fps)"),
    "fit --fps not a number": (FIT + ["--fps", "fast", "--out", "n.npz"], "--fps"),
    "fit --max-iter -5": (FIT + ["--max-iter", "-5", "--out", "n.npz"], "--max-iter"),
    "fit --max-iter 0": (FIT + ["--max-iter", "0", "--out", "n.npz"], "--max-iter"),
    "fit --latent-dim 0": (FIT + ["--latent-dim", "0", "--out", "n.npz"], "--latent-dim"),
    "fit --interaction-dim -1": (FIT + ["--interaction-dim", "-1", "--out", "n.npz"],
                                 "--interaction-dim"),
    "fit --latent-dim huge": (FIT + ["--latent-dim", "100000000000", "--out", "n.npz"],
                              "memory"),
    "fit --mapping-noise-floor -1": (FIT + ["--mapping-noise-floor", "-1", "--out", "n.npz"],
                                     "--mapping-noise-floor must be"),
    "fit --mapping-noise-floor 2": (FIT + ["--mapping-noise-floor", "2", "--out", "n.npz"],
                                    "--mapping-noise-floor must be"),
    "fit --mapping-noise-floor nan": (FIT + ["--mapping-noise-floor", "nan", "--out",
                                             "n.npz"], "--mapping-noise-floor must be"),
    "fit --out DIR": (FIT + ["--out", "adir"], "is a folder"),
    "fit --out under a file": (FIT + ["--out", "afile/n.npz"], "afile is a file"),
    "fit --out deep under a file": (FIT + ["--out", "afile/x/y/n.npz"], "afile is a file"),
    "fit Latin-1 labels.csv": (["fit", "latin", "--out", "n.npz"], "must be UTF-8"),
    "fit missing data": (["fit", "nowhere", "--out", "n.npz"], "no such file or folder"),
    "fit without --out": (FIT, "--out"),
    "generate --samples 100000000": (GEN + ["--frames", "5", "--samples", "100000000",
                                            "--out", "g"], "memory"),
    "generate --frames 10000000": (GEN + ["--frames", "10000000", "--out", "g"], "memory"),
    "generate --frames 2.5": (GEN + ["--frames", "2.5", "--out", "g"], "--frames"),
    "generate --frames 2 (the order)": (GEN + ["--frames", "2", "--out", "g"], "order"),
    "generate --frames -4": (GEN + ["--frames", "-4", "--out", "g"], "--frames"),
    "generate --samples -1": (GEN + ["--samples", "-1", "--out", "g"], "--samples"),
    "generate --seed -1": (GEN + ["--seed", "-1", "--out", "g"], "--seed"),
    "generate --seed 2**70": (GEN + ["--seed", str(2**70), "--out", "g"], "--seed"),
    "generate --emotion 1e150": (["generate", "m.npz", "--emotion", "1e150,-1e150",
                                  "--out", "g"], "within"),
    "generate --emotion nan": (["generate", "m.npz", "--emotion", "nan,1", "--out", "g"],
                               "finite"),
    "generate --emotion inf": (["generate", "m.npz", "--emotion", "inf,0", "--out", "g"],
                               "finite"),
    "generate --emotion labels": (["generate", "m.npz", "--emotion", "happy,sad",
                                   "--out", "g"], "--emotion"),
    "generate --out FILE": (GEN + ["--out", "afile"], "is a file"),
    "generate --out under a file": (GEN + ["--out", "afile/g"], "afile is a file"),
    "generate missing model": (["generate", "none.npz", "--out", "g"], "none.npz"),
    "sample --steps 10000000": (["sample", "m.npz", "--steps", "10000000", "--out", "p.nc"],
                                "memory"),
    "sample --steps -1": (["sample", "m.npz", "--steps", "-1", "--out", "p.nc"], "--steps"),
    "sample --steps 0": (["sample", "m.npz", "--steps", "0", "--out", "p.nc"], "--steps"),
    "sample --walkers 0": (["sample", "m.npz", "--walkers", "0", "--out", "p.nc"],
                           "--walkers"),
    "sample --out DIR": (["sample", "m.npz", "--out", "adir"], "is a folder"),
    "sample --backend DIR": (["sample", "m.npz", "--out", "p.nc", "--backend", "adir"],
                             "is a folder"),
    "sample --backend is --out": (["sample", "m.npz", "--out", "p.nc", "--backend", "p.nc"],
                                  "same file"),
    "sample --backend not HDF5": (["sample", "m.npz", "--out", "p.nc", "--backend", "afile"],
                                  "afile"),
    "infer missing clip": (["infer", "m.npz", "missing.bvh"], "no such file"),
    "infer a folder with no clip": (["infer", "m.npz", "adir"], "holds no .bvh file"),
    "infer a folder among clips": (["infer", "m.npz", "adir", "latin/a.bvh"],
                                   "not a regular file"),
    "infer --seed -1": (["infer", "m.npz", "latin/a.bvh", "latin/b.bvh", "--seed", "-1"],
                        "--seed"),
    "infer --likelihood-power nan": (["infer", "m.npz", "latin/a.bvh", "latin/b.bvh",
                                      "--likelihood-power", "nan"], "likelihood_power"),
    "infer --max-iter 0": (["infer", "m.npz", "latin/a.bvh", "latin/b.bvh", "--max-iter", "0"],
                           "--max-iter"),
    "evaluate --max-iter -3": (["evaluate", "m.npz", "builtin:handshakes", "--max-iter", "-3"],
                               "--max-iter"),
    "evaluate --refit-iter -1": (["evaluate", "m.npz", "builtin:handshakes", "--refit-iter",
                                  "-1"], "--refit-iter"),
    "evaluate --json DIR": (["evaluate", "m.npz", "builtin:handshakes", "--json", "adir"],
                            "is a folder"),
    "evaluate other levels": (["evaluate", "m.npz", "builtin:handshakes"],
                              "emotion levels ['happy', 'sad']"),
    "evaluate Latin-1 labels.csv": (["evaluate", "m.npz", "latin"], "must be UTF-8"),
    "evaluate --save-calibrated without --calibrate": (
        ["evaluate", "m.npz", "builtin:handshakes", "--save-calibrated", "c.npz"],
        "needs --calibrate"),
    "evaluate --save-calibrated DIR": (["evaluate", "m.npz", "builtin:handshakes",
                                        "--calibrate", "--save-calibrated", "adir"],
                                       "is a folder"),
    "demo --out FILE": (["demo", "--quick", "--out", "afile"], "is a file"),
    "demo --out under a file": (["demo", "--quick", "--out", "afile/demo"], "afile is a file"),
    "demo --seed -1": (["demo", "--quick", "--seed", "-1", "--out", "d"], "--seed"),
    "unknown flag": (["generate", "m.npz", "--out", "g", "--colour", "red"], "--colour"),
    "unknown command": (["dance"], "dance"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(capsys, work, name):
    argv, words = CASES[name]
    line = refused(capsys, work, argv)
    assert words in line, line


def test_a_steps_error_names_no_missing_backend(capsys, work):
    line = refused(capsys, work, ["sample", "m.npz", "--steps", "-1", "--out", "p.nc"])
    assert "None" not in line


def test_the_memory_message_gives_the_estimate_the_limit_and_the_way_out(capsys, work,
                                                                         tiny_model):
    line = refused(capsys, work, GEN + ["--frames", "10000000", "--out", "g"])
    assert "16 GiB available" in line and "--no-memory-check" in line
    joints = sum(tiny_model.skeleton(a).n_joints for a in range(2))
    need = validate.generate_memory(10_000_000, 0, joints, 54, 4)
    assert f"{need / 2**30:.3g} GiB" in line


def test_no_memory_check_lets_a_request_past_the_guard(capsys, work, monkeypatch):
    """With --no-memory-check the request reaches the generator (stopped there: it would run
    for minutes)."""
    import bayesmotion.model.generate as gen

    def stop(*a, **k):
        raise KeyboardInterrupt  # the CLI's exit 130: the guard let the request through

    monkeypatch.setattr(gen, "check_decodes", stop)
    with contextlib.chdir(work):
        assert main(GEN + ["--frames", "10000000", "--out", "g", "--no-memory-check"]) == 130
        assert main(GEN + ["--frames", "10000000", "--out", "g"]) == 2


def test_the_fit_memory_guard_counts_the_loaded_frames(capsys, work, monkeypatch):
    """A fit whose kernels exceed the memory is refused after loading, before fitting."""
    monkeypatch.setattr(validate, "available_memory", lambda *a, **k: 2**20)
    line = refused(capsys, work, FIT + ["--fps", "10", "--out", "n.npz"])
    assert "fitting 408 frames" in line and "1 MiB available" in line


def test_data_of_another_skeleton_or_trials_is_refused_by_evaluate(capsys, work, tiny_model):
    """The model's trials and skeleton against a dataset: a different joint name, then the
    same skeleton with other trials."""
    from bayesmotion import load_cmu_handshake, write_bvh

    data = work / "other"
    data.mkdir()
    h = load_cmu_handshake()
    for a, name in enumerate(("a.bvh", "b.bvh")):
        write_bvh(h.actors[a].select(slice(0, 60)), data / name)
    (data / "labels.csv").write_text("file,emotion,couple,trial,actor\n"
                                     "a.bvh,happy,c1,t1,0\nb.bvh,happy,c1,t1,1\n"
                                     "a.bvh,sad,c1,t2,0\nb.bvh,sad,c1,t2,1\n")
    line = refused(capsys, work, ["evaluate", "m.npz", "other"])
    assert "fitted on 6 trials, the data hold 2" in line
    text = (data / "a.bvh").read_text()
    (data / "a.bvh").write_text(text.replace("JOINT LeftUpLeg", "JOINT LeftThigh"))
    line = refused(capsys, work, ["evaluate", "m.npz", "other"])
    assert "actor 0 skeleton differs" in line and "'LeftThigh'" in line


@pytest.fixture
def read_only_dir(tmp_path):
    """A folder nobody may create files in: mode 0o555, and, for root (who ignores modes),
    the immutable attribute (``chattr +i``)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    immutable = False
    if os.geteuid() == 0:
        if shutil.which("chattr") is None or subprocess.run(
                ["chattr", "+i", str(ro)], capture_output=True).returncode != 0:
            ro.chmod(0o755)
            pytest.skip("running as root without chattr: no folder is read-only to us")
        immutable = True
    try:
        yield ro
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(ro)], check=True)
        ro.chmod(0o755)


@pytest.mark.parametrize("argv", [FIT + ["--out", "ro/n.npz"], FIT + ["--out", "ro/sub/n.npz"],
                                  GEN + ["--out", "ro/g"], GEN + ["--out", "ro"],
                                  ["demo", "--quick", "--out", "ro/demo"],
                                  ["sample", "m.npz", "--out", "ro/p.nc"]])
def test_a_read_only_folder_is_found_before_any_work(capsys, work, read_only_dir, argv):
    assert read_only_dir.parent == work
    line = refused(capsys, work, argv)
    assert "permission denied" in line or "not writable" in line, line
