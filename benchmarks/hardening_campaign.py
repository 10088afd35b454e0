"""Mutation campaign against the BVH reader, model files and emcee chain files (slow: minutes).

    nice python benchmarks/hardening_campaign.py [--quick] [--only bvh|model|chain]

Seeded mutations, run one after another in this process (no subprocess per case), each timed
and then run again for its traced memory peak (``tracemalloc``: Python and NumPy allocations;
apart, as tracing slows Python several times):

* BVH: >= 2,000 mutations (200 with ``--quick``) of the real CMU file ``18_01.bvh`` (the copy
  shipped in ``bayesmotion/datasets/builtin``): byte flips, truncations, line duplications,
  deletions and swaps, inserted bytes, and numbers replaced by huge, tiny, NaN/inf,
  non-ASCII-digit or malformed text; one to three per case. Each mutated file is written to
  disk and read with ``read_bvh``.
* Model files: >= 700 mutations (70 with ``--quick``) of a tiny saved model (6 trials, 54
  frames, as ``tests/conftest.py``'s ``tiny_model``): byte flips, dropped, duplicated and
  unknown members, array edits (NaN, inf, huge and tiny values, other dtypes and byte orders,
  other shapes), metadata edits (any field replaced or deleted) and header claims. Each is
  loaded with ``bayesmotion.load``; a model that loads generates 10 frames.
* Chain files: 300 mutations (10 with ``--quick``) of a small valid emcee HDF5 chain file
  (20 steps, 8 walkers, 2 dimensions: the joint emcee runner on a Gaussian, written once per
  run), of 44 kinds (``CHAIN_MUTATIONS``; case i's first mutation is kind i modulo 44, one case
  in three adds a second of a random kind): byte flips anywhere or in stored chain and
  log_prob values, zeroed bytes, truncations, appended bytes, random-bytes and empty files;
  the stored iteration negative, zero, too large, a float, string, array or bool; attributes
  deleted or changed; datasets deleted, reshaped, retyped, replaced by a group, shrunk or
  grown; NaN, inf and huge values written into stored chain or log_prob rows (and NaN past the
  stored steps, which is not damage); the group renamed, deleted or replaced by a dataset.
  Each file goes through three stages: ``read`` (``ChainFile(path, read_only=True)``:
  ``get_chain``, ``get_log_prob``, ``get_last_sample``, ``accepted``, ``iteration``),
  ``check`` (``check_chain_file``, what ``sample_posterior`` runs before any work) and
  ``resume`` (``run_emcee`` resuming it to 25 steps: the runner ``sample_posterior`` calls,
  with its checks, grow and saves); each stage's outcome is counted in ``by_stage``.

Outcomes per case: ``accepted`` (a Motion; a model that loads and generates finite motion; a
chain file that every stage reads or resumes with every returned value finite),
``documented error`` (BVHError; ModelFileError at load, or a BayesmotionError from generate on
a loaded model; a BayesmotionError naming the chain file from any stage), ``other exception``
(any other exception, or a chain file's BayesmotionError not naming it: a bug), and the flags
``over time`` (BVH > 1 s, model load > 5 s, a chain file's three stages > 5 s; listed in
``over_time_or_memory``) and ``over memory`` (> 256 MB traced). A loaded model whose
generated motion is not finite is counted apart (``accepted, non-finite output``), and one whose
predictive variances overflow is flagged (``non-finite variance``). A chain file is counted as
``silent acceptance`` when a stage accepted it although its stored steps (read with plain
h5py: the rows below the stored iteration) hold a NaN or inf chain or log_prob value, or a
stage returned a non-finite value; these are listed in ``silent_acceptances`` and must be 0.
The JSON goes to ``results/hardening_campaign.json`` (with ``--only``, that section replaces
its own in the existing JSON of the same mode and the totals are recomputed); the exit status
is 1 if any other exception or silent acceptance happened.
"""

from __future__ import annotations

import argparse
import io
import json
import re
import sys
import tempfile
import time
import traceback
import tracemalloc
import zipfile
from collections import Counter
from functools import partial
from importlib.resources import files
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

from _common import RESULTS, headline, machine_info, write_json  # noqa: E402

NAME = "hardening_campaign"
FULL = {"bvh_cases": 2000, "model_cases": 700, "chain_cases": 300, "seed": 20261126}
QUICK = {"bvh_cases": 200, "model_cases": 70, "chain_cases": 10, "seed": 20261126}
BVH_TIME_S, MODEL_TIME_S, CHAIN_TIME_S, MEMORY_B = 1.0, 5.0, 5.0, 256 * 2**20
NUMBERS = [b"1e308", b"1e309", b"-1e999", b"1e-320", b"nan", b"NaN", b"-inf", b"Infinity",
           "\u0663".encode(), "\uff11\uff12".encode(), "\u00b2".encode("latin-1"), b"1_000",
           b"0x1F", b"1e", b"--1", b".", b"+", b"9" * 400, b"1" * 5000, b"\x00", b"\xff\xfe",
           "\u2028".encode(), b"\x0b", b"1e+0400", b"-0", b"0.0083333", b"1e300"]


