"""What the log-posterior conditions on: codecs fitted to a dataset, the encoded poses and the
one-hot style labels of every training trial (:class:`ModelData`)."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from bayesmotion.codecs.affective import fit_codec
from bayesmotion.data.motion import MotionDataset
from bayesmotion.errors import BayesmotionError

if TYPE_CHECKING:
    from bayesmotion.model.spec import HGPDM


class ModelData(NamedTuple):
    """Everything the log-posterior conditions on, as arrays (static shapes).

    Attributes:
        Y: per actor, (N, D_a) normalised poses of all trials stacked.
        onehot: factor -> (R, K_f) one-hot labels of the training trials.
        trial_of_frame: (N,) trial index of every frame.
        lengths: (R,) frames per trial.
    """

    Y: tuple[np.ndarray, ...]
    onehot: dict[str, np.ndarray]
    trial_of_frame: np.ndarray
    lengths: np.ndarray


def fit_codecs(spec: HGPDM, dataset: MotionDataset) -> tuple:
    """One codec per actor slot (of ``spec.pose_space``), fitted on all training trials."""
    if spec.canonical_side and dataset.n_actors != 1:
        raise BayesmotionError(f"canonical_side mirrors one-actor clips; this dataset has "
                               f"{dataset.n_actors} actors per trial, and mirroring each alone "
                               f"would break their interaction")
    codecs = []
    for a in range(dataset.n_actors):
        motions = [t.actors[a] for t in dataset]
        partners = [t.actors[1 - a] for t in dataset] if spec.root_mode == "partner" else None
        if spec.root_mode == "partner" and dataset.n_actors != 2:
            raise BayesmotionError("root_mode='partner' needs two-actor trials")
        codecs.append(fit_codec(spec.pose_space, motions, partners, spec.root_mode,
                                spec.scaling, spec.rest_frames, spec.canonical_side))
    return tuple(codecs)


def encode_trial(codecs, trial, root_mode):
    """Per actor (Y (T, D_a), anchor) of one trial."""
    out = []
    for a, codec in enumerate(codecs):
        partner = trial.actors[1 - a] if root_mode == "partner" else None
        out.append(codec.encode(trial.actors[a], partner))
    return out


def onehot_labels(dataset: MotionDataset, factors) -> dict[str, np.ndarray]:
    out = {}
    for f in factors:
        levels = dataset.levels[f]
        labs = dataset.labels(f)
        if any(l is None for l in labs):
            raise BayesmotionError(f"every trial needs a {f!r} label")
        out[f] = np.eye(len(levels))[[levels.index(l) for l in labs]]
    return out


def prepare_data(spec: HGPDM, dataset: MotionDataset, codecs) -> ModelData:
    enc = [encode_trial(codecs, t, spec.root_mode) for t in dataset]
    Y = tuple(np.concatenate([e[a].Y for e in enc]) for a in range(dataset.n_actors))
    lengths = np.array([t.n_frames for t in dataset])
    if lengths.min() <= spec.order + 1:
        raise BayesmotionError(f"every trial needs more than {spec.order + 1} frames; the "
                               f"shortest has {lengths.min()}")
    return ModelData(Y, onehot_labels(dataset, spec.factors),
                     np.repeat(np.arange(len(dataset)), lengths), lengths)
