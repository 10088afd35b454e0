"""Model files: ``.npz`` arrays plus JSON metadata, written atomically, never pickled.

Layout of the archive (a zip of ``<name>.npy`` members, each a plain numeric array):

* ``__meta__``: UTF-8 JSON as uint8 -- format name and version, package version, the model
  specification and priors, label levels, codecs (skeleton, root mode), trial records (names,
  labels, lengths), fit diagnostics, and the emotion evidence's calibration (``calibration``,
  empty when not calibrated);
* ``param/<key>``: unconstrained parameters; ``Y/<a>``: training poses per actor;
  ``onehot/<factor>``; ``lengths``; ``codec<a>/...``: normalisation arrays;
  ``anchor/<r>/<a>`` and ``offsets/<r>/<a>``: per-trial decoding anchors and bone offsets.

Reading (:func:`open_archive`) checks the whole file against that format before anything uses
it: the metadata is at most :data:`MAX_META_BYTES` of UTF-8 JSON nested at most
:data:`MAX_META_DEPTH` deep, without NaN or infinity; each member is read only when the loader
asks for it by the name the format gives it, its ``.npy`` header (version 1 or 2) is checked
before its data -- a plain numeric dtype (bool, integer, float up to 64 bits; big-endian data is
converted to native order), at most :data:`MAX_NDIM` dimensions, and exactly as many bytes as
the zip directory says the member holds -- and the arrays together may take at most
:data:`MAX_ARRAY_BYTES`. Every float must be finite (NaN only where the format uses it: a
codec's ``branch``) and at most :data:`MAX_ABS` in magnitude, so its square cannot overflow.
Members the format does not name are never read; :func:`bayesmotion.load` refuses a file that
holds any.
"""

from __future__ import annotations

import contextlib
import io as _io
import json
import lzma
import math
import re
import struct
import zipfile
import zlib
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from bayesmotion._version import __version__
from bayesmotion.data.files import NotRegularFileError, atomic_path, open_regular
from bayesmotion.errors import ModelFileError

FORMAT = "bayesmotion-hgpdm"
FORMAT_VERSION = 1
MAX_META_BYTES = 16 * 2**20
"""Largest metadata accepted (a fitted model's is ~10 kB plus 50 bytes per trial)."""
MAX_META_DEPTH = 32
"""Deepest nesting of lists and objects accepted in the metadata (the format nests 7: a
codec's skeleton's End Site offsets, counting the number)."""
MAX_ARRAY_BYTES = 2**30
"""Bytes the arrays of one model file may take, decompressed: the training set of a model
whose N x N Gram matrices fit in memory is far smaller (N = 10,000 frames of 200 channels
for two actors: 32 MB)."""
MAX_NDIM = 4
"""Most dimensions of one array (the format uses 3)."""
MAX_ABS = 1e150
"""Largest magnitude of a stored float: its square (a variance, a squared distance) stays
finite in float64."""
_NAN_ALLOWED = re.compile(r"codec\d+/branch")  # NaN marks a column with no branch reference
_UNREADABLE = (zipfile.BadZipFile, zlib.error, lzma.LZMAError, EOFError, OSError, ValueError,
               NotImplementedError, RuntimeError, struct.error, OverflowError, KeyError)


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
    if model.data.loops is not None:
        arrays["loops"] = np.asarray(model.data.loops)
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
        "calibration": model.calibration,
    }
    return write_archive(path, meta, arrays)


def write_archive(path, meta: dict, arrays: dict[str, np.ndarray]) -> Path:
    """``arrays`` plus ``meta`` (JSON) as ``__meta__``, compressed, written atomically."""
    path = Path(path)
    arrays = {**arrays, "__meta__": np.frombuffer(
        json.dumps(meta, default=_json_default).encode(), np.uint8)}
    buf = _io.BytesIO()
    np.savez_compressed(buf, **arrays)
    with atomic_path(path) as tmp:  # usual permissions, removed on failure
        tmp.write_bytes(buf.getvalue())
    return path