# ------------------------------------------------------------------------------- BVH
def mutate_bvh(raw: bytes, rng: np.random.Generator) -> tuple[bytes, list[str]]:
    """One to three seeded edits of a BVH file's bytes; returns the bytes and their names."""
    done = []
    for _ in range(rng.integers(1, 4)):
        kind = str(rng.choice(["flip", "truncate", "duplicate line", "delete line", "swap lines",
                               "insert", "number", "number", "header"]))
        at = int(rng.integers(0, len(raw) + 1))
        lines = raw.split(b"\n")
        i, j = int(rng.integers(0, len(lines))), int(rng.integers(0, len(lines)))
        if kind == "flip" and raw:
            b = bytearray(raw)
            b[at % len(b)] ^= int(rng.integers(1, 256))
            raw = bytes(b)
        elif kind == "truncate":
            raw = raw[:at]
        elif kind == "insert":
            raw = raw[:at] + rng.bytes(int(rng.integers(1, 9))) + raw[at:]
        elif kind == "duplicate line":
            raw = b"\n".join(lines[:i] + [lines[i]] * int(rng.integers(2, 5)) + lines[i + 1:])
        elif kind == "delete line":
            raw = b"\n".join(lines[:i] + lines[i + 1:])
        elif kind == "swap lines":
            lines[i], lines[j] = lines[j], lines[i]
            raw = b"\n".join(lines)
        elif kind == "number":
            toks = list(re.finditer(rb"(?<!\S)[-+.\d][^\s]*", raw))
            if toks:
                t = toks[int(rng.integers(0, len(toks)))]
                raw = raw[:t.start()] + NUMBERS[int(rng.integers(0, len(NUMBERS)))] + raw[t.end():]
        elif kind == "header":
            field = rb"(Frames:|Frame Time:)[^\r\n]*"
            value = NUMBERS[int(rng.integers(0, len(NUMBERS)))]
            key = [b"Frames:", b"Frame Time:"][int(rng.integers(0, 2))]
            raw = re.sub(field, lambda m, k=key, v=value: (k + b" " + v) if m.group(1) == k
                         else m.group(0), raw, count=2)
        done.append(kind)
    return raw, done


def bvh_campaign(n: int, seed: int, folder: Path) -> dict:
    base = (files("bayesmotion") / "datasets" / "builtin" / "18_01.bvh").read_bytes()
    out = Counter()
    by_kind: dict[str, Counter] = {}
    times, peaks, raw_errors, slow = [], [], [], []
    path = folder / "case.bvh"
    for case in range(n):
        rng = np.random.default_rng([seed, case])
        data, kinds = mutate_bvh(base, rng)
        path.write_bytes(data)
        (outcome, raw), dt, peak = _measured(partial(_read_case, path, case, kinds))
        if raw:
            raw_errors.append(raw)
        _record(out, by_kind, kinds, outcome, case, dt, peak, BVH_TIME_S, slow, times, peaks)
    return _summary(n, out, by_kind, times, peaks, raw_errors, slow)


def _read_case(path, case, kinds):
    from bayesmotion.data.bvh import read_bvh
    from bayesmotion.errors import BVHError

    try:
        read_bvh(path)
        return "accepted", None
    except BVHError:
        return "documented error", None
    except Exception as e:  # noqa: BLE001 -- what the campaign counts
        return "other exception", _raw(case, kinds, "read_bvh", e)


def _load_case(path, case, kinds):
    from bayesmotion.errors import ModelFileError
    from bayesmotion.model.io import load

    try:
        return load(path), "loaded", None
    except ModelFileError:
        return None, "documented error", None
    except Exception as e:  # noqa: BLE001 -- what the campaign counts
        return None, "other exception", _raw(case, kinds, "load", e)


def _measured(attempt):
    """(attempt(), seconds, peak traced bytes): timed alone, then run again under tracemalloc
    (which slows Python several times) for its memory."""
    t0 = time.perf_counter()
    result = attempt()
    dt = time.perf_counter() - t0
    tracemalloc.start()
    try:
        attempt()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return result, dt, peak


def _count(out, by_kind, kinds, outcome, slow, big):
    out[outcome] += 1
    out["over time"] += slow
    out["over memory"] += big
    for k in set(kinds):
        by_kind.setdefault(k, Counter())[outcome] += 1


def _record(out, by_kind, kinds, outcome, case, dt, peak, limit_s, slow, times, peaks):
    """Count one case's outcome, listing it when it ran over ``limit_s`` or the memory bound."""
    if dt > limit_s or peak > MEMORY_B:
        slow.append({"case": case, "mutations": kinds, "seconds": dt, "peak_mb": peak / 2**20})
    _count(out, by_kind, kinds, outcome, dt > limit_s, peak > MEMORY_B)
    times.append(dt)
    peaks.append(peak)


