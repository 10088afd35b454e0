"""Model files on hostile input: ``load`` checks dtypes, byte order, shapes, values, metadata
size and depth, and sizes from the zip and .npy headers before reading; members the format does
not name are never read; and interrupted saves leave no temporary file behind for long. Property
tests: any mutation of a tiny model's file loads or raises ModelFileError, and a mutated model
that loads generates or raises a BayesmotionError, nothing else."""

import io
import json
import os
import re
import signal
import struct
import subprocess
import sys
import time
import tracemalloc
import zipfile
from datetime import timedelta

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bayesmotion as bm
from bayesmotion.data.bvh import read_bvh, write_bvh
from bayesmotion.data.files import STALE_SECONDS, atomic_path
from bayesmotion.errors import BayesmotionError, ModelFileError
from bayesmotion.model import archive
from bayesmotion.model.io import load


@pytest.fixture(scope="module")
def saved(tiny_model, tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "tiny.npz"
    tiny_model.save(path)
    return path


def npy(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=True)
    return buf.getvalue()


def members(path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as z:
        return {i.filename: z.read(i.filename) for i in z.infolist()}


def write_zip(path, entries, compression=zipfile.ZIP_DEFLATED):
    with zipfile.ZipFile(path, "w", compression) as z:
        for name, data in entries.items():
            z.writestr(name, data)
    return path


def arrays(path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def with_member(src, dst, name, value):
    """``src`` with member ``name`` (no .npy) replaced by ``value`` (an array, raw bytes, or
    None to drop it)."""
    entries = members(src)
    entries.pop(name + ".npy", None)
    if value is not None:
        entries[name + ".npy"] = value if isinstance(value, bytes) else npy(value)
    return write_zip(dst, entries)


def meta_of(path) -> dict:
    return json.loads(arrays(path)["__meta__"].tobytes())


def with_meta_text(src, dst, text: str):
    return with_member(src, dst, "__meta__", np.frombuffer(text.encode(), np.uint8))


def with_meta(src, dst, edit):
    meta = meta_of(src)
    edit(meta)
    return with_meta_text(src, dst, json.dumps(meta))


def assert_same_model(a, b):
    assert a.params.keys() == b.params.keys()
    for k in a.params:
        np.testing.assert_array_equal(np.asarray(a.params[k]), np.asarray(b.params[k]))
    for ya, yb in zip(a.data.Y, b.data.Y, strict=True):
        np.testing.assert_array_equal(ya, yb)
    for ca, cb in zip(a.codecs, b.codecs, strict=True):
        for f in ("keep", "constant", "mean", "scale"):
            np.testing.assert_array_equal(getattr(ca, f), getattr(cb, f))


# ------------------------------------------------------------------- dtypes and byte order
def test_big_endian_arrays_are_converted_exactly(saved, tmp_path):
    src = arrays(saved)
    entries = {k + ".npy": npy(v.astype(v.dtype.newbyteorder(">")) if k != "__meta__" else v)
               for k, v in src.items()}
    big = write_zip(tmp_path / "big.npz", entries)
    assert members(big)["param/X.npy"][:80].find(b"'>f8'") > 0  # really big-endian
    back, ref = load(big), load(saved)
    assert_same_model(back, ref)
    assert back.params["X"].dtype == np.float64 and back.params["X"].dtype.isnative
    assert back.log_posterior() == ref.log_posterior()


def test_fortran_order_and_float32_members_load_as_their_values(saved, tmp_path):
    X = arrays(saved)["param/X"]
    path = with_member(saved, tmp_path / "f.npz", "param/X", np.asfortranarray(X))
    assert b"'fortran_order': True" in members(path)["param/X.npy"][:100]
    np.testing.assert_array_equal(load(path).params["X"], X)
    path = with_member(saved, tmp_path / "f32.npz", "param/X", X.astype(np.float32))
    np.testing.assert_array_equal(load(path).params["X"], X.astype(np.float32).astype(float))


@pytest.mark.parametrize("name, value, match", [
    ("param/X", np.array(["a", "b"]), r"dtype <U1 .*never objects, strings or records"),
    ("param/X", np.array([b"ab"]), r"dtype \|S2"),
    ("param/X", np.zeros(3, [("a", "f8")]), r"records"),
    ("param/X", np.zeros(3, complex), r"dtype complex128"),
    ("param/X", np.zeros(3, np.longdouble), r"at most 64 bits"),
    ("param/X", np.zeros((1, 1, 1, 1, 1)), r"has 5 dimensions"),
    ("codec0/keep", np.arange(96.0), r"codec0/keep: must hold integers"),
    ("lengths", np.full(6, 9.0), r"trial lengths must be 6 integers"),
])
def test_arrays_of_the_wrong_dtype_are_refused(saved, tmp_path, name, value, match):
    with pytest.raises(ModelFileError, match=match):
        load(with_member(saved, tmp_path / "bad.npz", name, value))


def test_object_array_in_a_named_member_is_refused_without_unpickling(saved, tmp_path):
    path = with_member(saved, tmp_path / "obj.npz", "param/X",
                       np.array([_Boom(), 1], dtype=object))
    with pytest.raises(ModelFileError, match=r"'param/X.npy' has dtype object"):
        load(path)


class _Boom:
    def __reduce__(self):
        return (pytest.fail, ("unpickled",))


def test_a_plain_npy_file_and_foreign_files_are_refused(saved, tmp_path):
    plain = tmp_path / "plain.npz"
    plain.write_bytes(npy(np.arange(3)))
    with pytest.raises(ModelFileError, match=r"not a bayesmotion model file \(unreadable "):
        load(plain)
    fifo = tmp_path / "fifo.npz"
    os.mkfifo(fifo)
    with pytest.raises(ModelFileError, match=r"fifo\.npz: not a model file: not a regular file"):
        load(fifo)
    with pytest.raises(ModelFileError, match=r"path contains a NUL byte"):
        load("a\x00.npz")
    with pytest.raises(ModelFileError, match=r"no such model file"):
        load(tmp_path / "absent.npz")


def test_a_member_stored_twice_is_refused(saved, tmp_path):
    path = tmp_path / "twice.npz"
    with zipfile.ZipFile(path, "w") as z, pytest.warns(UserWarning, match="Duplicate name"):
        for name, data in members(saved).items():
            z.writestr(name, data)
        z.writestr("param/X.npy", npy(np.zeros(3)))
    with pytest.raises(ModelFileError, match=r"member 'param/X.npy' is stored twice"):
        load(path)


# ---------------------------------------------------------------------------- values
@pytest.mark.parametrize("name, change, match", [
    ("param/X", lambda v: np.where(v == v.flat[0], np.nan, v), r"'param/X.npy' holds NaN"),
    ("param/log_beta", lambda v: v * np.inf, r"holds values beyond \+-1e\+150"),
    ("codec0/scale", lambda v: v * 0 + 1e300, r"holds values beyond \+-1e\+150"),
    ("codec1/scale", lambda v: v * 0 + 1e-200, r"codec1: scales must be at least 1e-150"),
    ("codec0/mean", lambda v: np.append(v, 0.0), r"codec0: mean must be a float array of "
                                                 r"shape \(96,\)"),
    ("codec0/keep", lambda v: v + 1, r"codec0: kept columns must be distinct indices"),
    ("codec0/constant", lambda v: v[:3], r"codec0: constant must be a float array"),
    ("codec0/branch", lambda v: v[:-1], r"codec0: branch must be a float array of shape"),
    ("Y/1", lambda v: np.where(v == v.flat[5], np.inf, v), r"'Y/1.npy' holds values beyond"),
    ("Y/0", lambda v: v[:, :-1], r"training poses of actor 0 have shape \(54, 95\)"),
    ("anchor/2/1", lambda v: v[:-1], r"anchor of trial 2, actor 1 has shape \(8, 2\), expected "
                                     r"\(9, 2\)"),
    ("offsets/0/0", lambda v: v * np.nan, r"'offsets/0/0.npy' holds NaN"),
    ("offsets/3/1", lambda v: v[1:], r"bone offsets of trial 3, actor 1 have shape"),
    ("param/log_alpha", lambda v: v + 500.0, r"parameter log_alpha has values beyond \+-100"),
    ("onehot/emotion", lambda v: v[:, ::-1], r"'emotion' labels disagree with the one-hot"),
    ("lengths", lambda v: v * 10**9, r"trial lengths must be 6 integers"),
])
def test_bad_values_and_shapes_are_refused_at_load(saved, tmp_path, name, change, match):
    value = change(arrays(saved)[name])
    with pytest.raises(ModelFileError, match=match):
        load(with_member(saved, tmp_path / "bad.npz", name, value))


def test_nan_is_allowed_where_the_format_uses_it(saved, tiny_model):
    """A codec's branch marks columns without a reference angle with NaN: those files load."""
    assert np.isnan(arrays(saved)["codec0/branch"]).any()
    np.testing.assert_array_equal(load(saved).codecs[0].branch, tiny_model.codecs[0].branch)


# -------------------------------------------------------------------------- metadata
def test_deeply_nested_metadata_is_a_model_file_error(saved, tmp_path):
    text = json.dumps(meta_of(saved))
    for depth in (40, 100_000):
        nested = text[:-1] + ', "extra": ' + "[" * depth + "]" * depth + "}"
        with pytest.raises(ModelFileError, match=r"nested more than 32 levels deep"):
            load(with_meta_text(saved, tmp_path / "deep.npz", nested))
    nested = text[:-1] + ', "extra": ' + "[" * 20 + "]" * 20 + "}"  # within the limit
    assert_same_model(load(with_meta_text(saved, tmp_path / "ok.npz", nested)), load(saved))


def _last(text, old, new):
    """``text`` with the last ``old`` (the model's own field: codecs come first) replaced."""
    head, sep, tail = text.rpartition(old)
    return head + new + tail if sep else text


@pytest.mark.parametrize("edit, match", [
    (lambda t: _last(t, '"fps": 5.0', '"fps": NaN'), r"NaN is not allowed"),
    (lambda t: _last(t, '"fps": 5.0', '"fps": 1e999'), r"number '1e999' overflows"),
    (lambda t: _last(t, '"fps": 5.0', '"fps": 1e300'), r"frame rate 1e\+300 is not a number"),
    (lambda t: _last(t, '"fps": 5.0', '"fps": true'), r"frame rate True"),
    (lambda t: t.replace('"fps": 5.0', '"fps": true', 1), r"codec fps has type bool"),
    (lambda t: _last(t, '"fps": 5.0', '"fps": ' + "9" * 5000), r"Exceeds the limit"),
    (lambda t: t.replace('"latent_dim": 3', '"latent_dim": 3.0'), r"wrong types"),
    (lambda t: t.replace('"order": 2', '"order": true'), r"wrong types|order"),
    (lambda t: t.replace('"mapping_noise_floor": 0.0', '"mapping_noise_floor": -1.0'),
     r"mapping_noise_floor must be a number in \[0, 1\]"),
    (lambda t: t.replace('"mapping_noise_floor": 0.0', '"mapping_noise_floor": 1.7e308'),
     r"mapping_noise_floor must be a number in \[0, 1\]"),
    (lambda t: t.replace('"mapping_noise_floor": 0.0', '"mapping_noise_floor": "big"'),
     r"mapping_noise_floor must be a number in \[0, 1\]"),
    (lambda t: t.replace('"jitter": 1e-08', '"jitter": -1'), r"jitter -1 is not a number"),
    (lambda t: t.replace('"mover": 0', '"mover": 99'), r"mover 99 is not a joint index"),
    (lambda t: t.replace('"mover": 0', '"mover": 0.5'), r"codec mover has type float"),
    (lambda t: t.replace('"n_frames": 9', '"n_frames": 9.5', 1), r"trial record 0 must"),
    (lambda t: t.replace('"emotion": "happy", "couple"', '"emotion": "sad", "couple"', 1),
     r"'emotion' labels disagree"),
    (lambda t: t.replace('"levels": {"emotion": ["happy", "sad"]',
                         '"levels": {"emotion": "hs"'), r"levels of 'emotion' must be a list"),
    (lambda t: t[:-1] + ', "format_version": 2}', r"format version 2 is not supported"),
    (lambda t: t.replace('"format_version": 1', '"format_version": true'),
     r"format version True is not supported"),
    (lambda t: t.replace('"scaling": "type"', '"scaling": "x"', 1), r"wrong types or values"),
    (lambda t: t.replace('"rest_frames": false', '"rest_frames": true'),
     r"rest_frames=True and canonical_side=False do not match the codecs' stored rig steps"),
    (lambda t: t.replace('"fps": 5.0', '"fps": 1e300', 1), r"codec0: fps 1e\+300 is outside"),
    (lambda t: t.replace('"heading_axis": -1', '"heading_axis": 7', 1),
     r"codec0: heading axis must be -1 \(none\) or 0-2, got 7"),
    (lambda t: t.replace('"calibration": {}', '"calibration": []'),
     r"calibration must be a mapping"),
    (lambda t: t.replace('"calibration": {}', '"calibration": {"effective_frames": -1}'),
     r"effective_frames -1 is not a number > 0"),
    (lambda t: t.replace('"calibration": {}', '"calibration": {"effective_frames": true}'),
     r"effective_frames True is not a number > 0"),
    (lambda t: t.replace('"calibration": {}', '"calibration": {"effective_frames": "x"}'),
     r"effective_frames 'x' is not a number > 0"),
    (lambda t: "[" + t + "]", r"not a bayesmotion model file \(format None\)"),
    (lambda t: t.encode().decode("latin-1") + "\udcff", r"corrupted metadata"),
])
def test_bad_metadata_is_refused(saved, tmp_path, edit, match):
    text = json.dumps(meta_of(saved))
    new = edit(text)
    assert new != text
    path = with_member(saved, tmp_path / "bad.npz", "__meta__",
                       np.frombuffer(new.encode("utf-8", "surrogateescape"), np.uint8))
    with pytest.raises(ModelFileError, match=match):
        load(path)


def test_oversized_metadata_is_refused_before_it_is_read(saved, tmp_path, monkeypatch):
    meta = meta_of(saved)
    meta["diagnostics"]["note"] = "x" * 2_000_000
    path = with_meta_text(saved, tmp_path / "big.npz", json.dumps(meta))
    monkeypatch.setattr(archive, "MAX_META_BYTES", 1_000_000)
    with pytest.raises(ModelFileError, match=r"'__meta__.npy' declares 20\d{5} bytes, more than "
                                             r"its limit of 1000000 bytes"):
        load(path)
    monkeypatch.setattr(archive, "MAX_META_BYTES", 16 * 2**20)
    assert load(path).diagnostics["note"] == "x" * 2_000_000


# ---------------------------------------------------- sizes from headers, unknown members
def _patch_central_size(raw: bytes, name: bytes, size: int) -> bytes:
    """Set the uncompressed size of member ``name`` in the zip's central directory."""
    at = raw.index(b"PK\x01\x02")
    while True:
        n, m, k = struct.unpack("<HHH", raw[at + 28:at + 34])
        if raw[at + 46:at + 46 + n] == name:
            return raw[:at + 24] + struct.pack("<I", size) + raw[at + 28:]
        at += 46 + n + m + k


def npy_header(shape, descr="<f8") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue()


def test_header_claiming_a_terabyte_in_a_tiny_file_is_a_model_file_error(saved, tmp_path):
    claim = npy_header((10**12,)) + bytes(24)
    path = with_member(saved, tmp_path / "claim.npz", "param/X", claim)
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError, match=r"'param/X.npy' declares a \(1000000000000,\) "
                                                 r"float64 array \(8000000000000 bytes\) but "
                                                 r"holds 24 bytes"):
            load(path)
        assert tracemalloc.get_traced_memory()[1] < 8e6
    finally:
        tracemalloc.stop()


def test_consistent_claim_over_the_array_limit_is_refused_before_reading(saved, tmp_path):
    """Header and zip directory agree on 2 GiB (the directory patched; the data is not there):
    the limit refuses it before a byte of data is read."""
    n = 2**28
    header = npy_header((n,))
    src = members(saved)
    src["Y/0.npy"] = header + bytes(64)
    raw = write_zip(tmp_path / "tmp.npz", src, zipfile.ZIP_STORED).read_bytes()
    path = tmp_path / "claim.npz"
    path.write_bytes(_patch_central_size(raw, b"Y/0.npy", len(header) + 8 * n))
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError, match=r"'Y/0.npy' declares 2147483648 bytes, more "
                                                 r"than the \d+ bytes left of MAX_ARRAY_BYTES = "
                                                 r"1073741824 \(bayesmotion.model.archive\): not "
                                                 r"a model file this package wrote; nothing was "
                                                 r"read"):
            load(path)
        assert tracemalloc.get_traced_memory()[1] < 8e6
    finally:
        tracemalloc.stop()


def test_unknown_members_are_never_read(saved, tmp_path, monkeypatch):
    """A valid model plus a 40 MB zero-filled member that no name of the format points to: the
    load is refused naming it, the member is never opened, and the peak memory stays that of
    the model's own arrays."""
    entries = members(saved)
    entries["junk.npy"] = npy(np.zeros(5_000_000))
    entries["notes.txt"] = b"hello"
    path = write_zip(tmp_path / "junk.npz", entries)
    assert path.stat().st_size < 2e6
    opened = []
    real = archive.ArchiveArrays._load
    monkeypatch.setattr(archive.ArchiveArrays, "_load",
                        lambda self, key, *a, **k: opened.append(key) or real(self, key, *a, **k))
    tracemalloc.start()
    try:
        with pytest.raises(ModelFileError, match=r"holds 2 member\(s\) the format does not name "
                                                 r"\('junk.npy', 'notes.txt'\); they were not "
                                                 r"read"):
            load(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert "junk" not in opened and len(opened) == len(members(saved))
    assert peak < 4e6  # the junk alone decompresses to 40 MB


# ---------------------------------------------------------------- interrupted saves
def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _age(path, seconds):
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_stale_temporaries_of_the_target_are_removed_at_the_next_save(tiny_model, tmp_path):
    target = tmp_path / "model.npz"
    dead, old = _dead_pid(), STALE_SECONDS + 60
    stale = [tmp_path / f".model.npz.{dead}.abcd_123.tmp.npz",  # killed writer
             tmp_path / ".model.npz.x1y2z3w4.tmp.npz"]  # written before pids were recorded
    kept = [tmp_path / f".model.npz.{dead}.young123.tmp.npz",  # may still be in progress
            tmp_path / ".model.npz.1.abcdefgh.tmp.npz",  # pid 1 runs
            tmp_path / f".other.npz.{dead}.abcdefgh.tmp.npz",  # another target's
            tmp_path / f".model.npz.{dead}.abcdefgh.tmp.npz.bak",  # not the pattern
            tmp_path / f"model.npz.{dead}.abcdefgh.tmp.npz"]
    for p in stale + kept:
        p.write_bytes(b"partial")
        if "young" not in p.name:
            _age(p, old)
    link = tmp_path / f".model.npz.{dead}.linklink.tmp.npz"
    link.symlink_to(kept[-1])
    _age(kept[-1], old)
    tiny_model.save(target)
    assert not any(p.exists() for p in stale)
    assert all(p.exists() for p in kept) and link.is_symlink()
    assert_same_model(load(target), tiny_model)


def test_a_save_killed_with_sigkill_is_cleaned_by_the_next_save(tmp_path):
    """A real ``kill -9`` in the middle of a write; the next write to the same target, a minute
    later (aged here), removes the temporary file and writes the right content."""
    target = tmp_path / "clip.bvh"
    code = ("import sys, time; from bayesmotion.data.files import atomic_path\n"
            "with atomic_path(sys.argv[1]) as tmp:\n"
            "    tmp.write_text('HIERARCHY half written')\n"
            "    print('ready', flush=True); time.sleep(600)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(target)], stdout=subprocess.PIPE,
                         text=True)
    try:
        assert p.stdout.readline() == "ready\n"
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
        p.stdout.close()
    (tmp,) = tmp_path.iterdir()
    assert re.fullmatch(rf"\.clip\.bvh\.{p.pid}\.[a-z0-9_]{{8}}\.tmp\.bvh", tmp.name)
    motion = bm.read_bvh(_small_bvh(tmp_path))
    write_bvh(motion, target)
    assert tmp.exists()  # modified seconds ago: it could belong to a writer elsewhere
    _age(tmp, STALE_SECONDS + 1)
    write_bvh(motion, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.bvh", "src.bvh"]
    np.testing.assert_array_equal(read_bvh(target).values, motion.values)


def _small_bvh(folder):
    path = folder / "src.bvh"
    path.write_text("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition "
                    "Zposition\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1 2 3\n4 5 6\n")
    return path


def test_a_failed_write_still_removes_its_own_temporary(tmp_path):
    with pytest.raises(RuntimeError), atomic_path(tmp_path / "a.txt") as tmp:
        tmp.write_text("x")
        raise RuntimeError
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------ properties
_VALUES = [None, 0, -1, 1, 2, 3.5, 1e300, -1e-300, "", "x", "happy", [], {}, [1, 2], {"a": 1},
           True, False, 10**30]


@pytest.mark.slow
def test_model_without_dynamics_factors_loads_and_generates(saved, tmp_path):
    path = with_meta(saved, tmp_path / "nodyn.npz",
                     lambda m: m["spec"].__setitem__("dynamics_factors", []))
    model = load(path)
    assert model.spec.dynamics_factors == ()
    r = model.generate(emotion="happy", n_frames=10)
    assert np.all(np.isfinite(r.angles))


def _meta_paths(obj, prefix=()):
    """Every (path, value) of a JSON document (paths as tuples of keys and indices)."""
    yield prefix, obj
    items = obj.items() if isinstance(obj, dict) else enumerate(obj) \
        if isinstance(obj, list) else ()
    for k, v in items:
        yield from _meta_paths(v, (*prefix, k))


def _set(obj, path, value):
    for k in path[:-1]:
        obj = obj[k]
    obj[path[-1]] = value


def _mutate_meta(data, meta):
    paths = [p for p, _ in _meta_paths(meta) if p]
    if not paths:
        return meta
    path = data.draw(st.sampled_from(paths), label="meta path")
    if data.draw(st.booleans(), label="delete"):
        parent = meta
        for k in path[:-1]:
            parent = parent[k]
        del parent[path[-1]]
    else:
        _set(meta, path, data.draw(st.sampled_from(_VALUES), label="value"))
    return meta


def _mutate_array(data, a):
    with np.errstate(all="ignore"):  # casts of NaN to int, products that overflow: intended
        return _array_edit(data, a)


def _array_edit(data, a):
    kind = data.draw(st.sampled_from(["element", "scale", "dtype", "shape", "empty"]))
    if kind == "element" and a.size:
        a = a.copy()
        i = data.draw(st.integers(0, a.size - 1))
        if a.dtype.kind == "f":
            a.flat[i] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e300, 1e151, 1e149,
                                                   -0.0, 0.0, 1e-300, 1e6, -1e6]))
        elif a.dtype.kind in "iu":
            a.flat[i] = data.draw(st.integers(-3, 200))
        return a
    if kind == "scale" and a.dtype.kind == "f":
        return a * data.draw(st.sampled_from([0.0, -1.0, 1e-3, 1e3, 1e150]))
    if kind == "dtype":
        return a.astype(data.draw(st.sampled_from(["<f4", ">f8", "<i4", "?", "<u1", ">i8"])))
    if kind == "shape":
        return a.reshape(-1) if a.ndim > 1 else a[: max(a.size - 1, 0)]
    return a[:0]


