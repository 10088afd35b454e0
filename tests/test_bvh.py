"""BVH reader/writer: hand-checked content, exact round trips on the real files, every kind of
bad input, atomic writes, and hypothesis fuzzing (a result or a BVHError, never anything else)."""

import os
import re
import stat

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bayesmotion as bm
from bayesmotion.data import bvh as bvh_mod
from bayesmotion.data.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from bayesmotion.errors import BayesmotionError, BVHError

# A small file with every feature: mixed rotation orders, 0/3/6 channels, positions and rotations
# interleaved, two End Sites, scientific notation, tabs. 6 + 3 + 0 + 6 = 15 channels.
SYNTH = """HIERARCHY
ROOT hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\tJOINT spine
\t{
\t\tOFFSET 0 1.5e+01 -2.5E-1
\t\tCHANNELS 3 Xrotation Zrotation Yrotation
\t\tJOINT head
\t\t{
\t\t\tOFFSET 0 10 0
\t\t\tCHANNELS 0
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 5 0
\t\t\t}
\t\t}
\t}
\tJOINT leg
\t{
\t\tOFFSET 3 -10 .5
\t\tCHANNELS 6 Zrotation Yposition Xposition Yrotation Zposition Xrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -40 0
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 3.3333333e-2
1 2 3 10 20 30 -5 6 7 1e1 2E-1 -3 4 5 6
0 0 0 0 0 0 0 0 0 0 0 0 0 0 0
-1.5\t2.5e-3 -0 90 -90 180 45 -45 1 2 3 4 5 6 -7.25E+2
"""
SYNTH_VALUES = np.array([
    [1, 2, 3, 10, 20, 30, -5, 6, 7, 10, 0.2, -3, 4, 5, 6],
    [0] * 15,
    [-1.5, 2.5e-3, -0.0, 90, -90, 180, 45, -45, 1, 2, 3, 4, 5, 6, -725],
], dtype=float)


def line_of(text, needle, nth=0):
    """1-based number of the ``nth`` line containing ``needle``."""
    hits = [i + 1 for i, l in enumerate(text.split("\n")) if needle in l]
    return hits[nth]


def assert_same_motion(a, b):
    """Bit-equal values, offsets, End Sites and fps; identical tree and channels."""
    assert a.skeleton.names == b.skeleton.names
    assert a.skeleton.parents == b.skeleton.parents
    assert a.skeleton.channels == b.skeleton.channels
    assert a.values.shape == b.values.shape
    np.testing.assert_array_equal(a.values.view(np.int64), b.values.view(np.int64))
    np.testing.assert_array_equal(a.skeleton.offsets.view(np.int64),
                                  b.skeleton.offsets.view(np.int64))
    assert sorted(a.skeleton.end_sites) == sorted(b.skeleton.end_sites)
    for k, v in a.skeleton.end_sites.items():
        np.testing.assert_array_equal(v.view(np.int64), b.skeleton.end_sites[k].view(np.int64))
    assert a.fps == b.fps


# ------------------------------------------------------------------------ good content
@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r", "mixed"])
def test_reads_synthetic_file_exactly(tmp_path, newline):
    lines = SYNTH.split("\n")
    if newline == "mixed":
        text = "".join(l + ("\r\n" if i % 2 else "\n") for i, l in enumerate(lines))
    else:
        text = newline.join(lines)
    path = tmp_path / "synth.bvh"
    path.write_bytes(("\ufeff" + text).encode("utf-8"))  # with a byte-order mark
    m = read_bvh(path)
    sk = m.skeleton
    assert m.name == "synth"
    assert sk.names == ("hips", "spine", "head", "leg")
    assert sk.parents == (-1, 0, 1, 0)
    np.testing.assert_array_equal(sk.offsets, [[0, 0, 0], [0, 15, -0.25], [0, 10, 0],
                                               [3, -10, 0.5]])
    assert sk.channels[1] == ("Xrotation", "Zrotation", "Yrotation")
    assert sk.channels[2] == ()
    assert sk.rotation_layout()[1] == ("YXZ", "XZY", "", "ZYX")
    np.testing.assert_array_equal(sk.position_layout()[3], [11, 10, 13])
    assert sorted(sk.end_sites) == [2, 3]
    np.testing.assert_array_equal(sk.end_sites[3], [0, -40, 0])
    np.testing.assert_array_equal(m.values, SYNTH_VALUES)
    assert np.signbit(m.values[2, 2])  # "-0" stays negative zero
    assert m.fps == 30.0


