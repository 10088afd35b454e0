"""Mutation campaign against the BVH reader and model files (slow: minutes).

    nice python benchmarks/hardening_campaign.py [--quick]

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

Outcomes per case: ``accepted`` (a Motion; a model that loads and generates finite motion),
``documented error`` (BVHError; ModelFileError at load, or a BayesmotionError from generate on
a loaded model), ``other exception`` (any other exception: a bug), and the flags ``over time``
(BVH > 1 s, model load > 5 s; listed in ``over_time_or_memory``) and ``over memory``
(> 256 MB traced). A loaded model whose
generated motion is not finite is counted apart (``accepted, non-finite output``), and one whose
predictive variances overflow is flagged (``non-finite variance``). The JSON
goes to ``results/hardening_campaign.json``; the exit status is 1 if any other exception
happened.
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
FULL = {"bvh_cases": 2000, "model_cases": 700, "seed": 20261126}
QUICK = {"bvh_cases": 200, "model_cases": 70, "seed": 20261126}
BVH_TIME_S, MODEL_TIME_S, MEMORY_B = 1.0, 5.0, 256 * 2**20
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
        if dt > BVH_TIME_S or peak > MEMORY_B:
            slow.append({"case": case, "mutations": kinds, "seconds": dt, "peak_mb": peak / 2**20})
        _count(out, by_kind, kinds, outcome, dt > BVH_TIME_S, peak > MEMORY_B)
        times.append(dt)
        peaks.append(peak)
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
        if dt > MODEL_TIME_S or peak > MEMORY_B:
            slow.append({"case": case, "mutations": kinds, "seconds": dt, "peak_mb": peak / 2**20})
        _count(out, by_kind, kinds, outcome, dt > MODEL_TIME_S, peak > MEMORY_B)
        times.append(dt)
        peaks.append(peak)
    res = _summary(n, out, by_kind, times, peaks, raw_errors, slow)
    res["generated"] = len(gen_s)
    res["generate_seconds_total"] = float(sum(gen_s))
    return res


def _raw(case, kinds, stage, e) -> dict:
    return {"case": case, "mutations": kinds, "stage": stage,
            "error": f"{type(e).__name__}: {e}"[:300], "traceback": traceback.format_exc()[-1500:]}


# ------------------------------------------------------------------------------ driver
def run(quick: bool) -> dict:
    settings = QUICK if quick else FULL
    with tempfile.TemporaryDirectory() as tmp:
        bvh = bvh_campaign(settings["bvh_cases"], settings["seed"], Path(tmp))
        model = model_campaign(settings["model_cases"], settings["seed"], Path(tmp))
    raw = bvh["outcomes"].get("other exception", 0) + model["outcomes"].get("other exception", 0)
    rows = []
    for name, r in (("BVH mutations", bvh), ("model-file mutations", model)):
        o = r["outcomes"]
        rows.append(headline(f"{name}: other exceptions of {r['cases']}",
                             o.get("other exception", 0), "", "0",
                             o.get("other exception", 0) == 0,
                             f"accepted {o.get('accepted', 0)}, documented errors "
                             f"{o.get('documented error', 0)}, over time "
                             f"{o.get('over time', 0)}, over memory {o.get('over memory', 0)}"))
    return {"settings": settings, "bvh": bvh, "model": model, "other_exceptions": raw,
            "headline": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="200 BVH and 70 model-file cases")
    a = ap.parse_args()
    import bayesmotion  # noqa: F401  (float64 on)

    t0 = time.perf_counter()
    res = run(a.quick)
    write_json(RESULTS / f"{NAME}.json", {"name": NAME, "mode": "quick" if a.quick else "full",
                                          **res, "wall_s": time.perf_counter() - t0,
                                          "status": "ok", "machine": machine_info()})
    for part in ("bvh", "model"):
        print(part, res[part]["cases"], "cases:", res[part]["outcomes"])
    for e in res["bvh"]["other_exceptions"] + res["model"]["other_exceptions"]:
        print("OTHER EXCEPTION:", e["case"], e["mutations"], e["error"])
    return 1 if res["other_exceptions"] else 0


if __name__ == "__main__":
    sys.exit(main())