def _summary(n, out, by_kind, times, peaks, raw_errors, slow) -> dict:
    t = np.array(times)
    return {"cases": n, "outcomes": dict(out),
            "by_mutation": {k: dict(v) for k, v in sorted(by_kind.items())},
            "seconds_per_case": {"median": float(np.median(t)), "p99": float(np.quantile(t, .99)),
                                 "max": float(t.max()), "total": float(t.sum())},
            "peak_traced_mb": {"median": float(np.median(peaks)) / 2**20,
                               "max": float(max(peaks)) / 2**20},
            "other_exceptions": raw_errors[:50], "over_time_or_memory": slow[:50]}


# --------------------------------------------------------------------------- model files
_META_VALUES = [None, 0, -1, 1, 2, 3.5, 1e300, -1e-300, 1e151, "", "x", "happy", "heading", [],
                {}, [1, 2], {"a": 1}, True, False, 10**30, [[[[[[[[]]]]]]]], "NaN"]


def _npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def _header(shape, descr="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue()


def _json_paths(obj, prefix=()):
    yield prefix
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) \
        if isinstance(obj, list) else ()
    for k, v in items:
        yield from _json_paths(v, (*prefix, k))


def _edit_meta(meta: dict, rng) -> str:
    paths = [p for p in _json_paths(meta) if p]
    path = paths[int(rng.integers(0, len(paths)))]
    parent = meta
    for k in path[:-1]:
        parent = parent[k]
    if rng.random() < 0.25:
        del parent[path[-1]]
        return "meta delete"
    parent[path[-1]] = _META_VALUES[int(rng.integers(0, len(_META_VALUES)))]
    return "meta value"


def _edit_array(a: np.ndarray, rng) -> tuple[np.ndarray | bytes, str]:
    kind = str(rng.choice(["element", "element", "scale", "dtype", "shape", "empty", "claim"]))
    if kind == "element" and a.size:
        a = a.copy()
        i = int(rng.integers(0, a.size))
        if a.dtype.kind == "f":
            a.flat[i] = rng.choice([np.nan, np.inf, -np.inf, 1e300, 1e151, 1e149, 1e-300, -0.0,
                                    1e6, -1e6, 1e3, a.flat[i] * 1.001])
        elif a.dtype.kind in "iu":
            a.flat[i] = int(rng.integers(-3, 300))
        return a, "array element"
    if kind == "scale" and a.dtype.kind == "f":
        return a * rng.choice([0.0, -1.0, 1e-3, 1e3, 1e150, 1.0 + 1e-9]), "array scale"
    if kind == "dtype":
        dt = str(rng.choice(["<f4", ">f8", "<i4", "?", "<u1", ">i8", "<f2", "<c16", "<U3"]))
        return a.astype(dt), "array dtype"
    if kind == "shape":
        return (a.reshape(-1) if a.ndim > 1 else a[: max(a.size - 1, 0)]), "array shape"
    if kind == "claim":
        shape = (int(rng.choice([10**6, 10**9, 10**12])),) + a.shape[1:]
        return _header(shape) + a.tobytes()[:64], "header claim"
    return a[:0], "array empty"


def mutate_model(src: bytes, rng) -> tuple[bytes, list[str]]:
    done = []
    for _ in range(rng.integers(1, 3)):
        kind = str(rng.choice(["bytes", "array", "array", "array", "meta", "meta", "meta",
                               "member"]))
        if kind == "bytes":
            b = bytearray(src)
            b[int(rng.integers(0, len(b)))] ^= int(rng.integers(1, 256))
            src = bytes(b)
            done.append("byte flip")
            continue
        try:
            with zipfile.ZipFile(io.BytesIO(src)) as z:
                entries = {i.filename: z.read(i.filename) for i in z.infolist()}
        except Exception:  # noqa: BLE001 -- an earlier byte flip broke the zip: keep it so
            return src, done
        names = sorted(entries)
        name = names[int(rng.integers(0, len(names)))]
        if kind == "member":
            what = str(rng.choice(["drop", "duplicate", "unknown"]))
            if what == "drop":
                del entries[name]
            elif what == "duplicate":
                entries["param/extra.npy"] = entries[name]
            else:
                entries["zeros.npy"] = _npy(np.zeros(10**6))
            done.append(f"member {what}")
        else:
            name = "__meta__.npy" if kind == "meta" else name
            try:
                a = np.load(io.BytesIO(entries[name]), allow_pickle=False)
            except Exception:  # noqa: BLE001 -- an edited member that no longer loads
                continue
            if kind == "meta" and a.dtype == np.uint8:
                try:
                    meta = json.loads(a.tobytes())
                except ValueError:  # an earlier edit broke it: leave it broken
                    continue
                if not isinstance(meta, dict):
                    continue
                done.append(_edit_meta(meta, rng))
                entries[name] = _npy(np.frombuffer(json.dumps(meta).encode(), np.uint8))
            else:
                with np.errstate(all="ignore"):  # NaN cast to int, overflow: intended
                    new, what = _edit_array(a, rng)
                entries[name] = new if isinstance(new, bytes) else _npy(new)
                done.append(what)
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
            for n, d in entries.items():
                z.writestr(n, d)
        src = buf.getvalue()
    return src, done