@contextlib.contextmanager
def open_archive(path: Path, fmt: str = FORMAT,
                 version: int = FORMAT_VERSION) -> Iterator[tuple[dict, ArchiveArrays]]:
    """The checked metadata of a model file and its arrays, read on demand (module docstring).

    ``fmt`` / ``version``: the format the metadata must name; other files this package writes
    in the same layout (rollout files, :mod:`bayesmotion.model.rollout`) pass theirs.

    Raises:
        ModelFileError: the file is missing, not a regular file, not a zip, not of this
            format or version, or its metadata breaks the limits.
    """
    path = Path(path)
    what = _what(fmt)
    with _open_file(path, what) as fh:
        try:
            zf = zipfile.ZipFile(fh)
        except _UNREADABLE as e:
            raise ModelFileError(f"{path}: not a bayesmotion {what} (unreadable archive: "
                                 f"{e})") from None
        with zf:
            arrays = ArchiveArrays(zf, path, what)
            yield _read_meta(arrays, path, fmt, version), arrays


def _what(fmt: str) -> str:
    """How messages name a file of format ``fmt``: "model file", "rollout file"."""
    return "model file" if fmt == FORMAT else f"{fmt.removeprefix('bayesmotion-')} file"


@contextlib.contextmanager
def _open_file(path: Path, what: str = "model file"):
    """``path`` opened for reading, if a regular file (a FIFO is never opened)."""
    where = repr(str(path)) if "\x00" in str(path) else str(path)
    opened = contextlib.ExitStack()
    try:
        fh = opened.enter_context(open_regular(path))
    except NotRegularFileError:
        raise ModelFileError(f"{where}: not a {what}: not a regular file") from None
    except ValueError:
        raise ModelFileError(f"{where}: the path contains a NUL byte") from None
    except FileNotFoundError as e:
        raise ModelFileError(f"{where}: no such {what} ({e.strerror})") from None
    except OSError as e:
        raise ModelFileError(f"{where}: cannot read {what} ({e.strerror or e})") from None
    with opened:
        yield fh


class ArchiveArrays(Mapping):
    """The arrays of an open model archive by name (``"param/X"``), each read and checked
    when first asked for; ``in`` and iteration read nothing.

    Attributes:
        total_bytes: bytes of the arrays read so far.
    """

    def __init__(self, zf: zipfile.ZipFile, path: Path, what: str = "model file"):
        self._zf, self._path, self._what = zf, path, what
        self._members: dict[str, zipfile.ZipInfo] = {}
        self._others: list[str] = []
        for info in zf.infolist():
            name = info.filename
            key = name[:-4] if name.endswith(".npy") else None
            if key is None or key in self._members:
                if key is not None:
                    raise ModelFileError(f"{path}: corrupted {what}: member {name!r} is "
                                         f"stored twice")
                self._others.append(name)
            else:
                self._members[key] = info
        self._read: dict[str, np.ndarray] = {}
        self.total_bytes = 0

    def __contains__(self, key) -> bool:
        return key in self._members

    def __iter__(self):
        return iter(self._members)

    def __len__(self) -> int:
        return len(self._members)

    def __getitem__(self, key: str) -> np.ndarray:
        if key not in self._read:
            if key not in self._members:
                raise KeyError(key)
            self._read[key] = self._load(key)
        return self._read[key]

    def unread(self) -> list[str]:
        """Members never asked for: those the format does not name, as the loader asks for
        every one it names."""
        return sorted(self._others + [k + ".npy" for k in self._members if k not in self._read])

    def _load(self, key: str, limit: int | None = None) -> np.ndarray:
        """Member ``key`` checked (module docstring); ``limit``: its own byte limit, apart
        from the arrays' total (the metadata's)."""
        info = self._members[key]

        def bad(msg):
            return ModelFileError(f"{self._path}: corrupted {self._what}: member "
                                  f"{info.filename!r} "
                                  f"{msg}")

        if limit is None:
            budget = MAX_ARRAY_BYTES - self.total_bytes
            limit_name = f"the {budget} bytes left of MAX_ARRAY_BYTES = {MAX_ARRAY_BYTES}"
        else:
            budget, limit_name = limit, f"its limit of {limit} bytes"
        try:
            with self._zf.open(info) as f:
                shape, dtype, fortran = _header(f, bad)
                nbytes = math.prod(shape) * dtype.itemsize
                held = info.file_size - f.tell()
                if nbytes != held:
                    raise bad(f"declares a {shape} {dtype} array ({nbytes} bytes) but holds "
                              f"{held} bytes")
                if nbytes > budget:
                    raise ModelFileError(
                        f"{self._path}: member {info.filename!r} declares {nbytes} bytes, more "
                        f"than {limit_name} (bayesmotion.model.archive): not a {self._what} this "
                        f"package wrote; nothing was read")
                data = f.read(nbytes)
                if len(data) != nbytes or f.read(1):
                    raise bad("ends before or after its declared size")
        except _UNREADABLE as e:
            raise bad(f"is unreadable ({type(e).__name__}: {e})") from None
        if limit is None:
            self.total_bytes += nbytes
        a = np.frombuffer(data, dtype)
        a = a.reshape(shape[::-1]).transpose() if fortran else a.reshape(shape)
        return _checked(a, key, bad)