def mutate_model_file(data, src: bytes) -> bytes:
    """One to three edits of a model file: its bytes, a member's array, or its metadata."""
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        target = data.draw(st.sampled_from(["bytes", "array", "array", "meta", "meta", "member"]))
        if target == "bytes":
            b = bytearray(src)
            b[data.draw(st.integers(0, len(b) - 1))] ^= data.draw(st.integers(1, 255))
            src = bytes(b)
            continue
        try:
            with zipfile.ZipFile(io.BytesIO(src)) as z:
                entries = {i.filename: z.read(i.filename) for i in z.infolist()}
        except Exception:  # noqa: BLE001 -- an earlier byte edit broke the zip: keep it broken
            return src
        names = sorted(entries)
        if target == "member":
            name = data.draw(st.sampled_from(names))
            if data.draw(st.booleans()):
                del entries[name]
            else:
                entries["param/extra.npy"] = entries[name]
        else:
            name = "__meta__.npy" if target == "meta" else data.draw(st.sampled_from(names))
            try:
                a = np.load(io.BytesIO(entries[name]), allow_pickle=False)
            except Exception:  # noqa: BLE001 -- not loadable: leave it
                continue
            if target == "meta" and a.dtype == np.uint8:
                try:
                    meta = json.loads(a.tobytes())
                except ValueError:  # an earlier edit broke it: leave it broken
                    continue
                if not isinstance(meta, dict):
                    continue
                a = np.frombuffer(json.dumps(_mutate_meta(data, meta)).encode(), np.uint8)
            else:
                a = _mutate_array(data, a)
            entries[name] = npy(a)
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            for n, d in entries.items():
                z.writestr(n, d)
        src = buf.getvalue()
    return src