def tiny_model():
    """The test suite's tiny model: couple c1's happy and sad handshakes at 5 fps, fitted for
    60 iterations with latent dimensions 3."""
    import bayesmotion as bm

    ds = bm.load_handshakes(fps=5.0).filter(couple="c1", emotion=["happy", "sad"])
    ds = bm.MotionDataset(ds.trials, {"emotion": ("happy", "sad"), "couple": ("c1",)})
    return bm.HGPDM(latent_dim=3, interaction_dim=3).fit(ds, max_iter=60, progress=False)


def model_campaign(n: int, seed: int, folder: Path) -> dict:
    from bayesmotion.errors import BayesmotionError

    base_path = folder / "base.npz"
    tiny_model().save(base_path)
    base = base_path.read_bytes()
    out = Counter()
    by_kind: dict[str, Counter] = {}
    times, peaks, raw_errors, gen_s, slow = [], [], [], [], []
    path = folder / "case.npz"
    for case in range(n):
        rng = np.random.default_rng([seed, case])
        data, kinds = mutate_model(base, rng)
        kinds = kinds or ["none"]
        path.write_bytes(data)
        (model, outcome, raw), dt, peak = _measured(partial(_load_case, path, case, kinds))
        if raw:
            raw_errors.append(raw)
        if model is not None:
            t1 = time.perf_counter()
            try:
                levels = model.levels.get("emotion", ("neutral",))
                r = model.generate(emotion=levels[0], n_frames=10)
                outcome = ("accepted" if np.all(np.isfinite(r.angles))
                           and np.all(np.isfinite(r.positions)) else
                           "accepted, non-finite output")
                out["non-finite variance"] += not (np.all(np.isfinite(r.angles_var))
                                                   and np.all(np.isfinite(r.positions_var)))
            except BayesmotionError:
                outcome = "documented error"
                out["generate refused"] += 1
            except Exception as e:  # noqa: BLE001 -- what the campaign counts
                outcome = "other exception"
                raw_errors.append(_raw(case, kinds, "generate", e))
            gen_s.append(time.perf_counter() - t1)
        _record(out, by_kind, kinds, outcome, case, dt, peak, MODEL_TIME_S, slow, times, peaks)
    res = _summary(n, out, by_kind, times, peaks, raw_errors, slow)
    res["generated"] = len(gen_s)
    res["generate_seconds_total"] = float(sum(gen_s))
    return res


def _raw(case, kinds, stage, e) -> dict:
    return {"case": case, "mutations": kinds, "stage": stage,
            "error": f"{type(e).__name__}: {e}"[:300], "traceback": traceback.format_exc()[-1500:]}


# --------------------------------------------------------------------------- chain files
CHAIN_GROUP, CHAIN_STEPS, CHAIN_WALKERS = "mcmc", 20, 8
CHAIN_MU, CHAIN_SD = np.array([1.0, -2.0]), np.array([0.5, 2.0])
_ATTRS = ("nwalkers", "ndim", "iteration", "has_blobs", *(f"random_state_{i}" for i in range(5)))
_DATASETS = ("chain", "log_prob", "accepted")


class _Gaussian:
    """N(CHAIN_MU, diag(CHAIN_SD^2)) in the runner's target interface."""

    ndim, model = CHAIN_MU.size, None

    def logp_batch(self, xs):
        return -0.5 * np.sum(((np.asarray(xs) - CHAIN_MU) / CHAIN_SD) ** 2, axis=-1)


def _run_chain(path, n_steps: int):
    """The joint emcee runner (as ``sample_posterior`` calls it) on a 2-D Gaussian, writing or
    resuming the chain file ``path``: it checks the file (``check_chain_file``), opens and
    grows its group and saves each step."""
    import warnings

    from bayesmotion.inference.emcee_runner import run_emcee
    from bayesmotion.inference.posterior import ChainTooShortWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        return run_emcee(_Gaussian(), CHAIN_MU, n_walkers=CHAIN_WALKERS, n_steps=n_steps,
                         burn=0, thin=1, seed=3, backend=path, progress=False, init="ball",
                         ball=1e-2, moves=None)