def test_synthetic_round_trip_and_writer_layout():
    m = parse_bvh(SYNTH)
    text = format_bvh(m)
    assert_same_motion(m, parse_bvh(text))
    assert format_bvh(parse_bvh(text)) == text  # writing is idempotent
    assert "\r" not in text and text.endswith("\n")
    assert "\t\tCHANNELS 0\n" in text  # no trailing space after an empty channel list
    assert text.split("\n")[-2] == "-1.5 0.0025 -0 90 -90 180 45 -45 1 2 3 4 5 6 -725"


@pytest.mark.parametrize("frame_time, fps", [
    (".0083333", 120.0),  # CMU
    ("0.0333333", 30.0),  # Bandai
    ("3.3333333e-2", 30.0),
    ("0.016667", 60.0),  # rounded rather than truncated
    ("0.04", 25.0),
    ("1", 1.0),
    ("0.008334027835652971", 119.99),  # written with all digits: not an integer rate
    ("0.3", 1 / 0.3),  # 3.33 fps, too far from 3 to snap
    ("0.0333", 30.0),  # short texts: 1/30 is the only 1/n within one unit of the last digit
    ("0.0167", 60.0),
    ("0.01666", 60.0),  # truncated
    ("0.03", 1 / 0.03),  # fits 1/30 ... 1/33: ambiguous, not snapped
])
def test_fps_from_frame_time(frame_time, fps):
    text = SYNTH.replace("Frame Time: 3.3333333e-2", f"Frame Time: {frame_time}")
    assert parse_bvh(text).fps == pytest.approx(fps, rel=1e-15)


@settings(max_examples=200, deadline=None)
@given(fps=st.floats(min_value=1e-3, max_value=1e5, allow_nan=False, allow_infinity=False))
def test_fps_round_trips_exactly(fps):
    m = parse_bvh(SYNTH).replace(fps=fps)
    assert parse_bvh(format_bvh(m)).fps == fps


def test_integer_fps_written_as_shortest_frame_time():
    m = parse_bvh(SYNTH)
    assert "Frame Time: 0.03333333333333333\n" in format_bvh(m)
    assert "Frame Time: 0.008333333333333333\n" in format_bvh(m.replace(fps=120.0))


def test_deep_hierarchy_has_no_recursion_limit():
    J = 1500  # beyond Python's default recursion limit of 1000
    head = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0", "CHANNELS 3 Xposition Yposition Zposition"]
    for j in range(1, J):
        head += [f"JOINT j{j}", "{", "OFFSET 0 1 0", "CHANNELS 0"]
    text = "\n".join(head + ["}"] * J + ["MOTION", "Frames: 1", "Frame Time: 0.1", "1 2 3"])
    m = parse_bvh(text)
    assert m.skeleton.n_joints == J and m.skeleton.parents[-1] == J - 2
    assert_same_motion(m, parse_bvh(format_bvh(m)))


# ---------------------------------------------------------------------- real files
def test_round_trip_exact_on_real_cmu(cmu_files):
    for f in cmu_files:
        m = read_bvh(f)
        assert m.skeleton.n_joints == 31 and m.fps == 120.0 and m.n_frames == 304
        assert_same_motion(m, parse_bvh(format_bvh(m)))


def test_round_trip_exact_on_every_bandai_file(bandai_files):
    assert len(bandai_files) == 40
    for f in bandai_files:
        m = read_bvh(f)
        assert m.skeleton.n_joints == 22 and m.fps == 30.0
        assert all(len(c) == 6 for c in m.skeleton.channels)
        assert_same_motion(m, parse_bvh(format_bvh(m)))


def test_write_read_file_round_trip(cmu_files, tmp_path):
    m = read_bvh(cmu_files[0])
    out = write_bvh(m, tmp_path / "sub" / "copy.bvh")
    assert out == tmp_path / "sub" / "copy.bvh"
    assert_same_motion(m, read_bvh(out))