def _header(f, bad) -> tuple[tuple[int, ...], np.dtype, bool]:
    """Shape, dtype and Fortran order from an ``.npy`` header, refused unless a plain numeric
    array."""
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
    else:
        raise bad(f"has .npy format version {version}; model files use 1.0 or 2.0")
    if dtype.hasobject or dtype.kind not in "biuf" or dtype.itemsize > 8:
        raise bad(f"has dtype {dtype} ({dtype.str}); model files hold bool, integer or float "
                  "arrays of at most 64 bits, never objects, strings or records")
    if len(shape) > MAX_NDIM:
        raise bad(f"has {len(shape)} dimensions; model files hold at most {MAX_NDIM}")
    return shape, dtype, bool(fortran)


def _checked(a: np.ndarray, key: str, bad) -> np.ndarray:
    """A writable native-order copy (floats as float64), after the value checks of the module
    docstring."""
    if a.dtype.kind == "b":
        return a.view(np.uint8) != 0  # any nonzero byte is True
    if a.dtype.kind in "iu":
        return a.astype(a.dtype.newbyteorder("="))
    a = a.astype(np.float64)
    nan = np.isnan(a)
    if nan.any() and not _NAN_ALLOWED.fullmatch(key):
        raise bad("holds NaN")
    big = np.abs(np.where(nan, 0.0, a)) > MAX_ABS
    if big.any():
        raise bad(f"holds values beyond +-{MAX_ABS:g} (infinite or overflowing when squared), "
                  f"e.g. {a[big].flat[0]!r}")
    return a


def _read_meta(arrays: ArchiveArrays, path: Path, fmt: str = FORMAT,
               version: int = FORMAT_VERSION) -> dict:
    if "__meta__" not in arrays:
        raise ModelFileError(f"{path}: not a bayesmotion {_what(fmt)} (no metadata)")
    raw = arrays._load("__meta__", limit=MAX_META_BYTES)  # not counted with the arrays
    arrays._read["__meta__"] = raw  # read: not an unknown member
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise ModelFileError(f"{path}: corrupted metadata: expected UTF-8 bytes, got a "
                             f"{raw.shape} {raw.dtype} array")
    try:
        meta = json.loads(raw.tobytes().decode(), parse_constant=_no_constant,
                          parse_float=_finite_float)
    except RecursionError:  # the C decoder checks its depth: past ~1000 levels
        meta, deep = None, True
    except (UnicodeDecodeError, ValueError) as e:  # json.JSONDecodeError is a ValueError
        raise ModelFileError(f"{path}: corrupted metadata: {e}") from None
    else:
        deep = _depth(meta) > MAX_META_DEPTH
    if deep:
        raise ModelFileError(f"{path}: corrupted metadata: lists and objects nested more than "
                             f"{MAX_META_DEPTH} levels deep (bayesmotion.model.archive."
                             f"MAX_META_DEPTH); the format nests 7")
    what = _what(fmt)
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        raise ModelFileError(f"{path}: not a bayesmotion {what} (format "
                             f"{meta.get('format') if isinstance(meta, dict) else None!r})")
    if type(meta.get("format_version")) is not int or meta["format_version"] != version:
        raise ModelFileError(f"{path}: {what} format version {meta.get('format_version')!r} "
                             f"is not supported (this bayesmotion reads {version})")
    return meta


def _no_constant(name: str):
    raise ValueError(f"{name} is not allowed in model metadata")


def _finite_float(text: str) -> float:
    x = float(text)
    if not math.isfinite(x):
        raise ValueError(f"number {text[:40]!r} overflows float64")
    return x


def _depth(obj) -> int:
    """Nesting depth of lists and dicts, a scalar counting one (iterative; stops past
    :data:`MAX_META_DEPTH`)."""
    stack, deepest = [(obj, 1)], 0
    while stack:
        o, d = stack.pop()
        deepest = max(deepest, d)
        if d > MAX_META_DEPTH:
            return d
        if isinstance(o, dict):
            stack.extend((v, d + 1) for v in o.values())
        elif isinstance(o, list):
            stack.extend((v, d + 1) for v in o)
    return deepest