def _group_edit(edit):
    """A mutation editing the chain group of the file in place with h5py."""
    def apply(path, rng):
        import h5py

        with h5py.File(path, "a") as f:
            edit(f[CHAIN_GROUP], rng)
    return apply


def _file_edit(edit):
    """A mutation of the file's bytes."""
    def apply(path, rng):
        path.write_bytes(edit(path.read_bytes(), rng))
    return apply


def _pick(rng, seq):
    return seq[int(rng.integers(0, len(seq)))]


def _stored_index(g, key: str, rng) -> tuple:
    """A random element of dataset ``key`` within the stored steps."""
    ds = g[key]
    n = min(int(g.attrs["iteration"]), ds.shape[0])
    if n <= 0:
        raise ValueError("no stored step")
    return (int(rng.integers(0, n)),) + tuple(int(rng.integers(0, m)) for m in ds.shape[1:])


def _element_offset(path, key: str, index: tuple) -> int:
    """Byte offset in the file of one element of a chunked, uncompressed dataset."""
    import h5py

    with h5py.File(path, "r") as f:
        ds = f[f"{CHAIN_GROUP}/{key}"]
        start = tuple(i - i % c for i, c in zip(index, ds.chunks, strict=True))
        info = ds.id.get_chunk_info_by_coord(start)
        local = np.ravel_multi_index(tuple(i - s for i, s in zip(index, start, strict=True)),
                                     ds.chunks)
        return int(info.byte_offset) + int(local) * ds.dtype.itemsize


def _data_bytes(key: str, exponent: bool):
    """Flip one byte of a stored element of ``key`` (``exponent``: set every exponent bit of
    the float64, making it NaN or inf)."""
    def apply(path, rng):
        import h5py

        with h5py.File(path, "r") as f:
            index = _stored_index(f[CHAIN_GROUP], key, rng)
        off = _element_offset(path, key, index)
        b = bytearray(path.read_bytes())
        if exponent:
            b[off + 6] |= 0xF0
            b[off + 7] |= 0x7F
        else:
            b[off + int(rng.integers(0, 8))] ^= int(rng.integers(1, 256))
        path.write_bytes(bytes(b))
    return apply


def _set_value(key: str, values, row: bool = False):
    """Write one of ``values`` at a random element (``row``: a whole step) of ``key`` within
    the stored steps."""
    def edit(g, rng):
        index = _stored_index(g, key, rng)
        g[key][index[:1] if row else index] = _pick(rng, values)
    return _group_edit(edit)


def _set_attr(key, values):
    return _group_edit(lambda g, rng: g.attrs.__setitem__(key, _pick(rng, values)))


def _flip_bytes(n):
    def edit(raw, rng):
        b = bytearray(raw)
        for _ in range(n):
            b[int(rng.integers(0, len(b)))] ^= int(rng.integers(1, 256))
        return bytes(b)
    return edit


def _zero_run(raw, rng):
    at, n = int(rng.integers(0, len(raw))), int(rng.integers(8, 257))
    return raw[:at] + bytes(len(raw[at:at + n])) + raw[at + n:]


def _del_attr(g, rng):
    del g.attrs[_pick(rng, _ATTRS)]


def _shape_attr(g, rng):
    g.attrs[_pick(rng, ("nwalkers", "ndim"))] = int(rng.integers(-3, 20))


def _del_dataset(g, rng):
    del g[_pick(rng, _DATASETS)]


def _wrong_shape(g, rng):
    key = _pick(rng, _DATASETS)
    shape = list(g[key].shape)
    axis = int(rng.integers(0, len(shape) + 1))
    if axis == len(shape):
        shape.append(int(rng.integers(1, 4)))  # one axis more
    else:
        shape[axis] = max(0, shape[axis] + int(rng.choice([-3, -1, 1, 2])))
    del g[key]
    g.create_dataset(key, data=np.zeros(shape))


def _wrong_dtype(g, rng):
    key = _pick(rng, _DATASETS)
    data = g[key][...]
    dtype = _pick(rng, ("<i8", "?", "<f2", ">f4", "<c16", "S8", "<u1"))
    del g[key]
    with np.errstate(all="ignore"):
        g.create_dataset(key, data=data.astype(dtype))


def _shrunk(g, rng):
    n = int(rng.integers(0, g["chain"].shape[0]))
    for key in _pick(rng, (("chain",), ("log_prob",), ("chain", "log_prob"))):
        g[key].resize(n, axis=0)


def _grown_nan(g, rng):
    """Rows past the stored steps, holding NaN (as a killed longer run leaves unwritten rows):
    not damage."""
    n, more = g["chain"].shape[0], int(rng.integers(1, 30))
    for key in ("chain", "log_prob"):
        g[key].resize(n + more, axis=0)
        g[key][n:] = np.nan


