"""Generated motion: the :class:`Rollout` that ``generate`` returns, and rollout files, which
keep one whole, with its variances and samples, in the model files' safe layout
(:mod:`bayesmotion.model.archive`: a zip of plain numeric ``.npy`` members plus JSON metadata,
written atomically, never pickled).

A rollout file's metadata: format ``bayesmotion-rollout`` version 1, the package version,
``fps``, ``extrapolated``, ``start``, ``n_observed``, the style factors, the keys of
``samples``, ``sample_var`` and ``variance_parts``, and each actor's skeleton as BVH text (one
frame). Its arrays: ``I``, ``I_var``, ``X``, ``X_var``, ``Y``, ``Y_var``, ``angles``,
``angles_var``, ``positions``, ``positions_var``; ``styles/<factor>``; ``samples/<space>``
(sampled positions per actor, ``samples/positions/<a>``, as the format keeps at most four
dimensions); ``sample_var/<space>``; ``variance_parts/<space>/<within|between>``; ``draws``.

:func:`load_rollout` checks every member as a model file's are checked, that the file holds
exactly the members its metadata names, that every member's shape agrees with the mean
rollout's (samples: every space, one leading sample axis), that variances are not negative, and
that the skeletons parse. :func:`save_rollout` refuses, before writing, what the reader would
refuse.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bayesmotion._version import __version__
from bayesmotion.data.bvh import format_bvh, parse_bvh, write_bvh
from bayesmotion.data.fk import numpy_positions
from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError, BVHError, ModelFileError
from bayesmotion.features.contacts import (
    GROUND,
    pin_offset,
    plant_legs,
    root_translation_columns,
)
from bayesmotion.model.archive import MAX_ABS, MAX_ARRAY_BYTES, open_archive, write_archive


@dataclass(frozen=True, eq=False)
class Rollout:
    """Generated motion with its predictive uncertainty. Shapes: T frames, A actors, S samples.

    Attributes:
        fps: frame rate.
        styles: factor -> (T, K) coordinates used.
        extrapolated: any style outside the simplex.
        start: description of the start state.
        n_observed: leading frames copied from data (zero variance).
        I, I_var: (T, Q_I) mean latent and its one-step predictive variance (incl. noise;
            the same for every dimension of one GP layer).
        variance_parts: posterior-predictive rollouts only: space -> {"within", "between"}
            (GP variance given a draw, and variance of the mean across draws).
        draws: posterior-predictive rollouts only: indices of the draws used.
        X, X_var: (A, T, Q_X). Y, Y_var: (A, T, D).
        angles, angles_var: (A, T, C) channel values (BVH order) and their variance.
        positions, positions_var: (A, T, J, 3) joint positions and their variance.
        samples: dict with I (S, T, Q_I), X, Y, angles (S, A, T, C), positions (S, A, T, J, 3),
            or None. sample_var: the samples' spread in the same spaces.
        skeletons: per actor, the skeleton used for decoding.
    """

    fps: float
    styles: dict
    extrapolated: bool
    start: str
    n_observed: int
    I: np.ndarray
    I_var: np.ndarray
    X: np.ndarray
    X_var: np.ndarray
    Y: np.ndarray
    Y_var: np.ndarray
    angles: np.ndarray
    angles_var: np.ndarray
    positions: np.ndarray
    positions_var: np.ndarray
    skeletons: tuple
    samples: dict | None = None
    sample_var: dict | None = field(default=None)
    variance_parts: dict | None = None
    draws: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return self.I.shape[0]

    def to_motion(self, sample: int | None = None) -> tuple[Motion, ...]:
        """Per-actor Motions of the mean rollout (``sample=None``) or of sample ``sample``."""
        if sample is None:
            ang = self.angles
        else:
            if self.samples is None or not 0 <= sample < self.samples["angles"].shape[0]:
                raise BayesmotionError(f"rollout has no sample {sample}")
            ang = self.samples["angles"][sample]
        return tuple(Motion(sk, ang[a], self.fps, f"actor{a}")
                     for a, sk in enumerate(self.skeletons))

    def interval(self, q: float = 0.9, space: str = "positions"):
        """Central ``q`` Gaussian interval (lower, upper) of the mean rollout in a space."""
        from scipy.stats import norm

        mean, var = getattr(self, space), getattr(self, f"{space}_var")
        z = norm.ppf(0.5 + q / 2)
        sd = np.sqrt(var)
        return mean - z * sd, mean + z * sd

    def pin_feet(self, joint_map=None, *, legs: bool = False, **options) -> Rollout:
        """A copy whose actors' root paths are corrected so that planted feet do not glide
        (:func:`bayesmotion.features.contacts.pin_feet`), in the mean rollout and in every
        sample; the samples' spread is taken again from the corrected samples.

        Only each root's horizontal translation changes (``angles``' root X/Z position
        columns and ``positions``), and with ``legs`` each leg's hip, knee and ankle rotations
        too (:func:`bayesmotion.features.contacts.plant_legs`); the predictive variances
        (``*_var``) are those of the uncorrected rollout. ``joint_map`` and ``options``
        (``contact_height``, ``speed_scale``, ``smooth``) are the clean-up's.
        """
        cols = [root_translation_columns(sk) for sk in self.skeletons]
        leg_options = {k: v for k, v in options.items() if k != "smooth"}

        def fix(angles, positions):  # (A, T, C), (A, T, J, 3) of one rollout
            angles, positions = np.array(angles, np.float64), np.array(positions, np.float64)
            for a, sk in enumerate(self.skeletons):
                off = pin_offset(positions[a], sk, self.fps, joint_map, **options)
                angles[a][:, cols[a]] += off[:, GROUND]
                if legs:
                    angles[a] = plant_legs(angles[a], sk, self.fps, joint_map, **leg_options)
                    positions[a] = numpy_positions(sk, angles[a])
                else:
                    positions[a] += off[:, None, :]
            return angles, positions

        angles, positions = fix(self.angles, self.positions)
        samples, sample_var = self.samples, self.sample_var
        if samples is not None:
            fixed = [fix(a, p) for a, p in zip(samples["angles"], samples["positions"],
                                                strict=True)]
            samples = {**samples, "angles": np.stack([f[0] for f in fixed]),
                       "positions": np.stack([f[1] for f in fixed])}
            sample_var = {**(sample_var or {}), "angles": samples["angles"].var(0),
                          "positions": samples["positions"].var(0)}
        return replace(self, angles=angles, positions=positions, samples=samples,
                       sample_var=sample_var)

    def save(self, path) -> Path:
        """Write the whole rollout (means, variances, samples, skeletons) to ``path``
        (``.npz``, the layout in this module's docstring), atomically; read it back with
        :func:`load_rollout` (``bayesmotion.load_rollout``), view it with ``bayesmotion
        view``."""
        return save_rollout(self, path)

    def write_bvh(self, folder, prefix: str = "rollout", sample: int | None = None) -> list:
        """One BVH file per actor; returns the paths."""
        tag = "mean" if sample is None else f"sample{sample}"
        return [write_bvh(m, Path(folder) / f"{prefix}_{tag}_actor{a}.bvh")
                for a, m in enumerate(self.to_motion(sample))]


FORMAT = "bayesmotion-rollout"
FORMAT_VERSION = 1
_SPACES = ("I", "X", "Y", "angles", "positions")
_MEAN = ("I", "I_var", "X", "X_var", "Y", "Y_var", "angles", "angles_var", "positions",
         "positions_var")


def save_rollout(r: Rollout, path) -> Path:
    """Write ``r`` to ``path`` (``.npz``) atomically; returns the path."""
    arrays = {k: np.asarray(getattr(r, k), dtype=np.float64) for k in _MEAN}
    for f, c in r.styles.items():
        arrays[f"styles/{f}"] = np.asarray(c, dtype=np.float64)
    samples = sorted(r.samples) if r.samples is not None else None
    for k in samples or ():
        v = np.asarray(r.samples[k], dtype=np.float64)
        if k == "positions":  # (S, A, T, J, 3): one member per actor
            for a in range(v.shape[1]):
                arrays[f"samples/positions/{a}"] = v[:, a]
        else:
            arrays[f"samples/{k}"] = v
    sample_var = sorted(r.sample_var) if r.sample_var is not None else None
    for k in sample_var or ():
        arrays[f"sample_var/{k}"] = np.asarray(r.sample_var[k], dtype=np.float64)
    parts = ({k: sorted(v) for k, v in r.variance_parts.items()}
             if r.variance_parts is not None else None)
    for k, names in (parts or {}).items():
        for n in names:
            arrays[f"variance_parts/{k}/{n}"] = np.asarray(r.variance_parts[k][n], np.float64)
    if r.draws is not None:
        arrays["draws"] = np.asarray(r.draws, dtype=np.int64)
    skeletons = [format_bvh(Motion(sk, np.asarray(r.angles[a][:1]), r.fps, f"actor{a}"))
                 for a, sk in enumerate(r.skeletons)]
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "package_version": __version__,
            "fps": float(r.fps), "extrapolated": bool(r.extrapolated), "start": str(r.start),
            "n_observed": int(r.n_observed), "styles": list(r.styles), "samples": samples,
            "sample_var": sample_var, "variance_parts": parts, "draws": r.draws is not None,
            "skeletons": skeletons}
    _check_writable(arrays)
    return write_archive(path, meta, arrays)


def _check_writable(arrays: dict[str, np.ndarray]) -> None:
    """Refuse, before writing, a rollout that :func:`load_rollout` would refuse to read:
    values not finite or beyond the archive's ``MAX_ABS``, or more than ``MAX_ARRAY_BYTES``."""
    total = sum(a.nbytes for a in arrays.values())
    if total > MAX_ARRAY_BYTES:
        raise BayesmotionError(f"the rollout's arrays take {total / 2**20:.0f} MiB, more than "
                               f"a rollout file holds ({MAX_ARRAY_BYTES / 2**20:.0f} MiB, "
                               "bayesmotion.model.archive.MAX_ARRAY_BYTES); save fewer samples "
                               "or frames")
    for k, a in arrays.items():
        if a.dtype.kind == "f" and not np.all(np.abs(a) <= MAX_ABS):
            raise BayesmotionError(f"the rollout's {k} holds values that are not finite or "
                                   f"beyond +-{MAX_ABS:g}: it cannot be saved")


def load_rollout(path) -> Rollout:
    """A rollout written by :func:`save_rollout` (:meth:`Rollout.save`).

    Raises:
        ModelFileError: not a rollout file, a member missing, unnamed or malformed, or shapes
            that disagree.
    """
    path = Path(path)

    def bad(msg):
        return ModelFileError(f"{path}: corrupted rollout file: {msg}")

    with open_archive(path, FORMAT, FORMAT_VERSION) as (meta, arrays):
        def get(key):
            if key not in arrays:
                raise bad(f"member {key + '.npy'!r} is missing")
            return arrays[key]

        fps = meta.get("fps")
        if type(fps) not in (int, float) or not fps > 0:
            raise bad(f"fps must be a positive number, got {fps!r}")
        skeletons = meta.get("skeletons")
        if not isinstance(skeletons, list) or not skeletons or not all(
                isinstance(s, str) for s in skeletons):
            raise bad("metadata 'skeletons' must be a non-empty list of BVH texts")
        try:
            sks = tuple(parse_bvh(s, f"{path} (actor {a} skeleton)").skeleton
                        for a, s in enumerate(skeletons))
        except BVHError as e:
            raise bad(str(e)) from None
        mean = {k: get(k) for k in _MEAN}
        styles = {f: get(f"styles/{f}") for f in _names(meta.get("styles"), "styles", bad)}
        samples = None
        if meta.get("samples") is not None:
            samples = {}
            keys = _names(meta["samples"], "samples", bad)
            if sorted(keys) != sorted(_SPACES):
                raise bad(f"samples must hold every space {list(_SPACES)}, got {keys}")
            for k in keys:
                if k == "positions":
                    per_actor = [get(f"samples/positions/{a}") for a in range(len(sks))]
                    if len({p.shape for p in per_actor}) != 1 or per_actor[0].ndim != 4:
                        raise bad(f"sampled positions of the actors have shapes "
                                  f"{[p.shape for p in per_actor]}; expected one (S, T, J, 3)")
                    samples[k] = np.stack(per_actor, axis=1)
                else:
                    samples[k] = get(f"samples/{k}")
        sample_var = None
        if meta.get("sample_var") is not None:
            sample_var = {k: get(f"sample_var/{k}")
                          for k in _names(meta["sample_var"], "sample_var", bad)}
        parts = meta.get("variance_parts")
        if parts is not None:
            if not isinstance(parts, dict):
                raise bad("metadata 'variance_parts' must be an object")
            parts = {k: {n: get(f"variance_parts/{k}/{n}")
                         for n in _names(v, "variance_parts", bad)} for k, v in parts.items()}
        draws = get("draws") if meta.get("draws") is True else None
        if draws is not None and (draws.ndim != 1 or draws.dtype.kind not in "iu"):
            raise bad(f"draws must be a 1-D integer array, got {draws.shape} {draws.dtype}")
        unread = arrays.unread()
        if unread:
            raise bad(f"holds members its metadata does not name: {unread[:5]}")
    _check_shapes(mean, styles, samples, sample_var, parts, sks, bad)
    for k in ("extrapolated", "start", "n_observed"):
        if k not in meta:
            raise bad(f"metadata has no {k!r}")
    if type(meta["n_observed"]) is not int or meta["n_observed"] < 0:
        raise bad(f"n_observed must be an integer >= 0, got {meta['n_observed']!r}")
    return Rollout(fps=float(fps), styles=styles, extrapolated=bool(meta["extrapolated"]),
                   start=str(meta["start"]), n_observed=meta["n_observed"], skeletons=sks,
                   samples=samples, sample_var=sample_var, variance_parts=parts, draws=draws,
                   **mean)


def _names(x, what: str, bad) -> list[str]:
    if not isinstance(x, list) or not all(isinstance(s, str) and "/" not in s for s in x):
        raise bad(f"metadata {what!r} must be a list of names")
    return x


def _check_shapes(mean: dict, styles: dict, samples, sample_var, parts, sks, bad) -> None:
    A = len(sks)
    if mean["I"].ndim != 2:
        raise bad(f"I has shape {mean['I'].shape}; expected (T, Q)")
    T = mean["I"].shape[0]
    for k, nd in (("X", 3), ("Y", 3), ("angles", 3), ("positions", 4)):
        v = mean[k]
        if v.ndim != nd or v.shape[:2] != (A, T):
            raise bad(f"{k} has shape {v.shape}; expected {nd} dimensions starting ({A} actors, "
                      f"{T} frames)")
    for k in ("I", "X", "Y", "angles", "positions"):
        if mean[f"{k}_var"].shape != mean[k].shape:
            raise bad(f"{k}_var has shape {mean[k + '_var'].shape}; {k} has {mean[k].shape}")
    for a, sk in enumerate(sks):
        if mean["positions"].shape[2] != sk.n_joints or mean["angles"].shape[2] != sk.n_channels:
            raise bad(f"actor {a}'s positions / angles do not match its skeleton "
                      f"({sk.n_joints} joints, {sk.n_channels} channels)")
    for f, c in styles.items():
        if c.ndim != 2 or c.shape[0] != T:
            raise bad(f"styles/{f} has shape {c.shape}; expected ({T}, K)")
    for k in _SPACES:
        if np.any(mean[f"{k}_var"] < 0):
            raise bad(f"{k}_var holds negative variances")
    S = None
    for k, v in (samples or {}).items():
        S = v.shape[0] if S is None else S
        if v.shape != (S, *mean[k].shape):
            raise bad(f"samples/{k} has shape {v.shape}; expected ({S}, "
                      f"{', '.join(map(str, mean[k].shape))})")
    for k, v in (sample_var or {}).items():
        if k not in _SPACES or v.shape != mean[k].shape or np.any(v < 0):
            raise bad(f"sample_var/{k} must be non-negative variances of a space "
                      f"{list(_SPACES)} shaped as its mean")
    for k, d in (parts or {}).items():
        for n, v in d.items():
            if k not in _SPACES or v.shape != mean[k].shape or np.any(v < 0):
                raise bad(f"variance_parts/{k}/{n} must be non-negative variances of a space "
                          f"{list(_SPACES)} shaped as its mean")
