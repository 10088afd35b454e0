"""BVH reader and writer.

``parse_bvh``/``read_bvh`` accept any rotation order per joint, 0-6 channels per joint, End Sites,
CRLF/LF/CR line ends, tabs, a UTF-8 byte-order mark and scientific notation. Anything else raises
:class:`~bayesmotion.BVHError` naming the line and the problem, never another exception.

``write_bvh`` writes the shortest decimal that reads back to the same float64 (``repr``), so
read -> write -> read is bit-exact for channel values, offsets and fps; ``precision=k`` writes k
decimals instead.

Frame rate: ``fps = 1 / Frame Time``, snapped to an integer n when 1/n is the only reciprocal of
an integer within one unit of the frame time's last written digit (``.0083333`` -> 120.0,
``0.0333`` -> 30.0, ``0.01666`` -> 60.0; ``0.03``, which fits 30 to 33, stays 33.33...).
"""

from __future__ import annotations

import math
import os
import re
from decimal import Context, Decimal
from pathlib import Path

import numpy as np

from bayesmotion.data.files import atomic_write_text
from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import VALID_CHANNELS, Skeleton
from bayesmotion.errors import BayesmotionError, BVHError

_TOKEN = re.compile(r"\S+")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)  # ASCII digits only
_COUNT = re.compile(r"\d+", re.ASCII)
_DECIMAL = Context(prec=60)  # exact enough for 1 / frame time of any float64


