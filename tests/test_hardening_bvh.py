"""BVH reading on hostile input: only regular files, size and frame limits, line-by-line parsing
that stops at the first bad line, a plausible frame time, files cut short, short quotes; and
property tests (any bytes or any mutation of a valid file gives a Motion or a BVHError, never
another exception, within a per-example deadline)."""

import os
import re
import threading
import tracemalloc
from datetime import timedelta

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bayesmotion as bm
from bayesmotion.data import bvh as bvh_mod
from bayesmotion.data.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from bayesmotion.errors import BayesmotionError, BVHError

# 2 joints, 6 + 3 = 9 channels, three frames; ends with a newline, as every writer's file does
SMALL = """HIERARCHY
ROOT hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT head
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Zrotation Yrotation Xrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 5 0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0333333
1 2 3 10 20 30 -5 6 7
0 0 0 0 0 0 0 0 0
-1.5 2.5e-3 -0 90 -90 180 45 -45 1.25
"""
SMALL_VALUES = np.array([[1, 2, 3, 10, 20, 30, -5, 6, 7], [0] * 9,
                         [-1.5, 2.5e-3, -0.0, 90, -90, 180, 45, -45, 1.25]])


def _peak_bytes(fn):
    """(result or exception, peak traced bytes) of ``fn()``."""
    tracemalloc.start()
    try:
        try:
            out = fn()
        except BayesmotionError as e:
            out = e
        return out, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


# ----------------------------------------------------------------- what read_bvh opens
def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "f.bvh"
    os.mkfifo(fifo)
    result = []
    t = threading.Thread(target=lambda: result.append(_raises(read_bvh, fifo)), daemon=True)
    t.start()
    t.join(30)
    if t.is_alive():  # unblock the reader so the test process can end, then fail
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        pytest.fail("read_bvh blocked on a FIFO")
    assert isinstance(result[0], BVHError)
    assert re.fullmatch(r".*f\.bvh: cannot read file: it is a FIFO \(named pipe\), not a "
                        r"regular file", str(result[0]))


def _raises(fn, *args):
    try:
        fn(*args)
    except Exception as e:  # noqa: BLE001 -- returned for the caller to check
        return e
    return None


def test_device_behind_a_bvh_name_is_refused_before_reading(tmp_path):
    if not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero")
    link = tmp_path / "x.bvh"
    link.symlink_to("/dev/zero")
    err, peak = _peak_bytes(lambda: read_bvh(link))
    assert isinstance(err, BVHError)
    assert "it is a character device, not a regular file" in str(err)
    assert peak < 2**20  # nothing read


def test_path_with_nul_byte_is_a_bvh_error():
    with pytest.raises(BVHError, match=r"path contains a NUL byte"):
        read_bvh("a\x00b.bvh")


def test_folder_and_missing_file(tmp_path):
    with pytest.raises(BVHError, match=r"cannot read file: it is a directory"):
        read_bvh(tmp_path)
    with pytest.raises(BVHError, match=r"nope\.bvh: cannot read file: No such file"):
        read_bvh(tmp_path / "nope.bvh")


# ------------------------------------------------------------------------------ limits
def test_file_over_max_bytes_is_refused_before_reading(tmp_path):
    path = tmp_path / "big.bvh"
    path.write_bytes(SMALL.encode() + b"\n" * 3_000_000)
    err, peak = _peak_bytes(lambda: read_bvh(path, max_bytes=1_000_000))
    assert isinstance(err, BVHError)
    assert re.search(r"3000\d+ bytes is more than max_bytes=1000000; pass a larger max_bytes=",
                     str(err)), str(err)
    assert peak < 2**20  # the file was not read
    np.testing.assert_array_equal(read_bvh(path, max_bytes=4_000_000).values, SMALL_VALUES)
    with pytest.raises(BVHError, match=r"characters is more than max_bytes=100"):
        parse_bvh(SMALL, max_bytes=100)


