"""Bandai loader: labels, filters and resampling on synthetic folders (always run) and on the
real dataset (skipped when ../shared/data is absent)."""

import numpy as np
import pytest

from bayesmotion.data.bvh import read_bvh
from bayesmotion.datasets.bandai import EMOTION_ORDER, WALK_CONTENTS, bandai_files, load_bandai
from bayesmotion.errors import BayesmotionError

TINY = """HIERARCHY
ROOT root
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tEnd Site
\t{
\t\tOFFSET 0 1 0
\t}
}
MOTION
Frames: 4
Frame Time: 0.0333333
0 0 0 0 0 0
1 0 0 0 0 0
2 0 0 0 0 0
3 0 0 0 0 0
"""


@pytest.fixture
def fake_root(tmp_path):
    """A synthetic folder laid out like the dataset (own BVH text, no Bandai content)."""
    data = tmp_path / "data"
    data.mkdir()
    for content in ("walk", "walk-back", "bow"):
        for style in ("sad", "normal", "proud", "angry", "happy"):
            (data / f"dataset-1_{content}_{style}_001.bvh").write_text(TINY)
    (data / "notes.bvh").write_text(TINY)  # not a dataset clip: ignored
    (data / "dataset-1_walk_normal_001.json").write_text("{}")
    return tmp_path


def test_labels_and_level_order_on_synthetic_folder(fake_root):
    d = load_bandai(fake_root)
    assert len(d) == 15 and d.n_actors == 1
    assert d.levels["emotion"] == ("neutral", "happy", "angry", "sad", "proud")
    assert d.levels["content"] == ("bow", "walk", "walk-back")
    assert d.levels["id"] == ("001",)
    t = next(t for t in d if t.name == "dataset-1_walk-back_normal_001")
    assert t.labels == {"emotion": "neutral", "content": "walk-back", "id": "001"}
    assert t.actors[0].fps == 30.0 and t.actors[0].name == t.name


def test_root_may_be_the_data_folder_itself(fake_root):
    assert [t.name for t in load_bandai(fake_root / "data")] == [t.name for t in
                                                                 load_bandai(fake_root)]
    assert len(bandai_files(fake_root)) == 15


def test_filters_on_synthetic_folder(fake_root):
    assert len(load_bandai(fake_root, content="walk")) == 5
    d = load_bandai(fake_root, content=["walk", "bow"], style=["sad", "normal"])
    assert sorted(d.labels("emotion")) == ["neutral", "neutral", "sad", "sad"]
    assert d.levels["emotion"] == ("neutral", "sad")
    by_emotion = load_bandai(fake_root, style="neutral")  # emotion name works as a style filter
    assert [t.name for t in by_emotion] == [t.name for t in load_bandai(fake_root, style="normal")]


def test_resampling(fake_root):
    d = load_bandai(fake_root, content="bow", fps=15)
    assert d.fps == 15.0
    np.testing.assert_array_equal(d[0].actors[0].values[:, 0], [0, 2])


def test_errors_name_the_problem(fake_root, tmp_path):
    with pytest.raises(BayesmotionError, match="Bandai dataset folder not found: .*nowhere"):
        load_bandai(tmp_path / "nowhere")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BayesmotionError, match="no Bandai clip .* in .*empty"):
        load_bandai(empty)
    with pytest.raises(BayesmotionError,
                       match=r"content=\['wlak'\]; the folder has content in \['bow', 'walk'"):
        load_bandai(fake_root, content="wlak")
    with pytest.raises(BayesmotionError, match=r"style=\['bored'\].*or their emotion names"):
        load_bandai(fake_root, content="walk", style="bored")


# ---------------------------------------------------------------------------- real data
@pytest.fixture(scope="module")
def bandai(bandai_root):
    return load_bandai(bandai_root)


def test_real_dataset_shape(bandai):
    assert len(bandai) == 40 and bandai.n_actors == 1
    assert bandai.levels["emotion"] == EMOTION_ORDER
    assert len(bandai.levels["content"]) == 10
    cells = sorted(zip(bandai.labels("content"), bandai.labels("emotion"), strict=True))
    assert len(set(cells)) == 40  # every content x emotion exactly once
    for t in bandai:
        m = t.actors[0]
        assert m.skeleton.n_joints == 22 and m.fps == 30.0
        style = {"neutral": "normal"}.get(t.labels["emotion"], t.labels["emotion"])
        assert t.name == f"dataset-1_{t.labels['content']}_{style}_{t.labels['id']}"


def test_real_dataset_matches_files(bandai, bandai_files):
    m = read_bvh(bandai_files[0])
    t = next(t for t in bandai if t.name == bandai_files[0].stem)
    np.testing.assert_array_equal(t.actors[0].values, m.values)


def test_real_filters(bandai_root):
    walks = load_bandai(bandai_root, content=list(WALK_CONTENTS))
    assert len(walks) == 16
    assert set(walks.labels("content")) == set(WALK_CONTENTS)
    sad_bows = load_bandai(bandai_root, content="bow", style=("sad", "normal"))
    assert sorted(sad_bows.labels("emotion")) == ["neutral", "sad"]
    assert sad_bows.levels["emotion"] == ("neutral", "sad")
    happy = load_bandai(bandai_root, content=["walk", "run"], style="happy", fps=15)
    assert len(happy) == 2 and happy.fps == 15.0
