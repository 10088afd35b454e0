"""Motion, Trial and MotionDataset: the containers every other module works on.

All three are immutable: methods return new objects.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from bayesmotion.data.fk import numpy_positions
from bayesmotion.data.skeleton import ROTATION_CHANNELS, Skeleton, horizontal_columns
from bayesmotion.errors import BayesmotionError


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Motion:
    """One actor's motion.

    Attributes:
        skeleton: the joint tree and channel layout.
        values: (T, C) channel values per frame, BVH order, degrees and file units.
        fps: frames per second.
        name: free text (file name, actor id).
    """

    skeleton: Skeleton
    values: np.ndarray
    fps: float
    name: str = ""

    def __post_init__(self):
        v = _readonly(self.values)
        if v.ndim != 2 or v.shape[1] != self.skeleton.n_channels:
            raise BayesmotionError(
                f"Motion {self.name!r}: values must be (frames, {self.skeleton.n_channels}) "
                f"for this skeleton, got {v.shape}")
        if v.shape[0] == 0:
            raise BayesmotionError(f"Motion {self.name!r} has zero frames")
        if not np.all(np.isfinite(v)):
            raise BayesmotionError(f"Motion {self.name!r} has NaN or infinite channel values")
        if not isinstance(self.fps, int | float | np.number) or not (
                np.isfinite(self.fps) and self.fps > 0):
            raise BayesmotionError(f"Motion {self.name!r}: fps must be positive, got {self.fps}")
        object.__setattr__(self, "values", v)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def n_frames(self) -> int:
        return self.values.shape[0]

    @property
    def duration(self) -> float:
        """Seconds between the first and the last frame."""
        return (self.n_frames - 1) / self.fps

    def positions(self, with_end_sites: bool = False) -> np.ndarray:
        """(T, J, 3) world joint positions by forward kinematics (float64 NumPy)."""
        return numpy_positions(self.skeleton, self.values, with_end_sites)

    def rotation_mask(self) -> np.ndarray:
        """(C,) True for rotation channels."""
        return np.array([c in ROTATION_CHANNELS for chans in self.skeleton.channels
                         for c in chans])

    def replace(self, **changes) -> Motion:
        d = {"skeleton": self.skeleton, "values": self.values, "fps": self.fps, "name": self.name}
        d.update(changes)
        return Motion(**d)

    def select(self, frames) -> Motion:
        """Frames by slice, index array or boolean mask."""
        v = self.values[frames]
        if v.ndim == 1:
            v = v[None]
        return self.replace(values=v)

    def resample(self, fps: float) -> Motion:
        """Resample to ``fps``.

        An integer down-sampling ratio takes every k-th frame (exact); otherwise channels are
        linearly interpolated in time, rotation channels after unwrapping (so no 360 degree
        jumps are averaged).
        """
        if not (np.isfinite(fps) and fps > 0):
            raise BayesmotionError(f"target fps must be positive, got {fps}")
        ratio = self.fps / fps
        if abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1:
            return self.replace(values=self.values[:: int(round(ratio))], fps=fps)
        t_old = np.arange(self.n_frames) / self.fps
        t_new = np.arange(0.0, t_old[-1] + 1e-12, 1.0 / fps)
        v = self.values.copy()
        rot = self.rotation_mask()
        v[:, rot] = np.unwrap(v[:, rot], period=360.0, axis=0)
        out = np.stack([np.interp(t_new, t_old, v[:, c]) for c in range(v.shape[1])], axis=1)
        return self.replace(values=out, fps=fps)


@dataclass(frozen=True, eq=False)
class Trial:
    """One recording: one or two actors' motions on a shared clock, plus labels.

    Attributes:
        actors: one ``Motion`` per actor, equal frame counts and fps.
        labels: factor name -> level, e.g. ``{"emotion": "happy", "couple": "c1"}``.
        name: free text.
    """

    actors: tuple[Motion, ...]
    labels: Mapping[str, str] = field(default_factory=dict)
    name: str = ""

    def __post_init__(self):
        actors = (self.actors,) if isinstance(self.actors, Motion) else tuple(self.actors)
        if len(actors) not in (1, 2):
            raise BayesmotionError(f"Trial {self.name!r}: 1 or 2 actors, got {len(actors)}")
        n = {a.n_frames for a in actors}
        f = {a.fps for a in actors}
        if len(n) > 1 or len(f) > 1:
            raise BayesmotionError(
                f"Trial {self.name!r}: actors must share a clock, got frames {sorted(n)} "
                f"and fps {sorted(f)}")
        object.__setattr__(self, "actors", actors)
        object.__setattr__(self, "labels", dict(self.labels))

    @property
    def n_actors(self) -> int:
        return len(self.actors)

    @property
    def n_frames(self) -> int:
        return self.actors[0].n_frames

    @property
    def fps(self) -> float:
        return self.actors[0].fps

    def map(self, fn) -> Trial:
        """A trial whose actors are ``fn(motion)``."""
        return Trial(tuple(fn(a) for a in self.actors), self.labels, self.name)

    def select(self, frames) -> Trial:
        return self.map(lambda m: m.select(frames))

    def resample(self, fps: float) -> Trial:
        return self.map(lambda m: m.resample(fps))


@dataclass(frozen=True, eq=False)
class MotionDataset:
    """A labelled set of trials.

    Attributes:
        trials: the trials (all with the same number of actors).
        levels: factor -> ordered level names, e.g. ``{"emotion": ("neutral", "happy", ...)}``.
            Inferred from the trials' labels (sorted) when not given.
        name: free text.
    """

    trials: tuple[Trial, ...]
    levels: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    name: str = ""

    def __post_init__(self):
        trials = tuple(self.trials)
        if not trials:
            raise BayesmotionError(f"dataset {self.name!r} has no trials")
        if len({t.n_actors for t in trials}) > 1:
            raise BayesmotionError("all trials of a dataset must have the same number of actors")
        rates = [t.fps for t in trials]
        if max(rates) - min(rates) > 1e-6 * max(rates):
            lo, hi = trials[int(np.argmin(rates))], trials[int(np.argmax(rates))]
            raise BayesmotionError(
                f"dataset {self.name!r} mixes frame rates ({lo.name!r} at {lo.fps:g} fps, "
                f"{hi.name!r} at {hi.fps:g} fps); resample the trials to one rate first "
                f"(Trial.resample / MotionDataset.resample, or --fps on the command line)")
        levels = {k: tuple(v) for k, v in dict(self.levels).items()}
        for t in trials:
            for k, v in t.labels.items():
                if k in levels and v not in levels[k]:
                    raise BayesmotionError(
                        f"trial {t.name!r}: {k}={v!r} is not one of {list(levels[k])}")
        factors = sorted({k for t in trials for k in t.labels})
        for k in factors:
            if k not in levels:
                levels[k] = tuple(sorted({t.labels[k] for t in trials if k in t.labels}))
        object.__setattr__(self, "trials", trials)
        object.__setattr__(self, "levels", levels)

    def __len__(self) -> int:
        return len(self.trials)

    def __iter__(self) -> Iterator[Trial]:
        return iter(self.trials)

    def __getitem__(self, i) -> Trial:
        return self.trials[i]

    @property
    def n_actors(self) -> int:
        return self.trials[0].n_actors

    @property
    def factors(self) -> tuple[str, ...]:
        return tuple(self.levels)

    @property
    def fps(self) -> float:
        return self.trials[0].fps

    def labels(self, factor: str) -> list[str]:
        """The level of ``factor`` for each trial."""
        if factor not in self.levels:
            raise BayesmotionError(f"dataset has no factor {factor!r}; has {list(self.levels)}")
        return [t.labels.get(factor) for t in self.trials]

    def _with(self, trials: Sequence[Trial]) -> MotionDataset:
        return MotionDataset(tuple(trials), self.levels, self.name)

    def map(self, fn) -> MotionDataset:
        return self._with([fn(t) for t in self.trials])

    def resample(self, fps: float) -> MotionDataset:
        """Every trial resampled to ``fps`` (see :meth:`Motion.resample`)."""
        return self.map(lambda t: t.resample(fps))

    def select_frames(self, frames) -> MotionDataset:
        return self.map(lambda t: t.select(frames))

    def filter(self, **labels) -> MotionDataset:
        """Trials whose labels match, e.g. ``filter(emotion="happy")`` or a list of levels."""
        def ok(t):
            return all(t.labels.get(k) in (v if isinstance(v, list | tuple | set) else [v])
                       for k, v in labels.items())
        kept = [t for t in self.trials if ok(t)]
        if not kept:
            raise BayesmotionError(f"no trial matches {labels}")
        return self._with(kept)

    def split(self, factor: str) -> dict[str, MotionDataset]:
        """One dataset per level of ``factor`` (levels with no trial are left out)."""
        labs = self.labels(factor)
        return {lv: self._with([t for t, l in zip(self.trials, labs, strict=True) if l == lv])
                for lv in self.levels[factor] if lv in labs}

    def take(self, indices: Sequence[int]) -> MotionDataset:
        return self._with([self.trials[i] for i in indices])

    def leave_one_out(self) -> Iterator[tuple[MotionDataset, Trial]]:
        """(training set without trial i, trial i) for every i."""
        for i in range(len(self)):
            yield self._with([t for k, t in enumerate(self.trials) if k != i]), self.trials[i]


def find_mover(motions) -> int:
    """The joint whose horizontal position channels travel the most (0 when none moves).

    BVH exporters differ: CMU translates the root, Bandai keeps a ``joint_Root`` at the origin
    and translates ``Hips`` below it. "Travel" is the median frame-to-frame horizontal step,
    summed over the motions, so that a joint which moves in a few clips only is not taken for
    the one that walks in all (Bandai's ``joint_Root`` sits at the origin in every walk but the
    short walk-back normal one, where it carries the translation)."""
    sk = motions[0].skeleton
    best, best_step = 0, 0.0
    for j in range(sk.n_joints):
        h = horizontal_columns(sk, j)
        if h.size == 0:
            continue
        step = sum(float(np.median(np.linalg.norm(np.diff(m.values[:, h], axis=0), axis=-1)))
                   for m in motions if m.n_frames > 1)
        if step > best_step:
            best, best_step = j, step
    return best