def test_frame_count_over_max_frames_is_refused_naming_the_limit():
    with pytest.raises(BVHError, match=r"^<string>: line 17: 'Frames: 3' is more than "
                                       r"max_frames=2; pass a larger max_frames="):
        parse_bvh(SMALL, max_frames=2)
    np.testing.assert_array_equal(parse_bvh(SMALL, max_frames=3).values, SMALL_VALUES)
    text = SMALL.replace("Frames: 3", f"Frames: {bvh_mod.MAX_FRAMES + 1}")
    with pytest.raises(BVHError, match=rf"is more than max_frames={bvh_mod.MAX_FRAMES}"):
        parse_bvh(text)


@pytest.mark.parametrize("value", [0, -1, 2.5, True, "10"])
def test_limits_must_be_positive_ints(value):
    with pytest.raises(BayesmotionError, match="must be a positive int"):
        parse_bvh(SMALL, max_frames=value)


def test_joint_count_limit(monkeypatch):
    monkeypatch.setattr(bvh_mod, "MAX_JOINTS", 1)
    with pytest.raises(BVHError, match=r"^<string>: line 6: more than MAX_JOINTS=1 joints; if "
                                       r"the file is right, raise bayesmotion.data.bvh.MAX_JOINTS"):
        parse_bvh(SMALL)


