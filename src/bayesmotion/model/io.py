"""Loading model files (:mod:`bayesmotion.model.archive` holds the format and the writer).

``load`` checks the whole file before it returns: the archive's limits, dtypes and values
(:func:`~bayesmotion.model.archive.open_archive`), the metadata's types, and that every array
has the shape the metadata implies, so that a model it returns cannot fail later in
``generate``, ``infer_emotion`` or ``sample_posterior`` for a reason the file holds.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bayesmotion.codecs.affective import codec_from_saved
from bayesmotion.codecs.pose import ROOT_MODES
from bayesmotion.data.bvh import FRAME_TIME_RANGE
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.model.archive import open_archive
from bayesmotion.model.data import ModelData
from bayesmotion.model.fitted import FittedHGPDM, TrialRecord
from bayesmotion.model.params import AR_KEY, STYLE_PREFIX
from bayesmotion.model.spec import HGPDM

MAX_TRAINING_FRAMES = 50_000
"""Most training frames (N) a model file may hold: conditioning a model factors N x N Gram
matrices (20 GB at this limit)."""
_MAX_LOG = 100.0
_MAX_ATANH = 10.0  # tanh(10) = 1 - 4e-9: still a stationary autoregression
"""Largest magnitude of a stored log-hyperparameter: its exponential stays within 1e+-43."""
# the metadata's parse and the model's construction raise these on content of the wrong type
_CONTENT_ERRORS = (KeyError, TypeError, ValueError, IndexError, AttributeError, OverflowError,
                   BayesmotionError)


def load(path) -> FittedHGPDM:
    """Load a model file written by ``FittedHGPDM.save``.

    Raises:
        ModelFileError: the file is missing, corrupted, foreign, of another format version,
            or holds members the format does not name (they are not read).
    """
    path = Path(path)
    with open_archive(path) as (meta, arrays):
        try:
            model = _build(meta, arrays, path)
        except ModelFileError:
            raise
        except _CONTENT_ERRORS as e:
            raise ModelFileError(f"{path}: corrupted or incomplete model file "
                                 f"({type(e).__name__}: {e})") from None
        unknown = arrays.unread()
        if unknown:
            shown = ", ".join(repr(n[:60]) for n in unknown[:5])
            raise ModelFileError(f"{path}: not a model file this bayesmotion wrote: it holds "
                                 f"{len(unknown)} member(s) the format does not name ({shown}"
                                 f"{', ...' if len(unknown) > 5 else ''}); they were not read")
    return model


def _bad(path, msg):
    return ModelFileError(f"{path}: corrupted model file: {msg}")


def _build(meta: dict, arrays, path: Path) -> FittedHGPDM:
    spec = _spec(meta["spec"], path)
    params = {k: arrays[f"param/{k}"] for k in _strings(meta["params"], "params", path)}
    codec_meta = meta["codecs"]
    if not isinstance(codec_meta, list) or not 1 <= len(codec_meta) <= 2:
        raise _bad(path, "the model must have one or two actor codecs")
    codecs = tuple(codec_from_saved(m, arrays, f"codec{a}/") for a, m in enumerate(codec_meta))
    if any(c.pose_space != spec.pose_space for c in codecs):
        raise ModelFileError(f"{path}: corrupted model file: its specification's pose space "
                             f"{spec.pose_space!r} does not match its codecs' "
                             f"{[c.pose_space for c in codecs]}")
    if any(getattr(c, "relative_to", None) != spec.relative_to for c in codecs):
        raise _bad(path, f"relative_to={spec.relative_to!r} does not match the codecs' "
                         f"{[getattr(c, 'relative_to', None) for c in codecs]}")
    if any(c.root_mode != spec.root_mode for c in codecs) or (
            spec.root_mode == "partner" and len(codecs) != 2):
        raise _bad(path, f"root mode {spec.root_mode!r} does not match the codecs' "
                         f"{[c.root_mode for c in codecs]}")
    steps = [(getattr(c, "frames", None) is not None, c.side is not None) for c in codecs]
    if any(s != (spec.rest_frames, spec.canonical_side) for s in steps):
        raise _bad(path, f"the specification's rest_frames={spec.rest_frames} and "
                         f"canonical_side={spec.canonical_side} do not match the codecs' "
                         f"stored rig steps")
    trials = meta["trials"]
    if not isinstance(trials, list) or not trials:
        raise _bad(path, "no trial records")
    lengths = _lengths(arrays["lengths"], len(trials), spec.order, path)
    A = len(codecs)
    factors = _strings(meta["factors"], "factors", path)
    levels = _levels(meta["levels"], path)
    loops = _loops(arrays, lengths, spec, path)
    data = ModelData(tuple(arrays[f"Y/{a}"] for a in range(A)),
                     {f: arrays[f"onehot/{f}"] for f in factors},
                     np.repeat(np.arange(lengths.size), lengths), lengths, loops)
    records = tuple(_trial(t, r, arrays, A, path) for r, t in enumerate(trials))
    fps = meta["fps"]
    lo, hi = FRAME_TIME_RANGE
    if not _number(fps) or not 1 / hi <= fps <= 1 / lo:
        raise _bad(path, f"frame rate {fps!r} is not a number from {1 / hi:g} to {1 / lo:g}")
    diagnostics = meta.get("diagnostics", {})
    if not isinstance(diagnostics, dict):
        raise _bad(path, "diagnostics must be a mapping")
    jitter = diagnostics.get("jitter", 1e-8)
    if not _number(jitter) or not 0 <= jitter <= 1:
        raise _bad(path, f"diagnostics jitter {jitter!r} is not a number from 0 to 1")
    calibration = meta.get("calibration", {})
    if not isinstance(calibration, dict):
        raise _bad(path, "calibration must be a mapping")
    n_eff = calibration.get("effective_frames", 1.0)
    if not _number(n_eff) or not n_eff > 0:
        raise _bad(path, f"calibration effective_frames {n_eff!r} is not a number > 0")
    model = FittedHGPDM(spec=spec, params=params, codecs=codecs,
                        levels={k: tuple(v) for k, v in levels.items()}, data=data,
                        trials=records, fps=float(fps), diagnostics=diagnostics,
                        calibration=calibration)
    _check_shapes(model, path)
    return model


def _number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _strings(x, what: str, path) -> list[str]:
    if not isinstance(x, list) or not all(isinstance(s, str) for s in x) or \
            len(set(x)) != len(x):
        raise _bad(path, f"{what} must be a list of distinct names")
    return x


def _spec(d, path) -> HGPDM:
    """The specification, with the types ``HGPDM`` does not check itself."""
    if not isinstance(d, dict):
        raise _bad(path, "the specification must be a mapping")
    for key in ("interaction_factors", "dynamics_factors"):
        _strings(d.get(key), key, path)
    spec = HGPDM.from_dict(d)
    ints = [getattr(spec, k) for k in ("latent_dim", "interaction_dim", "order")]
    bools = [getattr(spec, k) for k in ("rest_frames", "canonical_side", "periodic")]
    if not all(type(v) is int for v in ints) or not all(type(v) is bool for v in bools) \
            or spec.root_mode not in ROOT_MODES or spec.scaling not in ("type", "channel"):
        raise _bad(path, f"specification fields have the wrong types or values: {d!r:.200}")
    return spec


def _levels(levels, path) -> dict:
    if not isinstance(levels, dict):
        raise _bad(path, "levels must be a mapping")
    for f, v in levels.items():
        _strings(v, f"levels of {f!r}", path)
    return levels


def _lengths(lengths: np.ndarray, n_trials: int, order: int, path) -> np.ndarray:
    """Frames per trial: n_trials integers, each above ``order + 1`` (what fitting needs), at
    most :data:`MAX_TRAINING_FRAMES` in all."""
    if lengths.dtype.kind not in "iu" or lengths.shape != (n_trials,) \
            or np.any(lengths <= order + 1) or np.any(lengths > MAX_TRAINING_FRAMES):
        raise _bad(path, f"trial lengths must be {n_trials} integers above {order + 1}, got a "
                         f"{lengths.dtype} array of shape {lengths.shape}")
    if int(lengths.sum()) > MAX_TRAINING_FRAMES:
        raise _bad(path, f"{int(lengths.sum())} training frames, more than bayesmotion.model.io."
                         f"MAX_TRAINING_FRAMES = {MAX_TRAINING_FRAMES}")
    return lengths.astype(np.int64)


def _loops(arrays, lengths: np.ndarray, spec, path) -> np.ndarray | None:
    """A periodic model's loop frames: per trial -1 or a frame k with k + 2 o <= its length
    (what :class:`~bayesmotion.model.layers.DynamicsIndex` needs); None for other models."""
    if not spec.periodic:
        if "loops" in arrays:
            raise _bad(path, "loop frames stored for a model that is not periodic")
        return None
    if "loops" not in arrays:
        raise _bad(path, "a periodic model without its loop frames")
    loops = arrays["loops"]
    if loops.dtype.kind not in "iu" or loops.shape != lengths.shape or np.any(loops < -1) \
            or np.any(loops + 2 * spec.order > lengths):
        raise _bad(path, f"loop frames must be {lengths.size} integers, -1 or a frame k with "
                         f"k + {2 * spec.order} <= its trial's length, got a {loops.dtype} "
                         f"array of shape {loops.shape}")
    return loops.astype(np.int64)


def _trial(t, r: int, arrays, A: int, path) -> TrialRecord:
    if not isinstance(t, dict) or not isinstance(t.get("name"), str) \
            or not isinstance(t.get("labels"), dict) or type(t.get("n_frames")) is not int \
            or not all(isinstance(k, str) and isinstance(v, str) for k, v in t["labels"].items()):
        raise _bad(path, f"trial record {r} must have a name, labels (names) and n_frames")
    return TrialRecord(t["name"], t["labels"], t["n_frames"],
                       tuple(arrays[f"anchor/{r}/{a}"] for a in range(A)),
                       tuple(arrays[f"offsets/{r}/{a}"] for a in range(A)))


def _anchor_shape(codec, n_frames: int) -> tuple[int, ...] | None:
    """The anchor shape that ``codec.encode`` gives a trial of ``n_frames`` frames (None: a
    "partner" codec without horizontal channels, which generation cannot place)."""
    h = codec.horizontal_columns().size if codec.decodes else 0
    mode = codec.root_mode if codec.decodes else "absolute"
    if mode == "heading":
        return (3,)
    if mode == "velocity":
        return (h,)
    if mode == "partner":
        return (n_frames, h) if h else None
    return (0,)


def _check_shapes(model, path):
    """Every array the model uses has the shape its metadata implies, and values in range: a
    file that passes cannot fail later inside ``log_posterior`` or ``generate``."""
    def bad(msg):
        raise _bad(path, msg)

    spec, data, params = model.spec, model.data, model.params
    lengths = np.asarray(data.lengths)
    if any(int(n) != r.n_frames for n, r in zip(lengths, model.trials, strict=True)):
        bad("trial lengths disagree with the trial records")
    N, R, A = int(lengths.sum()), lengths.size, len(model.codecs)
    o = spec.order
    expected = {"X": (A, N, spec.latent_dim), "I": (N, spec.interaction_dim),
                "log_gamma": (3,), "log_beta": (3,),
                "log_alpha": (2 + o,) if spec.stable_dynamics else (2 + 2 * o,)}
    if spec.stable_dynamics:
        expected[AR_KEY] = (o,)
    if spec.inducing is not None:
        m, m_dyn = min(spec.inducing, N), min(spec.inducing, N - o * R)
        expected.update(Xu=(A, m, spec.latent_dim), Iu=(m, spec.interaction_dim),
                        Du=(o, m_dyn, spec.interaction_dim))
    if set(data.onehot) != set(spec.factors) or not set(spec.factors) <= set(model.levels):
        bad(f"labels of factors {sorted(data.onehot)} (levels of {sorted(model.levels)}) do not "
            f"match the specification's factors {sorted(spec.factors)}")
    for f in spec.factors:
        K = len(model.levels[f])
        h = np.asarray(data.onehot[f])
        if h.shape != (R, K) or not np.all((h == 0) | (h == 1)) or np.any(h.sum(1) != 1):
            bad(f"labels of factor {f!r} are not one-hot ({R}, {K}) over its levels")
        if any(r.labels.get(f) != model.levels[f][k]
               for r, k in zip(model.trials, h.argmax(1), strict=True)):
            bad(f"the trial records' {f!r} labels disagree with the one-hot labels")
        if STYLE_PREFIX + f in params:
            expected[STYLE_PREFIX + f] = (K, K - 1)
    missing = sorted(k for k in expected if k not in params)  # style keys: only if present
    unknown = sorted(set(params) - set(expected))
    if missing or unknown:
        bad(f"parameters missing {missing}, unknown {unknown}")
    for k, shape in expected.items():
        v = np.asarray(params[k])
        if v.shape != shape:
            bad(f"parameter {k} has shape {v.shape}, expected {shape}")
        if not np.issubdtype(v.dtype, np.floating) or not np.all(np.isfinite(v)):
            bad(f"parameter {k} is not a finite float array")
        if k.startswith("log_") and np.any(np.abs(v) > _MAX_LOG):
            bad(f"parameter {k} has values beyond +-{_MAX_LOG:g}: its exponential overflows")
        if k == AR_KEY and np.any(np.abs(v) > _MAX_ATANH):
            bad(f"parameter {k} has values beyond +-{_MAX_ATANH:g}: the autoregression's "
                f"partial autocorrelations round to +-1, a unit root")
    for a, (Y, codec) in enumerate(zip(data.Y, model.codecs, strict=True)):
        if Y.shape != (N, codec.dim) or Y.dtype != np.float64:
            bad(f"training poses of actor {a} have shape {Y.shape}, expected {(N, codec.dim)}")
        J = codec.skeleton.n_joints
        for r, rec in enumerate(model.trials):
            want = _anchor_shape(codec, rec.n_frames)
            if rec.anchors[a].shape != want or rec.anchors[a].dtype != np.float64:
                bad(f"anchor of trial {r}, actor {a} has shape {rec.anchors[a].shape}, "
                    f"expected {want}")
            if rec.offsets[a].shape != (J, 3) or rec.offsets[a].dtype != np.float64:
                bad(f"bone offsets of trial {r}, actor {a} have shape {rec.offsets[a].shape}, "
                    f"expected {(J, 3)}")