# ----------------------------------------------------------------------------- reading
class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers.

    Args:
        lines: the lines of the hierarchy (everything before ``MOTION``).
        where: source name for messages.
        end: what running out of tokens means, e.g. ``"end of file"``.
        end_line: the line reported when tokens run out.
    """

    def __init__(self, lines: list[str], where: str, end: str, end_line: int):
        self.items = [(m.group(0), i + 1) for i, line in enumerate(lines)
                      for m in _TOKEN.finditer(line)]
        self.pos = 0
        self.where, self.end, self.end_line = where, end, end_line

    def error(self, msg: str, line: int | None = None) -> BVHError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.end_line
        return BVHError(f"{self.where}: line {line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected {self.end}, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]

    def expect(self, word: str, context: str = "") -> int:
        tok, line = self.next(repr(word) + context)
        if tok != word:
            raise self.error(f"expected {word!r}{context}, found {_short(tok)}", line)
        return line

    def peek(self) -> tuple[str, int] | None:
        return self.items[self.pos] if self.pos < len(self.items) else None

    def number(self, what: str) -> float:
        tok, line = self.next(f"a number for {what}")
        return _number(tok, what, lambda msg: self.error(msg, line))

    def vector(self, what: str) -> list[float]:
        return [self.number(f"{what} ({axis})") for axis in "XYZ"]


def _short(tok: str) -> str:
    return repr(tok if len(tok) <= 40 else tok[:40] + "...")


def _number(tok: str, what: str, error) -> float:
    """A finite decimal number (``1``, ``-.5``, ``3e-05``); anything else is ``error(msg)``."""
    if not _NUMBER.fullmatch(tok):
        if tok.lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise error(f"{what} is {tok!r}; NaN and infinity are not allowed")
        raise error(f"expected a number for {what}, found {_short(tok)}")
    x = float(tok)
    if not math.isfinite(x):
        raise error(f"{what} {_short(tok)} overflows float64")
    return x


def _open_joint(tk: _Tokens, parent: int, acc: dict) -> int:
    """Parse ``name { OFFSET x y z CHANNELS n c1..cn`` and record the joint; returns its index."""
    name, line = tk.next("a joint name")
    if name in ("{", "}"):
        raise tk.error(f"joint has no name (found {name!r})", line)
    if name in acc["lines"]:
        first = acc["lines"][name]
        raise tk.error(f"duplicate joint name {name!r} (first defined at line {first}); a BVH "
                       "hierarchy is a tree, so a joint cannot appear twice", line)
    j = len(acc["names"])
    acc["names"].append(name)
    acc["lines"][name] = line
    acc["parents"].append(parent)
    tk.expect("{", f" after joint {name!r}")
    tk.expect("OFFSET", f" in joint {name!r}")
    acc["offsets"].append(tk.vector(f"OFFSET of {name!r}"))
    tk.expect("CHANNELS", f" in joint {name!r}")
    acc["channels"].append(_channels(tk, name))
    return j


def _channels(tk: _Tokens, name: str) -> tuple[str, ...]:
    n_tok, line = tk.next(f"the channel count of {name!r}")
    if not _COUNT.fullmatch(n_tok) or len(n_tok) > 3 or int(n_tok) > 6:
        raise tk.error(f"joint {name!r}: channel count must be 0-6, found {_short(n_tok)}", line)
    chans: list[str] = []
    for k in range(int(n_tok)):
        c, line = tk.next(f"channel {k + 1} of {n_tok} of joint {name!r}")
        if c not in VALID_CHANNELS:
            raise tk.error(f"joint {name!r}: channel {k + 1} of {n_tok} is {_short(c)}, not one "
                           f"of {', '.join(VALID_CHANNELS)} (wrong channel count?)", line)
        if c in chans:
            raise tk.error(f"joint {name!r}: channel {c!r} listed twice", line)
        chans.append(c)
    return tuple(chans)


def _end_site(tk: _Tokens, j: int, acc: dict, line: int) -> None:
    name = acc["names"][j]
    tk.expect("Site", " after 'End'")
    if j in acc["end_sites"]:
        raise tk.error(f"joint {name!r} has two End Sites", line)
    tk.expect("{", " after 'End Site'")
    tk.expect("OFFSET", " in End Site")
    acc["end_sites"][j] = tk.vector(f"End Site OFFSET of {name!r}")
    tk.expect("}", f" closing the End Site of {name!r}")


def _parse_hierarchy(tk: _Tokens) -> Skeleton:
    """The joint tree, parsed with an explicit stack (no recursion limit on depth)."""
    tk.expect("HIERARCHY", " as the first word of a BVH file")
    root_line = tk.expect("ROOT", " after 'HIERARCHY'")
    acc = {"names": [], "lines": {}, "parents": [], "offsets": [], "channels": [],
           "end_sites": {}}
    stack = [_open_joint(tk, -1, acc)]
    while stack:
        j = stack[-1]
        if tk.peek() is None:
            open_ = ", ".join(repr(acc["names"][k]) for k in stack)
            raise tk.error(f"unbalanced braces: unexpected {tk.end} with {len(stack)} joint(s) "
                           f"still open ({open_}); expected 'JOINT', 'End Site' or '}}'")
        tok, line = tk.next("'JOINT', 'End Site' or '}'")
        if tok == "}":
            stack.pop()
        elif tok == "JOINT":
            stack.append(_open_joint(tk, j, acc))
        elif tok == "End":
            _end_site(tk, j, acc, line)
        else:
            raise tk.error(f"in joint {acc['names'][j]!r}: expected 'JOINT', 'End Site' or '}}', "
                           f"found {_short(tok)}", line)
    extra = tk.peek()
    if extra is not None:
        what = ("unbalanced braces: extra '}'" if extra[0] == "}"
                else f"unexpected {_short(extra[0])}")
        raise tk.error(f"{what} after the root joint closed (one ROOT per file)", extra[1])
    try:
        skeleton = Skeleton(acc["names"], acc["parents"], np.array(acc["offsets"]),
                            acc["channels"], acc["end_sites"])
    except BayesmotionError as e:
        raise tk.error(f"invalid hierarchy: {e}", root_line) from None
    return skeleton


def parse_bvh(text: str | bytes, where: str = "<string>", name: str = "") -> Motion:
    """Parse BVH text into a :class:`Motion`.

    Args:
        text: the file content (``bytes`` are decoded as UTF-8, else Latin-1).
        where: names the source in error messages.
        name: the motion's name.
    Returns:
        the motion; ``values`` is (frames, channels) in file order.
    Raises:
        BVHError: malformed content, with the line number and the problem.
    """
    if isinstance(text, bytes | bytearray):
        text = _decode(bytes(text))
    lines = text.removeprefix("\ufeff").replace("\r\n", "\n").replace("\r", "\n").split("\n")
    _check_text(lines, where)
    motion_at = next((i for i, l in enumerate(lines) if l.strip() == "MOTION"), None)
    if motion_at is None:
        tk = _Tokens(lines, where, "end of file", len(lines))
        _parse_hierarchy(tk)
        raise BVHError(f"{where}: line {len(lines)}: no MOTION section after the hierarchy")
    tk = _Tokens(lines[:motion_at], where, f"'MOTION' (line {motion_at + 1})", motion_at + 1)
    skeleton = _parse_hierarchy(tk)
    values, fps = _parse_motion(lines, motion_at, skeleton, where)
    try:
        return Motion(skeleton, values, fps, name)
    except BayesmotionError as e:  # defensive: _parse_motion checks what Motion checks
        raise BVHError(f"{where}: line {motion_at + 1}: invalid motion: {e}") from None


def _check_text(lines: list[str], where: str) -> None:
    if not any(l.strip() for l in lines):
        raise BVHError(f"{where}: line 1: the file is empty")
    for i, l in enumerate(lines):
        if "\x00" in l:
            raise BVHError(f"{where}: line {i + 1}: NUL byte: binary data, not a BVH text file")


def _header(lines: list[str], i: int, key: str, where: str) -> tuple[str, int]:
    """The text after ``key`` on the next non-blank line at or after ``i``; and that index."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise BVHError(f"{where}: line {len(lines)}: unexpected end of file, expected '{key}'")
    line = lines[i].strip()
    if not line.startswith(key):
        raise BVHError(f"{where}: line {i + 1}: expected '{key}', found {_short(line)}")
    return line[len(key):].strip(), i


def _parse_motion(lines: list[str], motion_at: int, skeleton: Skeleton,
                  where: str) -> tuple[np.ndarray, float]:
    """(frames, channels) values and fps from the lines after ``MOTION``."""
    frames_txt, i = _header(lines, motion_at + 1, "Frames:", where)
    if not _COUNT.fullmatch(frames_txt) or len(frames_txt) > 12:
        raise BVHError(f"{where}: line {i + 1}: frame count {_short(frames_txt)} is not a "
                       "non-negative integer below 10**12")
    n_frames = int(frames_txt)
    if n_frames == 0:
        raise BVHError(f"{where}: line {i + 1}: the file has zero frames ('Frames: 0')")
    if skeleton.n_channels == 0:
        raise BVHError(f"{where}: line {motion_at + 1}: the hierarchy declares no channels, so "
                       "frames cannot be stored")
    ft_txt, i = _header(lines, i + 1, "Frame Time:", where)
    fps = _fps(ft_txt, lambda msg: BVHError(f"{where}: line {i + 1}: {msg}"))
    return _frames(lines, i + 1, n_frames, skeleton, where), fps


def _fps(ft_txt: str, error) -> float:
    """Frames per second from the ``Frame Time:`` text (see the module docstring).

    ``1 / ft`` is computed in decimal from the text, so the writer can always pick a text that
    reads back to a given float64 fps exactly.
    """
    ft = _number(ft_txt, "the frame time", error)
    if not ft > 0:
        raise error(f"frame time must be positive, got {ft_txt!r}")
    ft_dec = Decimal(ft_txt)
    fps = float(_DECIMAL.divide(1, ft_dec))
    if not math.isfinite(fps):
        raise error(f"frame time {ft_txt!r} is too small (fps overflows)")
    # snap to n when 1/n is the only reciprocal of an integer within one unit of the text's last
    # written digit ("0.0333" -> 30, "0.0167" or "0.01666" -> 60; "0.03" fits 30 to 33: kept)
    unit = Decimal(1).scaleb(ft_dec.as_tuple().exponent)
    lo_ft, hi_ft = _DECIMAL.subtract(ft_dec, unit), _DECIMAL.add(ft_dec, unit)
    if lo_ft > 0:
        n_lo = math.ceil(_DECIMAL.divide(1, hi_ft))
        n_hi = math.floor(_DECIMAL.divide(1, lo_ft))
        if n_lo == n_hi and n_lo >= 1:
            return float(n_lo)
    return fps


def _frames(lines: list[str], start: int, n_frames: int, skeleton: Skeleton,
            where: str) -> np.ndarray:
    C = skeleton.n_channels
    rows = []
    for i in range(start, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        if len(rows) == n_frames:
            raise BVHError(f"{where}: line {i + 1}: more frame lines than 'Frames: {n_frames}'")
        toks = line.split()
        if len(toks) != C:
            raise BVHError(f"{where}: line {i + 1}: expected {C} channel values (frame "
                           f"{len(rows) + 1} of {n_frames}), found {len(toks)}")
        rows.append(_row(toks, line, lambda msg, i=i: BVHError(f"{where}: line {i + 1}: {msg}"),
                         skeleton))
    if len(rows) < n_frames:
        raise BVHError(f"{where}: line {len(lines)}: the file is truncated: 'Frames: {n_frames}' "
                       f"but only {len(rows)} frame lines")
    return np.array(rows, dtype=np.float64).reshape(n_frames, C)


def _row(toks: list[str], line: str, error, skeleton: Skeleton) -> list[float]:
    """One frame's floats; the fast path is plain ``float``, the strict check runs on failure."""
    try:
        if line.isascii() and "_" not in line:
            row = [float(t) for t in toks]
            if all(math.isfinite(x) for x in row):
                return row
    except ValueError:
        pass
    names = skeleton.channel_names
    return [_number(t, f"channel {c + 1} ({names[c]})", error) for c, t in enumerate(toks)]


def _decode(raw: bytes) -> str:
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


def read_bvh(path: str | os.PathLike) -> Motion:
    """Read a BVH file.

    Args:
        path: file path.
    Returns:
        the :class:`Motion` (name = file stem).
    Raises:
        BVHError: unreadable file or malformed content, with the line number.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise BVHError(f"{path}: cannot read file: {e.strerror or e}") from None
    return parse_bvh(_decode(raw), where=str(path), name=path.stem)


# ----------------------------------------------------------------------------- writing
def _fmt(x: float, precision: int | None) -> str:
    if precision is None:
        s = repr(float(x))
        return s[:-2] if s.endswith(".0") else s
    return f"{x:.{precision}f}"


def _frame_time_text(fps: float) -> str:
    """The shortest of a few frame-time texts that :func:`_fps` reads back as ``fps`` exactly."""
    for digits in (None, 17, 21, 25, 30):
        exact = _DECIMAL.divide(1, Decimal(fps))
        txt = repr(1.0 / fps) if digits is None else f"{exact:.{digits}g}"
        if _fps(txt, BVHError) == fps:
            break
    return txt


def format_bvh(motion: Motion, precision: int | None = None) -> str:
    """BVH text of a motion (see :func:`write_bvh`); tab indents, LF line ends."""
    if precision is not None and (isinstance(precision, bool) or not isinstance(precision, int)
                                  or precision < 0):
        raise BayesmotionError(f"precision must be None or a non-negative int, got {precision!r}")
    sk = motion.skeleton
    children = [[] for _ in sk.names]
    for j, p in enumerate(sk.parents):
        if p >= 0:
            children[p].append(j)
    out = ["HIERARCHY"]
    stack: list[tuple[int, int, bool]] = [(0, 0, False)]  # (joint, depth, closing?)
    while stack:
        j, depth, closing = stack.pop()
        ind = "\t" * depth
        if closing:
            if j in sk.end_sites:
                off = " ".join(_fmt(v, precision) for v in sk.end_sites[j])
                out += [f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {off}", f"{ind}\t}}"]
            out.append(f"{ind}}}")
            continue
        off = " ".join(_fmt(v, precision) for v in sk.offsets[j])
        out += [f"{ind}{'ROOT' if sk.parents[j] < 0 else 'JOINT'} {sk.names[j]}", f"{ind}{{",
                f"{ind}\tOFFSET {off}",
                f"{ind}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}".rstrip()]
        stack.append((j, depth, True))
        stack += [(c, depth + 1, False) for c in reversed(children[j])]
    out += ["MOTION", f"Frames: {motion.n_frames}",
            f"Frame Time: {_frame_time_text(motion.fps)}"]
    out += [" ".join(_fmt(v, precision) for v in row) for row in motion.values.tolist()]
    return "\n".join(out) + "\n"


def write_bvh(motion: Motion, path: str | os.PathLike, precision: int | None = None) -> Path:
    """Write a motion as BVH, atomically (temp file in the same folder, then rename).

    Args:
        motion: the motion.
        path: destination; an existing file is replaced only once the new one is complete.
        precision: decimals per value; ``None`` writes the shortest exact decimal.
    Returns:
        the path written.
    """
    return atomic_write_text(Path(path), format_bvh(motion, precision))