# --------------------------------------------------------- streaming: fail at the first line
def test_megabytes_of_digits_on_line_one_fail_at_once_in_bounded_memory(tmp_path):
    """20 MB of digits (one token) and 20 MB of one-digit tokens on line 1: the error names line
    1, quoting at most 80 characters, and the peak memory is the file and its decoded text
    (not a list of ten million tokens, some 600 MB)."""
    size = 20_000_000
    for body, found in (("7" * size, "'" + "7" * 77 + "...'"), ("7 " * (size // 2), "'7'")):
        path = tmp_path / "digits.bvh"
        path.write_text(body)
        err, peak = _peak_bytes(lambda p=path: read_bvh(p))
        assert str(err) == (f"{path}: line 1: expected 'HIERARCHY' as the first word of a BVH "
                            f"file, found {found}")
        assert peak < 2.5 * size


def test_huge_frame_line_is_not_split_whole():
    """A frame line of 10 million values for 9 channels: the count error, without splitting the
    line into ten million strings."""
    head = SMALL[:SMALL.index("1 2 3 10")]
    text = head + "1 " * 10_000_000 + "\n"
    err, peak = _peak_bytes(lambda: parse_bvh(text))
    assert str(err) == ("<string>: line 19: expected 9 channel values (frame 1 of 3), found more "
                        "than 100009")
    assert peak < 5e6  # the text itself was allocated before tracing started


def test_first_bad_frame_line_stops_the_parse(monkeypatch):
    """Lines after the first bad one are never converted (counted by patching the row parser)."""
    text = SMALL.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0 x") + "1 " * 9 + "\n"
    calls = []
    real = bvh_mod._row
    monkeypatch.setattr(bvh_mod, "_row", lambda *a: calls.append(1) or real(*a))
    with pytest.raises(BVHError, match=r"^<string>: line 20: expected a number for channel 9 "):
        parse_bvh(text)
    assert len(calls) == 2


@settings(max_examples=200, deadline=None)
@given(pieces=st.lists(st.tuples(st.text(alphabet="ab \t", max_size=5),
                                 st.sampled_from(["\n", "\r\n", "\r", ""])), max_size=20))
def test_lines_match_splitting_the_normalised_text(pieces):
    """The incremental line reader against the reference: normalise the line ends, split."""
    text = "".join(a + b for a, b in pieces)
    ref = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    lines = bvh_mod._Lines(text, "<t>")
    got = []
    ended = []
    while (line := lines.next()) is not None:
        got.append(line)
        ended.append(lines.terminated)
        assert lines.number == len(got)
    assert got == ref
    assert ended == [True] * (len(ref) - 1) + [False]  # the last piece follows the last end


# ------------------------------------------------------------------------ frame time
@pytest.mark.parametrize("frame_time", ["1e300", "1e-300", "1e-7", "20000", "86400"])
def test_implausible_frame_time_is_refused(frame_time):
    with pytest.raises(BVHError, match=rf"^<string>: line 18: frame time '{frame_time}' s is "
                                       r"outside 1e-06 to 10000 s \(0.0001 to 1e\+06 fps\)"):
        parse_bvh(SMALL.replace("0.0333333", frame_time))


@pytest.mark.parametrize("frame_time, fps", [("0.000001", 1e6), ("10000", 1e-4), ("1e-5", 1e5)])
def test_frame_time_range_is_inclusive(frame_time, fps):
    assert parse_bvh(SMALL.replace("0.0333333", frame_time)).fps == fps


def test_writer_refuses_a_rate_the_reader_refuses():
    m = parse_bvh(SMALL)
    for fps in (1e-5, 2e6):
        with pytest.raises(BayesmotionError, match=r"outside the 0.0001 to 1e\+06 fps"):
            format_bvh(m.replace(fps=fps))


# ----------------------------------------------------------------- files cut short
def test_file_cut_inside_its_last_number_is_refused_by_read_bvh(tmp_path):
    """'1.25' cut to '1.2' still has 9 values that parse: only the missing line end shows the
    cut. read_bvh refuses it; parse_bvh of a string (often written without a final newline)
    accepts it; with the newline restored, read_bvh accepts it too."""
    cut = SMALL[:-2]  # "... 1.2"
    path = tmp_path / "cut.bvh"
    path.write_text(cut)
    with pytest.raises(BVHError, match=r"cut\.bvh: line 21: the last frame line has no line "
                                       r"end, so the file may have been cut inside its last "
                                       r"number; if the file is complete, end it with a newline"):
        read_bvh(path)
    assert parse_bvh(cut).values[2, 8] == 1.2
    for end in ("\n", "\r\n", "\r", "\n\n  \n"):
        path.write_text(cut + end, newline="")
        assert read_bvh(path).values[2, 8] == 1.2


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_every_cut_of_the_real_cmu_file_inside_its_last_line_is_refused(cmu_files, data,
                                                                         tmp_path_factory):
    raw = cmu_files[0].read_bytes()  # CRLF line ends
    body = raw.rstrip(b"\r\n")
    start = body.rfind(b"\n") + 1
    # from an empty last line to the whole line without its line end (a lone CR still ends it)
    cut = data.draw(st.integers(start, len(body)), label="cut at")
    path = tmp_path_factory.mktemp("cut") / "c.bvh"
    path.write_bytes(raw[:cut])
    with pytest.raises(BVHError, match=r"c\.bvh: line 491: "):
        read_bvh(path)


def test_every_real_file_and_writer_output_is_read(cmu_files, bandai_files, tmp_path):
    assert len(cmu_files) == 2 and len(bandai_files) == 40
    for f in [*cmu_files, *bandai_files]:
        m = read_bvh(f)
        for precision in (None, 0, 3):
            out = write_bvh(m, tmp_path / f"{f.stem}.bvh", precision=precision)
            back = read_bvh(out)
            assert back.values.shape == m.values.shape and back.fps == m.fps
            if precision is None:
                np.testing.assert_array_equal(back.values, m.values)


# ---------------------------------------------------------------- quotes in messages
LONG = "Q" * 5000


@pytest.mark.parametrize("edit", [
    lambda t: t.replace("HIERARCHY", LONG),
    lambda t: t.replace("ROOT hips", "ROOT " + LONG).replace("JOINT head", "JOINT " + LONG),
    lambda t: t.replace("JOINT head", f"JOINT {LONG}\n{{\nOFFSET 0 0 0\nCHANNELS 9"),
    lambda t: t.replace("CHANNELS 3 Zrotation", "CHANNELS 3 " + LONG),
    lambda t: t.replace("OFFSET 0 10 0", f"OFFSET 0 {LONG} 0"),
    lambda t: t.replace("OFFSET 0 10 0", f"OFFSET 0 {'+' * 5000}nan 0"),
    lambda t: t.replace("\tJOINT head", "\t" + LONG),
    lambda t: t.replace("}\nMOTION", "}\n" + LONG + "\nMOTION"),
    lambda t: t.replace("Frames: 3", "Frames: " + "9" * 5000),
    lambda t: t.replace("Frames: 3", LONG),
    lambda t: t.replace("0.0333333", "-" + "0" * 5000),
    lambda t: t.replace("0.0333333", "0." + "0" * 5000 + "1"),
    lambda t: t.replace("0.0333333", LONG),
    lambda t: t.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0 " + LONG),
    lambda t: t.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0 1" + "0" * 5000),
    lambda t: t.replace("MOTION", "MOTION\n" + LONG),
])
def test_errors_quote_at_most_80_characters_of_a_token(edit):
    with pytest.raises(BVHError) as info:
        parse_bvh(edit(SMALL))
    msg = str(info.value)
    assert re.match(r"<string>: line \d+: \S", msg), msg
    assert max(len(run) for run in re.findall(r"(.)\1*", msg)) <= 80, msg[:300]
    assert len(msg) < 400, msg[:300]


# ----------------------------------------------------------------------- properties
def _check(result_of):
    """A Motion with finite values and a plausible rate, or a BVHError naming a line."""
    try:
        m = result_of()
    except BVHError as e:
        assert re.match(r"(<string>|.*\.bvh): (line \d+: \S|cannot read file)", str(e)), str(e)
        return
    assert isinstance(m, bm.Motion)
    assert np.all(np.isfinite(m.values)) and 1e-4 <= m.fps <= 1e6


@settings(max_examples=300, deadline=timedelta(seconds=5))
@given(raw=st.binary(max_size=400))
def test_any_bytes_give_a_motion_or_a_bvh_error(raw):
    _check(lambda: parse_bvh(raw))


def _mutations():
    numbers = st.sampled_from(["1e308", "1e309", "-1e999", "nan", "NaN", "inf", "-Infinity",
                               "\u0663", "\uff11", "1_0", "0x10", "1e", ".", "-", "99" * 60,
                               "1e-320", "\x00", "\u2028", "\x85", "\ufeff"])
    return st.one_of(
        st.tuples(st.just("flip"), st.integers(0, 10**6), st.integers(1, 255)),
        st.tuples(st.just("truncate"), st.integers(0, 10**6)),
        st.tuples(st.just("duplicate line"), st.integers(0, 10**6)),
        st.tuples(st.just("delete line"), st.integers(0, 10**6)),
        st.tuples(st.just("number"), st.integers(0, 10**6), numbers),
        st.tuples(st.just("insert"), st.integers(0, 10**6), st.binary(min_size=1, max_size=6)),
    )


def apply_mutation(raw: bytes, mutation) -> bytes:
    """One edit of a file's bytes."""
    kind, at = mutation[0], mutation[1] % (len(raw) + 1)
    if kind == "flip":
        b = bytearray(raw)
        if b:
            b[at % len(b)] ^= mutation[2]
        return bytes(b)
    if kind == "truncate":
        return raw[:at]
    if kind == "insert":
        return raw[:at] + mutation[2] + raw[at:]
    lines = raw.split(b"\n")
    i = at % len(lines)
    if kind == "duplicate line":
        lines.insert(i, lines[i])
    elif kind == "delete line":
        del lines[i]
    else:  # replace one number (a token starting with a digit or a sign) by mutation[2]
        toks = list(re.finditer(rb"(?<!\S)[-+.\d][^\s]*", raw))
        if toks:
            t = toks[at % len(toks)]
            return raw[:t.start()] + mutation[2].encode() + raw[t.end():]
    return b"\n".join(lines)


@settings(max_examples=300, deadline=timedelta(seconds=5))
@given(mutations=st.lists(_mutations(), min_size=1, max_size=4))
def test_mutated_small_file_gives_a_motion_or_a_bvh_error(mutations):
    raw = SMALL.encode()
    for m in mutations:
        raw = apply_mutation(raw, m)
    _check(lambda: parse_bvh(raw))


@settings(max_examples=40, deadline=timedelta(seconds=10),
          suppress_health_check=[HealthCheck.too_slow])
@given(mutations=st.lists(_mutations(), min_size=1, max_size=3))
def test_mutated_real_cmu_file_read_from_disk_gives_a_motion_or_a_bvh_error(
        cmu_files, tmp_path_factory, mutations):
    raw = cmu_files[0].read_bytes()
    for m in mutations:
        raw = apply_mutation(raw, m)
    path = tmp_path_factory.mktemp("mut") / "m.bvh"
    path.write_bytes(raw)
    _check(lambda: read_bvh(path))
