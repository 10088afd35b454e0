"""Turning what a caller hands us (Trial, Motions, BVH paths, arrays) into model-space poses."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bayesmotion.codecs.pose import check_layout
from bayesmotion.data.bvh import read_bvh
from bayesmotion.data.motion import Motion, Trial
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError, SkeletonMismatchError
from bayesmotion.model.data import encode_trial


def _as_motion(x) -> Motion:
    if isinstance(x, Motion):
        return x
    if isinstance(x, str | os.PathLike):
        return read_bvh(x)
    raise BayesmotionError(f"cannot read a motion from {type(x).__name__}")


def match_skeleton(motion: Motion, target: Skeleton) -> Motion:
    """Reorder a motion's channels to ``target``'s layout, matching joints by name.

    Raises SkeletonMismatchError naming the joints the motion lacks.
    """
    sk = motion.skeleton
    if sk.same_layout(target):
        return motion
    missing = [n for n in target.names if n not in sk.names]
    if missing:
        raise SkeletonMismatchError(f"clip skeleton lacks the model's joints {missing}")
    starts = sk.channel_offsets
    cols = []
    for j, name in enumerate(target.names):
        k = sk.index(name)
        src = list(sk.channels[k])
        for c in target.channels[j]:
            if c not in src:
                raise SkeletonMismatchError(f"joint {name!r} of the clip has no {c} channel")
            cols.append(starts[k] + src.index(c))
    out = Motion(target.with_offsets(np.array([sk.offsets[sk.index(n)] for n in target.names])),
                 motion.values[:, cols], motion.fps, motion.name)
    check_layout(target, out.skeleton)
    return out


def clip_to_trial(model, clip) -> Trial:
    """A Trial with the model's actor count, joint layout and frame rate."""
    if isinstance(clip, Trial):
        trial = clip
    elif isinstance(clip, Motion | str | os.PathLike):
        trial = Trial((_as_motion(clip),), name=str(getattr(clip, "name", clip)))
    elif isinstance(clip, list | tuple) and all(isinstance(c, Motion | str | os.PathLike)
                                                for c in clip):
        trial = Trial(tuple(_as_motion(c) for c in clip), name="clip")
    else:
        raise BayesmotionError("clip must be a Trial, one or two Motions, BVH paths, or an "
                               "array of model-space poses")
    if trial.n_actors != model.n_actors:
        raise BayesmotionError(f"the model has {model.n_actors} actor(s); the clip has "
                               f"{trial.n_actors}")
    actors = tuple(match_skeleton(m, model.codecs[a].skeleton) for a, m in enumerate(trial.actors))
    trial = Trial(actors, trial.labels, trial.name)
    if abs(trial.fps - model.fps) > 1e-6:
        trial = trial.resample(model.fps)
    return trial


def clip_poses(model, clip) -> list[np.ndarray]:
    """Per actor, (T, D_a) normalised poses of a clip (arrays pass through after checks)."""
    return clip_poses_and_sides(model, clip)[0]


def clip_poses_and_sides(model, clip, group=None) -> tuple[list[np.ndarray], list[bool]]:
    """:func:`clip_poses` and, per actor, whether the codec mirrored the clip to its canonical
    side (``HGPDM(canonical_side=True)``; always False for arrays, already in model space).
    ``group``: the clip's label of the model's ``relative_to`` (default: the trial's label)."""
    Ys, mirrored, _ = encode_clip(model, clip, group)
    return Ys, mirrored


def encode_clip(model, clip, group=None) -> tuple[list[np.ndarray], list[bool], str | None]:
    """:func:`clip_poses_and_sides` and the group the poses are read relative to (None for a
    model without ``relative_to`` and for arrays, already in model space)."""
    if isinstance(clip, np.ndarray):
        arr = clip[None] if clip.ndim == 2 else clip
        if arr.ndim != 3 or arr.shape[0] != model.n_actors:
            raise BayesmotionError(f"pose array must be (T, D) for one actor or (A, T, D); got "
                                   f"{clip.shape}")
        for a in range(model.n_actors):
            if arr[a].shape[1] != model.codecs[a].dim:
                raise BayesmotionError(f"actor {a}: pose array has {arr[a].shape[1]} columns, "
                                       f"the model expects {model.codecs[a].dim}")
        if not np.all(np.isfinite(arr)):
            raise BayesmotionError("pose array has NaN or infinite values")
        return [np.asarray(x, dtype=np.float64) for x in arr], [False] * model.n_actors, None
    if isinstance(clip, str | os.PathLike) and not Path(clip).exists():
        raise BayesmotionError(f"{clip}: no such file")
    trial = clip_to_trial(model, clip)
    relative_to = getattr(model.spec, "relative_to", None)
    if relative_to is not None and group is None:
        group = trial.labels.get(relative_to)
    enc = encode_trial(model.codecs, trial, model.codecs[0].root_mode, group)
    used = None if relative_to is None else str(group)
    return [e.Y for e in enc], [bool(e.mirrored) for e in enc], used
