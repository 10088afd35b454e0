"""The CLI's data specifications: a BVH folder with labels.csv."""

import csv

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.data.bvh import write_bvh
from bayesmotion.datasets.loaders import load_data
from bayesmotion.errors import BayesmotionError


def _folder(tmp_path, rows, rates=None):
    """BVH files of the first built-in handshake's actors (at the given frame rates) and a
    labels.csv with ``rows`` (dicts)."""
    trial = bm.load_handshakes(fps=10.0)[0]
    for r in rows:
        m = trial.actors[1 if r.get("actor") == "1" else 0]
        fps = (rates or {}).get(r["file"])
        write_bvh(m.resample(fps) if fps else m, tmp_path / r["file"])
    cols = sorted({k for r in rows for k in r})
    with open(tmp_path / "labels.csv", "w", newline="") as f:
        w = csv.DictWriter(f, cols)
        w.writeheader()
        w.writerows(rows)
    return trial


def test_rows_sharing_a_trial_form_one_trial_ordered_by_actor(tmp_path):
    trial = _folder(tmp_path, [
        {"file": "b.bvh", "emotion": "happy", "couple": "c1", "trial": "t1", "actor": "1"},
        {"file": "a.bvh", "emotion": "happy", "couple": "c1", "trial": "t1", "actor": "0"},
        {"file": "c.bvh", "emotion": "sad", "couple": "c2", "trial": "t2", "actor": "0"},
        {"file": "d.bvh", "emotion": "sad", "couple": "c2", "trial": "t2", "actor": "1"}])
    ds = load_data(str(tmp_path))
    assert len(ds) == 2 and ds[0].n_actors == 2 and ds.levels["emotion"] == ("happy", "sad")
    assert ds[1].labels == {"emotion": "sad", "couple": "c2"}
    for a in range(2):  # actor 0 first although its row came second
        np.testing.assert_allclose(ds[0].actors[a].values, trial.actors[a].values, atol=1e-4)


def test_a_content_column_labels_each_trials_action(tmp_path):
    _folder(tmp_path, [{"file": "a.bvh", "emotion": "happy", "content": "walk", "trial": ""},
                       {"file": "b.bvh", "emotion": "sad", "content": "", "trial": ""}])
    ds = load_data(str(tmp_path))
    assert [t.labels for t in ds] == [{"emotion": "happy", "content": "walk"},
                                      {"emotion": "sad"}]


def test_mixed_frame_rates_are_refused_unless_resampled(tmp_path):
    _folder(tmp_path, [{"file": "a.bvh", "emotion": "happy", "trial": ""},
                       {"file": "b.bvh", "emotion": "sad", "trial": ""}], rates={"b.bvh": 5.0})
    with pytest.raises(BayesmotionError, match="mixes frame rates"):
        load_data(str(tmp_path))
    ds = load_data(str(tmp_path), fps=5.0)
    assert {t.fps for t in ds} == {5.0}


@pytest.mark.parametrize("rows, match", [
    ([{"file": "a.bvh", "emotion": "happy", "trial": "t", "actor": "left"}], "integers"),
    ([{"file": "a.bvh", "emotion": "happy", "trial": "t", "actor": "0"},
      {"file": "b.bvh", "emotion": "happy", "trial": "t", "actor": "0"}], "once each"),
    ([{"file": "a.bvh", "emotion": "happy", "trial": "t", "actor": "0"},
      {"file": "b.bvh", "emotion": "sad", "trial": "t", "actor": "1"}], "disagree on emotion"),
    ([{"file": "a.bvh", "emotion": "happy", "content": "walk", "trial": "t", "actor": "0"},
      {"file": "b.bvh", "emotion": "happy", "content": "bow", "trial": "t", "actor": "1"}],
     "disagree on content"),
])
def test_bad_label_rows_are_named(tmp_path, rows, match):
    _folder(tmp_path, rows)
    with pytest.raises(BayesmotionError, match=match):
        load_data(str(tmp_path))


def test_a_dataset_of_mixed_frame_rates_names_two_trials():
    ds = bm.load_handshakes(fps=10.0)
    mixed = [ds[0], ds[1].resample(5.0)]
    with pytest.raises(BayesmotionError, match=f"{ds[1].name!r} at 5 fps"):
        bm.MotionDataset(mixed)
