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

from bayesmotion._version import __version__
from bayesmotion.data.files import atomic_path
from bayesmotion.errors import ModelFileError

FORMAT = "bayesmotion-hgpdm"
FORMAT_VERSION = 1


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def save_model(model, path) -> Path:
    """Write ``model`` (a FittedHGPDM) to ``path`` in the layout above, atomically."""

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


def read_archive(path: Path) -> tuple[dict, dict]:
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
