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
        loops: None, or for a periodic model (``HGPDM(periodic=True)``) per trial -1 or the
            trial-local frame its end loops back to (:func:`find_loops`).
    """

    Y: tuple[np.ndarray, ...]
    onehot: dict[str, np.ndarray]
    trial_of_frame: np.ndarray
    lengths: np.ndarray
    loops: np.ndarray | None = None


def fit_codecs(spec: HGPDM, dataset: MotionDataset) -> tuple:
    """One codec per actor slot (of ``spec.pose_space``), fitted on all training trials."""
    if spec.canonical_side and dataset.n_actors != 1:
        raise BayesmotionError(f"canonical_side mirrors one-actor clips; this dataset has "
                               f"{dataset.n_actors} actors per trial, and mirroring each alone "
                               f"would break their interaction")
    if spec.relative_to is not None and spec.relative_to not in dataset.levels:
        raise BayesmotionError(f"relative_to={spec.relative_to!r}: the trials have no "
                               f"{spec.relative_to!r} label; their labels are "
                               f"{sorted(dataset.levels)}")
    codecs = []
    for a in range(dataset.n_actors):
        motions = [t.actors[a] for t in dataset]
        partners = [t.actors[1 - a] for t in dataset] if spec.root_mode == "partner" else None
        if spec.root_mode == "partner" and dataset.n_actors != 2:
            raise BayesmotionError("root_mode='partner' needs two-actor trials")
        groups = (None if spec.relative_to is None
                  else [t.labels.get(spec.relative_to) for t in dataset])
        codecs.append(fit_codec(spec.pose_space, motions, partners, spec.root_mode,
                                spec.scaling, spec.rest_frames, spec.canonical_side,
                                spec.relative_to, groups))
    return tuple(codecs)


def encode_trial(codecs, trial, root_mode, group=None):
    """Per actor (Y (T, D_a), anchor) of one trial. ``group``: the trial's label of the codecs'
    ``relative_to`` (default: read from the trial's labels)."""
    out = []
    for a, codec in enumerate(codecs):
        partner = trial.actors[1 - a] if root_mode == "partner" else None
        relative_to = getattr(codec, "relative_to", None)
        if relative_to is None:
            out.append(codec.encode(trial.actors[a], partner))
        else:
            g = trial.labels.get(relative_to) if group is None else group
            out.append(codec.encode(trial.actors[a], partner, group=g))
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
    loops = find_loops(Y, lengths, spec.order)[0] if spec.periodic else None
    return ModelData(Y, onehot_labels(dataset, spec.factors),
                     np.repeat(np.arange(len(dataset)), lengths), lengths, loops)


# a loop is at least this many frames long (shorter matches are a pose held still)
LOOP_MIN_PERIOD = 5


def find_loops(Y, lengths, order: int, min_period: int = LOOP_MIN_PERIOD,
               tolerance: float = 1.0) -> tuple[np.ndarray, list[dict]]:
    """Where each trial's end loops back to, for periodic motion (a walk, a run).

    For a trial of n frames with poses y (every actor's normalised poses side by side), the
    candidate frames k have their o-frame window y[k:k+o] compared with the last o frames
    y[n-o:n] by root-mean-square distance, over the k that leave a loop of at least
    ``min_period`` frames (n - o - k) and o frames after the window (k + 2 o <= n). The
    closest k is the trial's loop if its distance is at most ``tolerance`` times the trial's
    median distance between consecutive frames (closer than one frame's step); else -1, the
    trial does not loop (a gesture, a clip that ends elsewhere).

    Returns (loops (R,) ints, per trial {"frame", "period", "match"}: the closest k, its loop
    length n - o - k and its distance over the median step, or None where no k qualifies).
    """
    Yc = np.concatenate([np.asarray(y) for y in Y], axis=1)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    loops, info = [], []
    for s, n in zip(starts, lengths, strict=True):
        s, n = int(s), int(n)
        y = Yc[s:s + n]
        step = float(np.median(np.linalg.norm(np.diff(y, axis=0), axis=1)))
        ks = np.arange(0, min(n - 2 * order, n - order - min_period) + 1)
        if ks.size == 0 or step <= 0:
            loops.append(-1)
            info.append(None)
            continue
        tail = y[n - order:]
        d = np.sqrt(np.array([np.mean(np.sum((y[k:k + order] - tail) ** 2, -1)) for k in ks]))
        k = int(ks[np.argmin(d)])
        match = float(d.min() / step)
        loops.append(k if match <= tolerance else -1)
        info.append({"frame": k, "period": n - order - k, "match": match})
    return np.asarray(loops, dtype=np.int64), info