# ------------------------------------------------------------------------- writer
@pytest.mark.parametrize("k", [0, 2, 5])
def test_writer_precision(k):
    m = parse_bvh(SYNTH).replace(values=parse_bvh(SYNTH).values + np.pi)
    text = format_bvh(m, precision=k)
    frame_lines = text.rstrip("\n").split("\n")[-3:]
    number = r"-?\d+" + (rf"\.\d{{{k}}}" if k else "")
    assert all(re.fullmatch(number, tok) for l in frame_lines for tok in l.split())
    got = parse_bvh(text)
    np.testing.assert_allclose(got.values, m.values, rtol=0, atol=0.5 * 10.0**-k + 1e-12)
    np.testing.assert_allclose(got.skeleton.offsets, m.skeleton.offsets,
                               rtol=0, atol=0.5 * 10.0**-k)
    assert got.fps == m.fps


@pytest.mark.parametrize("precision", [-1, 2.5, True, "3"])
def test_writer_rejects_bad_precision(precision):
    with pytest.raises(BayesmotionError, match="precision must be None or a non-negative int"):
        format_bvh(parse_bvh(SYNTH), precision=precision)


def test_write_is_atomic_when_replace_fails(tmp_path, monkeypatch):
    path = tmp_path / "m.bvh"
    write_bvh(parse_bvh(SYNTH), path)
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    m2 = parse_bvh(SYNTH).replace(values=np.zeros((5, 15)))
    with pytest.raises(OSError, match="disk full"):
        write_bvh(m2, path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ["m.bvh"]  # no temporary file left behind


def test_write_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        new = write_bvh(parse_bvh(SYNTH), tmp_path / "new.bvh")
        assert stat.S_IMODE(new.stat().st_mode) == 0o644  # not mkstemp's 0o600
        new.chmod(0o640)
        write_bvh(parse_bvh(SYNTH), new)
        assert stat.S_IMODE(new.stat().st_mode) == 0o640  # a replaced file keeps its mode
    finally:
        os.umask(umask)


# ------------------------------------------------------------------------ bad input
def _edit(old, new, nth=0):
    def f(text):
        i = -1
        for _ in range(nth + 1):
            i = text.index(old, i + 1)
        return text[:i] + new + text[i + len(old):]
    return f


def _n(needle, nth=0):
    return lambda text: line_of(text, needle, nth)


_LAST_FRAME = "-1.5\t2.5e-3 -0 90 -90 180 45 -45 1 2 3 4 5 6 -7.25E+2\n"
BAD = {
    # name: (edit of SYNTH, line of the error (a function of the edited text), message regex)
    "truncated motion": (_edit(_LAST_FRAME, ""), lambda t: len(t.split("\n")),
                         r"truncated: 'Frames: 3' but only 2 frame lines"),
    "truncated hierarchy": (lambda t: t[:t.index("\tJOINT leg") + 10], lambda t: 20,
                            r"unexpected end of file, expected '\{' after joint 'leg'"),
    "truncated mid-number": (lambda t: t[:t.index("-7.25E+2") + 6], lambda t: len(t.split("\n")),
                             r"channel 15 \(leg:Xrotation\), found '-7.25E'"),
    "too few values": (_edit(" -7.25E+2", ""), _n("-1.5"),
                       r"expected 15 channel values \(frame 3 of 3\), found 14"),
    "too many values": (_edit("-7.25E+2", "-7.25E+2 1"), _n("-1.5"),
                        r"expected 15 channel values \(frame 3 of 3\), found 16"),
    "too few channel names": (_edit(" Xrotation\n\t\tEnd", "\n\t\tEnd"), _n("End Site", 1),
                              r"joint 'leg': channel 6 of 6 is 'End'.*wrong channel count"),
    "channel count 7": (_edit("CHANNELS 3", "CHANNELS 7"), _n("CHANNELS 7"),
                        r"channel count must be 0-6, found '7'"),
    "channel count text": (_edit("CHANNELS 3", "CHANNELS three"), _n("CHANNELS three"),
                           r"channel count must be 0-6, found 'three'"),
    "channel count unicode digit": (_edit("CHANNELS 3", "CHANNELS \u0663"), _n("\u0663"),
                                    r"channel count must be 0-6"),
    "unknown channel": (_edit("3 Xrotation", "3 Wrotation"), _n("Wrotation"),
                        r"joint 'spine': channel 1 of 3 is 'Wrotation'"),
    "channel twice": (_edit("3 Xrotation", "3 Zrotation"), _n("CHANNELS 3"),
                      r"channel 'Zrotation' listed twice"),
    "non-numeric value": (_edit("1 2 3 10", "1 2 3 1.0.0"), _n("1 2 3 1.0.0"),
                          r"expected a number for channel 4 \(hips:Yrotation\), found '1.0.0'"),
    "underscore number": (_edit("1 2 3 10", "1 2 3 1_0"), _n("1_0"),
                          r"channel 4 \(hips:Yrotation\), found '1_0'"),
    "non-numeric offset": (_edit("OFFSET 0 10 0", "OFFSET 0 ten 0"), _n("ten"),
                           r"expected a number for OFFSET of 'head' \(Y\), found 'ten'"),
    "NaN value": (_edit("0 0 0 0 0 0 0 0", "0 0 0 NaN 0 0 0 0"), _n("NaN"),
                  r"channel 4 \(hips:Yrotation\) is 'NaN'; NaN and infinity are not allowed"),
    "inf value": (_edit("0 0 0 0 0 0 0 0", "0 -inf 0 0 0 0 0 0"), _n("-inf"),
                  r"channel 2 \(hips:Yposition\) is '-inf'"),
    "overflowing value": (_edit("0 0 0 0 0 0 0 0", "0 0 1e999 0 0 0 0 0"), _n("1e999"),
                          r"channel 3 \(hips:Zposition\) '1e999' overflows float64"),
    "nan offset": (_edit("OFFSET 3 -10 .5", "OFFSET nan -10 .5"), _n("OFFSET nan"),
                   r"OFFSET of 'leg' \(X\) is 'nan'"),
    "missing MOTION": (lambda t: t[:t.index("MOTION")], lambda t: len(t.split("\n")),
                       r"no MOTION section after the hierarchy"),
    "zero frames": (_edit("Frames: 3", "Frames: 0"), _n("Frames:"), r"zero frames"),
    "negative frames": (_edit("Frames: 3", "Frames: -3"), _n("Frames:"),
                        r"frame count '-3' is not a non-negative integer"),
    "huge frame count": (_edit("Frames: 3", "Frames: " + "9" * 5000), _n("Frames:"),
                         r"is not a non-negative integer below 10\*\*12"),
    "more frames than declared": (_edit("Frames: 3", "Frames: 2"), _n("-1.5"),
                                  r"more frame lines than 'Frames: 2'"),
    "missing Frames line": (_edit("Frames: 3\n", ""), _n("Frame Time"), r"expected 'Frames:'"),
    "missing Frame Time": (_edit("Frame Time: 3.3333333e-2\n", ""), _n("1 2 3 10"),
                           r"expected 'Frame Time:', found '1 2 3"),
    "zero frame time": (_edit("3.3333333e-2", "0"), _n("Frame Time"),
                        r"frame time must be positive, got '0'"),
    "negative frame time": (_edit("3.3333333e-2", "-0.1"), _n("Frame Time"),
                            r"frame time must be positive"),
    "nan frame time": (_edit("3.3333333e-2", "nan"), _n("Frame Time"),
                       r"the frame time is 'nan'"),
    "tiny frame time": (_edit("3.3333333e-2", "1e-320"), _n("Frame Time"),
                        r"frame time '1e-320' is too small \(fps overflows\)"),
    "text frame time": (_edit("3.3333333e-2", "fast"), _n("Frame Time"),
                        r"expected a number for the frame time, found 'fast'"),
    "duplicate joint name": (_edit("JOINT leg", "JOINT spine"), _n("JOINT spine", 1),
                             r"duplicate joint name 'spine' \(first defined at line 6\)"),
    "cycle (joint inside itself)": (_edit("JOINT head", "JOINT hips"), _n("JOINT hips"),
                                    r"duplicate joint name 'hips'.*hierarchy is a tree"),
    "missing closing brace": (_edit("\t}\n}\nMOTION", "\t}\nMOTION"), _n("MOTION"),
                              r"unbalanced braces: .*1 joint\(s\) still open \('hips'\)"),
    "extra closing brace": (_edit("}\nMOTION", "}\n}\nMOTION"), lambda t: line_of(t, "MOTION") - 1,
                            r"unbalanced braces: extra '\}' after the root joint closed"),
    "two roots": (_edit("}\nMOTION", "}\nROOT b\n{\nOFFSET 0 0 0\nCHANNELS 0\n}\nMOTION"),
                  _n("ROOT b"), r"unexpected 'ROOT' after the root joint closed"),
    "missing HIERARCHY": (_edit("HIERARCHY\n", ""), lambda t: 1,
                          r"expected 'HIERARCHY' as the first word of a BVH file, found 'ROOT'"),
    "JOINT without name": (_edit("JOINT head", "JOINT"), lambda t: line_of(t, "JOINT", 1) + 1,
                           r"joint has no name \(found '\{'\)"),
    "two End Sites": (_edit("\t\t}\n\t}\n}", "\t\t}\n\t\tEnd Site { OFFSET 0 0 0 }\n\t}\n}"),
                      _n("End Site { OFFSET"), r"joint 'leg' has two End Sites"),
    "End without Site": (_edit("End Site", "End Zone"), _n("End Zone"),
                         r"expected 'Site' after 'End', found 'Zone'"),
    "stray word in joint": (_edit("\tJOINT leg", "\tLIMB leg"), _n("LIMB"),
                            r"in joint 'hips': expected 'JOINT', 'End Site' or '\}', found 'LIMB'"),
    "no channels at all": (lambda t: "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 0\n}\n"
                           "MOTION\nFrames: 1\nFrame Time: 0.1\n\n", _n("MOTION"),
                           r"declares no channels"),
    "empty file": (lambda t: " \n\n", lambda t: 1, r"the file is empty"),
    "binary garbage": (lambda t: "\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", lambda t: 3,
                       r"NUL byte: binary data, not a BVH text file"),
    "garbage without NUL": (lambda t: "".join(map(chr, range(1, 256))), lambda t: 1,
                            r"expected 'HIERARCHY'.*, found '\\x01"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_raises_bvh_error_naming_line(case):
    edit, line, message = BAD[case]
    text = edit(SYNTH)
    with pytest.raises(BVHError) as info:
        parse_bvh(text, where="bad.bvh")
    msg = str(info.value)
    assert msg.startswith(f"bad.bvh: line {line(text)}: "), msg
    assert re.search(message, msg), msg


def test_read_bvh_missing_file_and_folder(tmp_path):
    with pytest.raises(BVHError, match=r"nope\.bvh: cannot read file"):
        read_bvh(tmp_path / "nope.bvh")
    with pytest.raises(BVHError, match="cannot read file"):
        read_bvh(tmp_path)


def test_read_bvh_latin1_names(tmp_path):
    path = tmp_path / "latin.bvh"
    path.write_bytes(SYNTH.replace("leg", "jamb\xe9").encode("latin-1"))
    assert read_bvh(path).skeleton.names[-1] == "jamb\xe9"
    assert parse_bvh(SYNTH.encode("utf-8")).skeleton.names == ("hips", "spine", "head", "leg")


# ------------------------------------------------------------------------- fuzzing
KEYWORDS = ["HIERARCHY", "ROOT", "JOINT", "End", "Site", "{", "}", "OFFSET", "CHANNELS", "MOTION",
            "Frames:", "Frame", "Time:", "Xposition", "Yposition", "Zposition", "Xrotation",
            "Yrotation", "Zrotation", "0", "1", "3", "6", "7", "-2.5", "1e-3", ".0083333",
            "1e999", "nan", "-inf", "1e-320", "1_0", "\u0663", "\x00", "x", "99999999999999"]
SEPARATORS = [" ", "\t", "\n", "\r\n", "\r", "\x0b", "\u2028", ""]


def check_parse(data):
    """``parse_bvh`` gives a Motion that round-trips exactly, or a BVHError naming a line."""
    try:
        m = parse_bvh(data)
    except BVHError as e:
        assert re.match(r"<string>: line \d+: \S", str(e)), str(e)
        return
    assert isinstance(m, bm.Motion)
    assert np.all(np.isfinite(m.values)) and m.fps > 0
    assert_same_motion(m, parse_bvh(format_bvh(m)))


def _tokens(text):
    return list(re.finditer(r"\S+", text))


def _index(data, n):
    """An index into n items, biased to the start (where the hierarchy is) half the time."""
    return data.draw(st.one_of(st.integers(0, min(n, 400) - 1), st.integers(0, n - 1)))


def _token_op(kind):
    def op(data, text):
        toks = _tokens(text)
        if not toks:
            return text
        t = toks[_index(data, len(toks))]
        new = {"delete": "", "duplicate": t.group(0) + " " + t.group(0)}.get(kind)
        if new is None:
            new = data.draw(st.one_of(st.sampled_from(KEYWORDS), st.text(max_size=4)))
        return text[:t.start()] + new + text[t.end():]
    return op


def _line_op(kind):
    def op(data, text):
        lines = text.split("\n")
        i = _index(data, len(lines))
        if kind == "delete":
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        else:
            j = _index(data, len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines)
    return op


def _byte_op(kind):
    def op(data, text):
        raw = text.encode("utf-8") if isinstance(text, str) else text
        at = data.draw(st.integers(0, len(raw)))
        if kind == "truncate":
            return raw[:at]
        return raw[:at] + data.draw(st.binary(min_size=1, max_size=8)) + raw[at:]
    return op


MUTATIONS = [_token_op("delete"), _token_op("duplicate"), _token_op("replace"),
             _line_op("delete"), _line_op("duplicate"), _line_op("swap"),
             _byte_op("truncate"), _byte_op("insert")]


def mutate(data, text):
    for op in data.draw(st.lists(st.sampled_from(MUTATIONS), min_size=1, max_size=3)):
        if isinstance(text, bytes):  # after a byte-level edit, keep editing the decoded text
            text = bvh_mod._decode(text)
        text = op(data, text)
    return text


@settings(max_examples=400, deadline=None)
@given(data=st.data())
def test_fuzz_mutated_synthetic_file(data):
    check_parse(mutate(data, SYNTH))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_mutated_real_cmu_file(cmu_files, data):
    check_parse(mutate(data, _cmu_text(cmu_files[0])))


_CACHE = {}


def _cmu_text(path):
    if path not in _CACHE:
        _CACHE[path] = path.read_bytes().decode("utf-8")
    return _CACHE[path]


@settings(max_examples=300, deadline=None)
@given(words=st.lists(st.tuples(st.sampled_from(KEYWORDS), st.sampled_from(SEPARATORS)),
                      max_size=60))
def test_fuzz_keyword_soup(words):
    check_parse("".join(w + s for w, s in words))


@settings(max_examples=200, deadline=None)
@given(text=st.one_of(st.text(max_size=300), st.binary(max_size=300)))
def test_fuzz_random_text_and_bytes(text):
    check_parse(text)


@pytest.mark.parametrize("change, match", [
    ({"names": ("root", "left arm")}, "whitespace"),
    ({"names": ("root", "")}, "non-empty"),
    ({"offsets": np.array([[0.0, 0, 0], [np.nan, 0, 0]])}, "finite"),
    ({"end_sites": {1: np.array([np.inf, 0, 0])}}, "finite"),
])
def test_skeletons_that_bvh_cannot_hold_are_refused(change, match):
    """A skeleton that a BVH file cannot hold is refused, not written to a file read_bvh rejects."""
    from bayesmotion.data.skeleton import Skeleton

    base = {"names": ("root", "arm"), "parents": (-1, 0),
            "offsets": np.array([[0.0, 0, 0], [1.0, 0, 0]]),
            "channels": (("Xposition", "Yposition", "Zposition", "Zrotation"), ("Zrotation",)),
            "end_sites": {1: np.array([0.5, 0, 0])}}
    Skeleton(**base)  # valid as given
    with pytest.raises(BayesmotionError, match=match):
        Skeleton(**{**base, **change})
