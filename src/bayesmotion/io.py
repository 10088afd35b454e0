"""Model files: ``.npz`` arrays plus JSON metadata, written atomically, never pickled.

Layout of the archive (all plain arrays, loaded with ``allow_pickle=False``):

* ``__meta__``: UTF-8 JSON as uint8 -- format name and version, package version, the model
  specification and priors, label levels, codecs (skeleton, root mode), trial records (names,
  labels, lengths), fit diagnostics;
* ``param/<key>``: unconstrained parameters; ``Y/<a>``: training poses per actor;
  ``onehot/<factor>``; ``lengths``; ``codec<a>/...``: normalisation arrays;
  ``anchor/<r>/<a>`` and ``offsets/<r>/<a>``: per-trial decoding anchors and bone offsets.
"""

from __future__ import annotations

import io as _io
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .data.bvh import atomic_path
from .errors import BayesmotionError, ModelFileError
from .params import STYLE_PREFIX

FORMAT = "bayesmotion-hgpdm"
FORMAT_VERSION = 1


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def save_model(model, path) -> Path:
    from . import __version__

    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    for k, v in model.params.items():
        arrays[f"param/{k}"] = np.asarray(v)
    for a, Y in enumerate(model.data.Y):
        arrays[f"Y/{a}"] = np.asarray(Y)
    for f, h in model.data.onehot.items():
        arrays[f"onehot/{f}"] = np.asarray(h)
    arrays["lengths"] = np.asarray(model.data.lengths)
    for a, codec in enumerate(model.codecs):
        arrays.update(codec.to_arrays(f"codec{a}/"))
    for r, rec in enumerate(model.trials):
        for a in range(len(rec.anchors)):
            arrays[f"anchor/{r}/{a}"] = np.asarray(rec.anchors[a])
            arrays[f"offsets/{r}/{a}"] = np.asarray(rec.offsets[a])
    meta = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "package_version": __version__,
        "spec": model.spec.to_dict(),
        "levels": {k: list(v) for k, v in model.levels.items()},
        "factors": list(model.data.onehot),
        "params": list(model.params),
        "codecs": [c.to_meta() for c in model.codecs],
        "trials": [{"name": r.name, "labels": r.labels, "n_frames": r.n_frames}
                   for r in model.trials],
        "fps": model.fps,
        "diagnostics": model.diagnostics,
    }
    arrays["__meta__"] = np.frombuffer(json.dumps(meta, default=_json_default).encode(), np.uint8)
    buf = _io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_path(path) as tmp:  # usual permissions, removed on failure
        tmp.write_bytes(buf.getvalue())
    return path


def _read_archive(path: Path) -> tuple[dict, dict]:
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, zlib.error, EOFError, KeyError,
            NotImplementedError) as e:
        raise ModelFileError(f"{path}: not a bayesmotion model file (unreadable archive: {e})") \
            from None
    if "__meta__" not in arrays:
        raise ModelFileError(f"{path}: not a bayesmotion model file (no metadata)")
    try:
        meta = json.loads(arrays.pop("__meta__").tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ModelFileError(f"{path}: corrupted metadata: {e}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ModelFileError(f"{path}: not a bayesmotion model file (format "
                             f"{meta.get('format') if isinstance(meta, dict) else None!r})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(f"{path}: model file format version {meta.get('format_version')} "
                             f"is not supported (this bayesmotion reads {FORMAT_VERSION})")
    return meta, arrays


def load(path):
    """Load a model file written by ``FittedHGPDM.save``.

    Raises:
        ModelFileError: the file is missing, corrupted, foreign, or of another format version.
    """
    from .data.affective_codec import codec_from_saved
    from .fitted import FittedHGPDM, TrialRecord
    from .model import HGPDM, ModelData

    path = Path(path)
    meta, arrays = _read_archive(path)
    try:
        spec = HGPDM.from_dict(meta["spec"])
        params = {k: arrays[f"param/{k}"] for k in meta["params"]}
        codecs = tuple(codec_from_saved(m, arrays, f"codec{a}/")
                       for a, m in enumerate(meta["codecs"]))
        if any(c.pose_space != spec.pose_space for c in codecs):
            raise ModelFileError(f"{path}: corrupted model file: its specification's pose space "
                                 f"{spec.pose_space!r} does not match its codecs' "
                                 f"{[c.pose_space for c in codecs]}")
        A = len(codecs)
        data = ModelData(tuple(arrays[f"Y/{a}"] for a in range(A)),
                         {f: arrays[f"onehot/{f}"] for f in meta["factors"]},
                         np.repeat(np.arange(len(arrays["lengths"])), arrays["lengths"]),
                         arrays["lengths"])
        trials = tuple(
            TrialRecord(t["name"], t["labels"], int(t["n_frames"]),
                        tuple(arrays[f"anchor/{r}/{a}"] for a in range(A)),
                        tuple(arrays[f"offsets/{r}/{a}"] for a in range(A)))
            for r, t in enumerate(meta["trials"]))
        model = FittedHGPDM(spec=spec, params=params, codecs=codecs,
                            levels={k: tuple(v) for k, v in meta["levels"].items()}, data=data,
                            trials=trials, fps=float(meta["fps"]),
                            diagnostics=meta.get("diagnostics", {}))
    except ModelFileError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, BayesmotionError) as e:
        raise ModelFileError(f"{path}: corrupted or incomplete model file ({type(e).__name__}: "
                             f"{e})") from None
    _check_shapes(model, path)
    return model


def _check_shapes(model, path):
    """Every array the model uses has the shape its metadata implies, and finite values: a
    file that passes cannot fail later inside ``log_posterior`` or ``generate``."""
    def bad(msg):
        raise ModelFileError(f"{path}: corrupted model file: {msg}")

    spec, data, params = model.spec, model.data, model.params
    lengths = np.asarray(data.lengths)
    if lengths.ndim != 1 or lengths.size != len(model.trials) or np.any(lengths < 1):
        bad(f"trial lengths {lengths.tolist()} do not match the {len(model.trials)} trials")
    if any(int(n) != r.n_frames for n, r in zip(lengths, model.trials, strict=True)):
        bad("trial lengths disagree with the trial records")
    N, R, A = int(lengths.sum()), lengths.size, len(model.codecs)
    o = spec.order
    expected = {"X": (A, N, spec.latent_dim), "I": (N, spec.interaction_dim),
                "log_gamma": (3,), "log_beta": (3,), "log_alpha": (2 + 2 * o,)}
    if set(data.onehot) != set(spec.factors) or not set(spec.factors) <= set(model.levels):
        bad(f"labels of factors {sorted(data.onehot)} (levels of {sorted(model.levels)}) do not "
            f"match the specification's factors {sorted(spec.factors)}")
    for f in spec.factors:
        K = len(model.levels[f])
        h = np.asarray(data.onehot[f])
        if h.shape != (R, K) or not np.all((h == 0) | (h == 1)) or np.any(h.sum(1) != 1):
            bad(f"labels of factor {f!r} are not one-hot ({R}, {K}) over its levels")
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
    for a, Y in enumerate(data.Y):
        if Y.shape != (N, model.codecs[a].dim):
            bad(f"training poses of actor {a} have shape {Y.shape}, expected "
                f"{(N, model.codecs[a].dim)}")
        if not np.all(np.isfinite(Y)):
            bad(f"training poses of actor {a} are not finite")
