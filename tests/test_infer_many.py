"""Batch emotion inference on Dask (bayesmotion.infer_many, 'infer FOLDER'): the same answers as
infer_emotion clip by clip, a table written as clips finish, resumed after an interruption, a
failing clip reported in its row, the model loaded once per worker, and the command line on a
running scheduler's address (the multi-machine path) against a LocalCluster started here."""

import warnings

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.app.cli import main
from bayesmotion.emotion.batch import Table, columns, find_clips, read_table
from bayesmotion.emotion.ood import OutOfDistributionWarning
from bayesmotion.errors import BayesmotionError
from tests.conftest import make_tiny_dataset

distributed = pytest.importorskip("dask.distributed", reason="dask.distributed not installed")

SETTINGS = {"seed": 3, "n_steps": 60}


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Three training handshakes as BVH pairs, and a broken pair."""
    folder = tmp_path_factory.mktemp("clips")
    for i, t in enumerate(make_tiny_dataset().trials[:3]):
        for a, m in enumerate(t.actors):
            bm.write_bvh(m, folder / f"t{i}_actor{a}.bvh")
    (folder / "broken_actor0.bvh").write_text("HIERARCHY\nnot a skeleton\n")
    (folder / "broken_actor1.bvh").write_text("HIERARCHY\nnot a skeleton\n")
    return folder


def test_projection_starts_are_checked_before_any_work(tiny_model, tmp_path):
    """Several level starts without a jitter, and a pad_to that is not a number of frames, are
    refused before a cluster starts or a table is written."""
    with pytest.raises(BayesmotionError, match="level_starts > 1 needs start_jitter > 0"):
        bm.infer_many(tiny_model, [tmp_path / "absent.bvh"], tmp_path / "t.csv", level_starts=2)
    with pytest.raises(BayesmotionError, match="pad_to must be a positive number of frames"):
        bm.infer_many(tiny_model, [tmp_path / "absent.bvh"], tmp_path / "t.csv", pad_to=0)
    assert not (tmp_path / "t.csv").exists()


def test_find_clips_groups_actor_files(tmp_path):
    for name in ("a_actor0", "a_actor1", "b_actor0", "b_actor1"):
        (tmp_path / f"{name}.bvh").write_text("")
    assert find_clips(tmp_path, 2) == {
        c: (str(tmp_path / f"{c}_actor0.bvh"), str(tmp_path / f"{c}_actor1.bvh"))
        for c in ("a", "b")}
    assert list(find_clips(tmp_path, 1)) == ["a_actor0", "a_actor1", "b_actor0", "b_actor1"]
    (tmp_path / "c_actor0.bvh").write_text("")
    with pytest.raises(BayesmotionError, match=r"\['c'\]"):
        find_clips(tmp_path, 2)
    (tmp_path / "loose.bvh").write_text("")
    with pytest.raises(BayesmotionError, match="loose.bvh"):
        find_clips(tmp_path, 2)


def test_table_drops_a_partial_line_and_error_rows(tmp_path):
    cols = columns(["happy", "sad"])
    t = Table(tmp_path / "t.csv", cols)
    t.append(dict.fromkeys(cols, "") | {"clip": "a", "label": "happy"})
    t.append(dict.fromkeys(cols, "") | {"clip": "b", "error": "BVHError: x"})
    with open(tmp_path / "t.csv", "a") as f:
        f.write("c,half a row")  # what a kill mid-write leaves
    assert list(t.finished()) == ["a"]
    assert [r["clip"] for r in read_table(tmp_path / "t.csv")] == ["a"]
    with pytest.raises(BayesmotionError, match="columns"):
        Table(tmp_path / "t.csv", columns(["calm"])).finished()


@pytest.mark.slow
def test_infer_many_answers_as_infer_emotion_and_resumes(tiny_model, clips, client, tmp_path):
    table = tmp_path / "emotions.csv"
    rows = bm.infer_many(tiny_model, clips, table, client=client, progress=False, **SETTINGS)
    assert [r["clip"] for r in rows] == ["broken", "t0", "t1", "t2"]
    broken, good = rows[0], rows[1:]
    assert broken["error"].startswith("BVHError") and broken["label"] == ""
    levels = tiny_model.levels["emotion"]
    for r in good:
        assert r["error"] == ""
        files = r["files"].split(";")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfDistributionWarning)
            ep = bm.infer_emotion(tiny_model, files, **SETTINGS)
        assert r["label"] == ep.label and r["label_set_90"] == ";".join(ep.label_set(0.9))
        np.testing.assert_allclose([r[f"p_{lv}"] for lv in levels], ep.probabilities,
                                   atol=1e-6)
        np.testing.assert_allclose([r[f"mean_{lv}"] for lv in levels], ep.mean, atol=1e-6)
        assert r["out_of_distribution"] == ep.out_of_distribution
        assert r["unseen_levels"] == "" and ep.info["unseen_levels"] == {}
    on_disk = read_table(table)
    assert sorted(r["clip"] for r in on_disk) == ["broken", "t0", "t1", "t2"]
    # the model travelled once and each worker loaded it once
    loaded = client.run(lambda: len(__import__("bayesmotion.model.distributed",
                                               fromlist=["_MODELS"])._MODELS))
    assert sorted(loaded.values()) == [1, 1]

    # an interruption: the table holds one finished row, then half a line
    text = table.read_text().splitlines(keepends=True)
    kept = next(line for line in text[1:] if line.startswith("t1,"))
    table.write_text(text[0] + kept + "t2,/half")
    before = next(r for r in read_table(table) if r["clip"] == "t1")
    again = bm.infer_many(tiny_model, clips, table, client=client, progress=False, **SETTINGS)
    after = read_table(table)
    assert sorted(r["clip"] for r in after) == ["broken", "t0", "t1", "t2"]  # each once
    t1 = next(r for r in again if r["clip"] == "t1")
    assert t1["seconds"] == before["seconds"] and t1["worker"] == before["worker"]  # not redone
    redone = {r["clip"]: r for r in again}
    for r in good:
        if r["clip"] != "t1":
            assert redone[r["clip"]]["label"] == r["label"]
    assert redone["broken"]["error"].startswith("BVHError")  # tried again, fails again


@pytest.mark.slow
def test_cli_infers_a_folder_on_a_running_scheduler(tiny_model, clips, client, tmp_path,
                                                   capsys):
    model = tmp_path / "m.npz"
    tiny_model.save(model)
    table = tmp_path / "out.csv"
    assert main(["infer", str(model), str(clips), "--scheduler", client.scheduler.address,
                 "--table", str(table), "--seed", "3"]) == 0
    out = capsys.readouterr()
    assert "4 clips, 1 failed" in out.out and "broken" in out.err
    rows = read_table(table)
    assert {r["clip"] for r in rows if r["label"]} == {"t0", "t1", "t2"}
    assert main(["infer", str(model), str(clips), "--workers", "0"]) == 2
