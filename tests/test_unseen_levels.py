"""Emotion levels never seen in training together with a clip's given styles: flagged, with
the layers whose style cells they miss (``infer_emotion``'s ``info["unseen_levels"]``)."""

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.emotion.infer import unseen_levels
from bayesmotion.emotion.ood import OutOfDistributionWarning, UnseenStyleWarning


def _fake(cells, interaction=("couple", "emotion"), dynamics=("couple", "emotion")):
    """A stand-in model whose training trials have the (couple, emotion) level indices."""
    couple = np.eye(2)[[c for c, _ in cells]]
    emotion = np.eye(3)[[e for _, e in cells]]
    return SimpleNamespace(
        data=SimpleNamespace(onehot={"couple": couple, "emotion": emotion}),
        spec=SimpleNamespace(interaction_factors=interaction, dynamics_factors=dynamics,
                             dynamics_linear="stable"),
        levels={"couple": ("c1", "c2"), "emotion": ("angry", "happy", "sad")})


def test_levels_missing_from_the_given_cells_and_only_those():
    m = _fake([(0, 0), (0, 1), (0, 2), (1, 0), (1, 1)])  # couple c2 never sad
    both = ["interaction", "dynamics"]
    assert unseen_levels(m, {"couple": np.array([0.0, 1.0])}) == {"sad": both}
    assert unseen_levels(m, {"couple": np.array([1.0, 0.0])}) == {}
    # a free couple may be c1, which was sad; mixed coordinates match both couples
    assert unseen_levels(m, {}) == {}
    assert unseen_levels(m, {"couple": np.array([0.3, 0.7])}) == {}
    # only the layers that carry both factors miss the cell
    m = _fake([(0, 0), (0, 1), (0, 2), (1, 0), (1, 1)], dynamics=("emotion",))
    assert unseen_levels(m, {"couple": np.array([0.0, 1.0])}) == {"sad": ["interaction"]}
    # a layer without the emotion factor is not asked
    m = _fake([(0, 0), (1, 1)], interaction=("couple",), dynamics=("couple",))
    assert unseen_levels(m, {"couple": np.array([0.0, 1.0])}) == {}
    # a level no training trial has at all is unseen whatever is given
    m = _fake([(0, 0), (1, 1)])
    assert unseen_levels(m, {}) == {"sad": both}


@pytest.fixture(scope="module")
def missing_cell_model():
    """Happy and sad handshakes of both couples, without couple c2's sad trials."""
    ds = bm.load_handshakes(fps=5.0).filter(emotion=["happy", "sad"])
    ds = bm.MotionDataset(ds.trials, {"couple": ds.levels["couple"],
                                      "emotion": ("happy", "sad")})
    keep = [i for i, t in enumerate(ds.trials)
            if not (t.labels["couple"] == "c2" and t.labels["emotion"] == "sad")]
    assert len(keep) < len(ds.trials)
    return bm.HGPDM(latent_dim=3, interaction_dim=3).fit(ds.take(keep), max_iter=30,
                                                          progress=False), ds


def test_infer_emotion_flags_a_level_unseen_with_the_given_couple(missing_cell_model):
    model, ds = missing_cell_model
    clip = next(t for t in ds.trials
                if t.labels["couple"] == "c2" and t.labels["emotion"] == "happy")
    kw = {"n_steps": 30, "n_walkers": 8, "max_iter": 30}
    with pytest.warns(UnseenStyleWarning, match=r"emotion 'sad' \(interaction and dynamics\)"
                                                r" together with the given styles "
                                                r"\(couple='c2'\).*without the couple style"):
        ep = bm.infer_emotion(model, clip, couple="c2", **kw)
    assert ep.info["unseen_levels"] == {"sad": ["interaction", "dynamics"]}
    assert "never seen with the given styles: sad" in str(ep)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnseenStyleWarning)
        warnings.simplefilter("ignore", OutOfDistributionWarning)  # c2's clip as couple c1
        ep = bm.infer_emotion(model, clip, couple="c1", **kw)
    assert ep.info["unseen_levels"] == {}
    assert "never seen" not in str(ep)


def test_the_warning_says_what_is_missing_and_what_to_do():
    from bayesmotion.emotion.infer import _unseen_message

    m = _fake([(0, 0), (0, 1), (0, 2), (1, 0), (1, 1)])
    m.params = {}
    c2 = {"couple": np.array([0.0, 1.0])}
    text = _unseen_message(m, unseen_levels(m, c2), c2)
    assert "emotion 'sad' (interaction and dynamics) together with the given styles " \
           "(couple='c2')" in text
    assert "judged by the GP prior" in text and "without the couple style factor" in text
    # a level no trial has at all: no factor to drop would help
    m = _fake([(0, 0), (1, 1)])
    m.params = {}
    text = _unseen_message(m, unseen_levels(m, {}), {})
    assert "given styles" not in text and "without the" not in text
    assert "No training trial has emotion 'sad' at all" in text
    # learned style vectors borrow across cells
    m = _fake([(0, 0), (0, 1), (0, 2), (1, 0), (1, 1)])
    m.params = {"style:emotion": np.zeros((3, 2))}
    assert "through the learned style vectors" in _unseen_message(
        m, unseen_levels(m, c2), c2)