def _lowered_nan_after(g, rng):
    """The stored iteration lowered to k (the acceptance counts capped at k), NaN written in the
    rows after it: not damage."""
    it = int(g.attrs["iteration"])
    k = int(rng.integers(1, it))
    g.attrs["iteration"] = k
    g["accepted"][...] = np.minimum(g["accepted"][...], k)
    g["chain"][k:it] = np.nan
    g["log_prob"][k:it] = np.inf


def _accepted_out(g, rng):
    it = int(g.attrs["iteration"])
    acc = g["accepted"][...].astype(float)
    acc[int(rng.integers(0, acc.size))] = _pick(rng, (-1.0, it + 1.0, np.nan, np.inf, 1e300))
    g["accepted"][...] = acc


def _dataset_to_group(g, rng):
    key = _pick(rng, _DATASETS)
    del g[key]
    g.create_group(key)


def _extra_member(g, rng):
    g.create_dataset(f"extra_{int(rng.integers(0, 100))}", data=rng.random(5))


def _root_edit(edit):
    def apply(path, rng):
        import h5py

        with h5py.File(path, "a") as f:
            edit(f, rng)
    return apply


def _renamed(f, rng):
    f.move(CHAIN_GROUP, _pick(rng, ("mcmc_old", "MCMC", "gamma", "chain")))


def _group_to_dataset(f, rng):
    del f[CHAIN_GROUP]
    f[CHAIN_GROUP] = rng.random(int(rng.integers(0, 10)))


def _group_deleted(f, rng):
    del f[CHAIN_GROUP]


#: name -> mutation(path, rng): each edits the file at ``path`` in place
CHAIN_MUTATIONS = {
    # bytes
    "byte flip": _file_edit(_flip_bytes(1)),
    "byte flips x8": _file_edit(_flip_bytes(8)),
    "bytes zeroed": _file_edit(_zero_run),
    "chain data byte flip": _data_bytes("chain", exponent=False),
    "log_prob data byte flip": _data_bytes("log_prob", exponent=False),
    "chain data exponent set": _data_bytes("chain", exponent=True),
    "log_prob data exponent set": _data_bytes("log_prob", exponent=True),
    "truncated": _file_edit(lambda raw, rng: raw[:int(rng.integers(0, len(raw)))]),
    "truncated in its header": _file_edit(lambda raw, rng: raw[:int(rng.integers(0, 2048))]),
    "random bytes appended": _file_edit(
        lambda raw, rng: raw + rng.bytes(int(rng.integers(1, 4097)))),
    "random bytes file": _file_edit(lambda raw, rng: rng.bytes(int(rng.integers(1, 8193)))),
    "random bytes after the signature": _file_edit(
        lambda raw, rng: raw[:8] + rng.bytes(len(raw) - 8)),
    "empty file": _file_edit(lambda raw, rng: b""),
    # the stored iteration
    "iteration negative": _set_attr("iteration", (-1, -2, -CHAIN_STEPS, -(2**31), -(2**62))),
    "iteration too large": _set_attr("iteration", (CHAIN_STEPS + 1, CHAIN_STEPS + 5, 10**6,
                                                   2**62, np.uint64(2**64 - 1))),
    "iteration a float": _set_attr("iteration", (2.5, float(CHAIN_STEPS), np.nan, np.inf,
                                                 -0.5, 1e300)),
    "iteration a string": _set_attr("iteration", ("20", "twenty", b"\xff", "")),
    "iteration an array": _set_attr("iteration", (np.arange(3), np.array([CHAIN_STEPS]),
                                                  np.zeros((0,)))),
    "iteration a bool": _set_attr("iteration", (True, False)),
    "iteration zero": _set_attr("iteration", (0, np.int8(0), np.uint64(0))),
    "iteration lowered, NaN after it": _group_edit(_lowered_nan_after),
    # other attributes
    "attribute deleted": _group_edit(_del_attr),
    "nwalkers or ndim changed": _group_edit(_shape_attr),
    "has_blobs set": _set_attr("has_blobs", (True, 1, 7)),
    "random state garbage": _group_edit(lambda g, rng: g.attrs.__setitem__(
        f"random_state_{int(rng.integers(0, 5))}",
        _pick(rng, (np.arange(3), "x", -1, np.zeros(624, dtype=np.uint8), 2.5)))),
    "adaptation length bad": _set_attr("bayesmotion_adapt_steps", (-4, 2.5, "ten", np.arange(2))),
    "refit steps bad": _set_attr("bayesmotion_refit_steps",
                                 (np.array([400, 300]), np.array([2.5]), "ten", -1,
                                  np.zeros((2, 2), dtype=int))),
    # datasets
    "dataset deleted": _group_edit(_del_dataset),
    "dataset of another shape": _group_edit(_wrong_shape),
    "dataset of another dtype": _group_edit(_wrong_dtype),
    "dataset replaced by a group": _group_edit(_dataset_to_group),
    "datasets shrunk": _group_edit(_shrunk),
    "datasets grown with NaN rows": _group_edit(_grown_nan),
    "accepted out of range": _group_edit(_accepted_out),
    "extra dataset": _group_edit(_extra_member),
    # stored values
    "NaN in chain": _set_value("chain", (np.nan,)),
    "inf in chain": _set_value("chain", (np.inf, -np.inf)),
    "NaN row in chain": _set_value("chain", (np.nan, np.inf), row=True),
    "NaN in log_prob": _set_value("log_prob", (np.nan,)),
    "inf in log_prob": _set_value("log_prob", (np.inf, -np.inf)),
    "huge value in chain": _set_value("chain", (1e308, -1e308, 1e-320)),
    "huge value in log_prob": _set_value("log_prob", (-1e308, 1e308)),
    # the group
    "group renamed": _root_edit(_renamed),
    "group deleted": _root_edit(_group_deleted),
    "group replaced by a dataset": _root_edit(_group_to_dataset),
}