def check_mutated_model(path):
    """Load gives a model or a ModelFileError; a model generates or raises BayesmotionError."""
    try:
        model = load(path)
    except ModelFileError:
        return "refused"
    try:
        levels = model.levels.get("emotion", ("neutral",))
        r = model.generate(emotion=levels[0], n_frames=10)
    except BayesmotionError:
        return "generate refused"
    assert r.angles.shape[1] == 10
    return "generated"


@settings(max_examples=120, deadline=timedelta(seconds=60),
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_mutated_model_files_load_or_raise_model_file_error(saved, tmp_path_factory, data):
    raw = mutate_model_file(data, saved.read_bytes())
    path = tmp_path_factory.mktemp("mut") / "m.npz"
    path.write_bytes(raw)
    try:
        model = load(path)
    except ModelFileError:
        return
    # what load lets through is a whole model: finite parameters of the shapes its spec and
    # data imply, and a finite log-posterior
    assert all(np.all(np.isfinite(v)) for v in model.params.values())
    assert model.params["X"].shape[:2] == (len(model.data.Y), model.params["I"].shape[0])
    assert model.params["I"].shape[1] == model.spec.interaction_dim
    assert np.isfinite(model.log_posterior())


@pytest.mark.slow
@settings(max_examples=25, deadline=timedelta(seconds=120),
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_mutated_models_that_load_generate_or_raise_a_bayesmotion_error(saved, tmp_path_factory,
                                                                        data):
    """Only edits of array values and metadata values (every such file that loads is
    generated from: 3-4 s of compilation each)."""
    src = saved.read_bytes()
    with zipfile.ZipFile(io.BytesIO(src)) as z:
        entries = {i.filename: z.read(i.filename) for i in z.infolist()}
    name = data.draw(st.sampled_from(sorted(entries)))
    a = np.load(io.BytesIO(entries[name]), allow_pickle=False)
    if name == "__meta__.npy":
        meta = _mutate_meta(data, json.loads(a.tobytes()))
        a = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    else:
        a = _mutate_array(data, a)
    entries[name] = npy(a)
    path = write_zip(tmp_path_factory.mktemp("mut") / "m.npz", entries)
    check_mutated_model(path)