def mutate_chain(base: bytes, path: Path, case: int, rng) -> tuple[bytes, list[str]]:
    """The base file with one or two seeded mutations: the first of kind ``case`` modulo the
    kinds (so every kind is run), a second (one case in three) of a random kind, dropped (the
    file as the first left it) when it cannot be applied to what the first left."""
    names = list(CHAIN_MUTATIONS)
    kinds = [names[case % len(names)]]
    if rng.random() < 1 / 3:
        kinds.append(_pick(rng, names))
    data, done = base, []
    for k in kinds:
        path.write_bytes(data)
        try:
            CHAIN_MUTATIONS[k](path, rng)
        except Exception:  # noqa: BLE001 -- an earlier mutation left nothing to edit: keep it
            if not done:
                raise
            continue
        data = path.read_bytes()
        done.append(k)
    return data, done


def _stored_nonfinite(path) -> bool | None:
    """Whether the chain group's stored steps (all rows when the stored iteration is not an
    integer) hold a non-finite chain or log_prob value, read with plain h5py; None when h5py
    cannot tell."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            g = f[CHAIN_GROUP]
            it = np.asarray(g.attrs.get("iteration", -1))
            for key in ("chain", "log_prob"):
                ds = g[key]
                n = ds.shape[0]
                if it.shape == () and it.dtype.kind in "iu":
                    n = min(max(int(it), 0), n)
                if not np.all(np.isfinite(ds[:n])):
                    return True
        return False
    except Exception:  # noqa: BLE001 -- a file plain h5py cannot read either
        return None


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=np.float64))) for a in arrays)


def _chain_stages(data: bytes, path: Path, case: int, kinds: list[str]):
    """What a user does with the file: read it with ChainFile, check it as sample_posterior
    does, resume it with the runner. Returns {stage: outcome} and the raw errors."""
    from bayesmotion.errors import BayesmotionError
    from bayesmotion.inference.chainfile import ChainFile, check_chain_file

    path.write_bytes(data)
    damaged = _stored_nonfinite(path)
    outcomes, raw = {}, []

    def read():
        be = ChainFile(str(path), read_only=True)
        chain, log_prob = be.get_chain(), be.get_log_prob()
        last = be.get_last_sample()
        return (_finite(chain, log_prob, last.coords, last.log_prob, be.accepted)
                and be.iteration == len(chain) == len(log_prob))

    def check():
        check_chain_file(path)
        return True

    def resume():
        post = _run_chain(path, CHAIN_STEPS + 5)
        be = ChainFile(str(path), read_only=True)
        return _finite(post.chains, be.get_chain(), be.get_log_prob())

    for stage, attempt in (("read", read), ("check", check), ("resume", resume)):
        try:
            finite = attempt()
            outcomes[stage] = ("silent acceptance" if damaged or not finite else "accepted")
        except BayesmotionError as e:
            outcomes[stage] = "documented error"
            if str(path) not in str(e):
                raw.append({**_raw(case, kinds, stage, e), "why": "message lacks the path"})
                outcomes[stage] = "other exception"
        except Exception as e:  # noqa: BLE001 -- what the campaign counts
            outcomes[stage] = "other exception"
            raw.append(_raw(case, kinds, stage, e))
    return outcomes, raw


def chain_campaign(n: int, seed: int, folder: Path) -> dict:
    base_path = folder / "base.h5"
    _run_chain(base_path, CHAIN_STEPS)
    base = base_path.read_bytes()
    out = Counter()
    by_kind: dict[str, Counter] = {}
    by_stage: dict[str, Counter] = {}
    times, peaks, raw_errors, slow, silent = [], [], [], [], []
    work, path = folder / "mutating.h5", folder / "case.h5"
    for case in range(n):
        rng = np.random.default_rng([seed, case])
        data, kinds = mutate_chain(base, work, case, rng)
        (stages, raw), dt, peak = _measured(partial(_chain_stages, data, path, case, kinds))
        raw_errors.extend(raw)
        for stage, o in stages.items():
            by_stage.setdefault(stage, Counter())[o] += 1
        order = ("other exception", "silent acceptance", "documented error", "accepted")
        outcome = next(o for o in order if o in stages.values())
        if outcome == "silent acceptance":
            silent.append({"case": case, "mutations": kinds, "stages": stages})
        _record(out, by_kind, kinds, outcome, case, dt, peak, CHAIN_TIME_S, slow, times, peaks)
    res = _summary(n, out, by_kind, times, peaks, raw_errors, slow)
    res["outcomes"].setdefault("silent acceptance", 0)
    res["outcomes"].setdefault("other exception", 0)
    res["by_stage"] = {k: dict(v) for k, v in by_stage.items()}
    res["mutation_kinds"] = len(CHAIN_MUTATIONS)
    res["silent_acceptances"] = silent[:50]
    res["base_file"] = {"steps": CHAIN_STEPS, "walkers": CHAIN_WALKERS, "ndim": CHAIN_MU.size,
                        "bytes": len(base)}
    return res


# ------------------------------------------------------------------------------ driver
def _headline(res: dict) -> list:
    rows = []
    for key, name in (("bvh", "BVH mutations"), ("model", "model-file mutations"),
                      ("chain", "chain-file mutations")):
        if key not in res:
            continue
        r = res[key]
        o = r["outcomes"]
        note = (f"accepted {o.get('accepted', 0)}, documented errors "
                f"{o.get('documented error', 0)}, over time {o.get('over time', 0)}, over "
                f"memory {o.get('over memory', 0)}")
        rows.append(headline(f"{name}: other exceptions of {r['cases']}",
                             o.get("other exception", 0), "", "0",
                             o.get("other exception", 0) == 0, note))
        if key == "chain":
            rows.append(headline(f"{name}: corrupted steps silently accepted of {r['cases']}",
                                 o.get("silent acceptance", 0), "", "0",
                                 o.get("silent acceptance", 0) == 0, note))
    return rows


def _totals(res: dict) -> dict:
    parts = [res[k] for k in ("bvh", "model", "chain") if k in res]
    res["other_exceptions"] = sum(r["outcomes"].get("other exception", 0) for r in parts)
    res["silent_acceptances"] = sum(r["outcomes"].get("silent acceptance", 0) for r in parts)
    res["headline"] = _headline(res)
    return res


def run(quick: bool, only: str | None = None) -> dict:
    settings = QUICK if quick else FULL
    res = {"settings": settings}
    with tempfile.TemporaryDirectory() as tmp:
        if only in (None, "bvh"):
            res["bvh"] = bvh_campaign(settings["bvh_cases"], settings["seed"], Path(tmp))
        if only in (None, "model"):
            res["model"] = model_campaign(settings["model_cases"], settings["seed"], Path(tmp))
        if only in (None, "chain"):
            res["chain"] = chain_campaign(settings["chain_cases"], settings["seed"], Path(tmp))
    return _totals(res)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="200 BVH, 70 model-file and 10 chain-file cases")
    ap.add_argument("--only", choices=("bvh", "model", "chain"),
                    help="run one section and merge it into the existing JSON of the same mode, "
                         "keeping the other sections' results")
    a = ap.parse_args()
    import bayesmotion  # noqa: F401  (float64 on)

    mode = "quick" if a.quick else "full"
    t0 = time.perf_counter()
    res = run(a.quick, a.only)
    wall = time.perf_counter() - t0
    out = {"name": NAME, "mode": mode, **res, "wall_s": wall}
    target = RESULTS / f"{NAME}.json"
    if a.only:
        old = json.loads(target.read_text()) if target.exists() else {}
        if old.get("mode") != mode:
            print(f"{target} holds no {mode} run to merge into", file=sys.stderr)
            return 2
        key = f"{a.only}_cases"
        old["settings"] = {**old.get("settings", {}), key: res["settings"][key]}
        old[a.only] = res[a.only]
        old.setdefault("section_runs", {})[a.only] = {"wall_s": wall, "machine": machine_info()}
        out = _totals(old)
        out.update(status="ok")
    else:
        out.update(status="ok", machine=machine_info())
    write_json(target, out)
    for part in ("bvh", "model", "chain"):
        if part in out:
            print(part, out[part]["cases"], "cases:", out[part]["outcomes"])
    for part in ("bvh", "model", "chain"):
        for e in out.get(part, {}).get("other_exceptions", []):
            print("OTHER EXCEPTION:", part, e["case"], e["mutations"], e["stage"], e["error"])
    for e in out.get("chain", {}).get("silent_acceptances", []):
        print("SILENT ACCEPTANCE:", e["case"], e["mutations"], e["stages"])
    return 1 if out["other_exceptions"] or out["silent_acceptances"] else 0


if __name__ == "__main__":
    sys.exit(main())
