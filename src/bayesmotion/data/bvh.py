"""BVH reader and writer.

One concept: the BVH text format, read and written in one module because the writer picks its
texts with the reader's rules (frame time, numbers), so that every file it writes reads back.

``parse_bvh``/``read_bvh`` accept any rotation order per joint, 0-6 channels per joint, End Sites,
CRLF/LF/CR line ends, tabs, a UTF-8 byte-order mark and scientific notation. Anything else raises
:class:`~bayesmotion.BVHError` naming the line and the problem, never another exception.

Untrusted input: ``read_bvh`` reads regular files only (a FIFO or a device is refused before it
is opened), of at most ``max_bytes`` (:data:`MAX_BYTES`) and ``max_frames`` (:data:`MAX_FRAMES`)
frames; the hierarchy may hold :data:`MAX_JOINTS` joints. The text is read line by
line, each line split only as far as the channel count, so a parse fails at the first bad line
without tokenising the rest. Messages quote at most 80 characters of any token or line.
``read_bvh`` also refuses a file whose last frame line has no line end: every writer ends its
lines (``write_bvh``, CMU, Bandai), so that file was cut short, maybe inside its last number,
which would otherwise read back as a different value (``parse_bvh`` of a string accepts it).

``write_bvh`` writes the shortest decimal that reads back to the same float64 (``repr``), so
read -> write -> read is bit-exact for channel values, offsets and fps; ``precision=k`` writes k
decimals instead.

Frame rate: ``fps = 1 / Frame Time``, snapped to an integer n when 1/n is the only reciprocal of
an integer within one unit of the frame time's last written digit (``.0083333`` -> 120.0,
``0.0333`` -> 30.0, ``0.01666`` -> 60.0; ``0.03``, which fits 30 to 33, stays 33.33...). The
frame time must lie in :data:`FRAME_TIME_RANGE`.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from decimal import Context, Decimal
from pathlib import Path

import numpy as np

from bayesmotion.data.files import atomic_write_text, open_regular, read_at_most
from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import VALID_CHANNELS, Skeleton
from bayesmotion.errors import BayesmotionError, BVHError

MAX_BYTES = 512 * 2**20
"""Default ``max_bytes``: the largest file (or text) read; 512 MiB is ~40 min of a 100-channel
rig at 120 fps."""
MAX_FRAMES = 1_000_000
"""Default ``max_frames``: the most frames a file may declare (2.3 h at 120 fps)."""
MAX_JOINTS = 100_000
"""Joints the HIERARCHY may declare (CMU has 31, Bandai 22): it bounds the hierarchy's parse
whatever the text, which the writer's tab indents make quadratic in a deep chain's depth."""
FRAME_TIME_RANGE = (1e-6, 1e4)
"""Accepted frame times in seconds (1e-4 to 1e6 fps): beyond high-speed capture at one end and
a frame every few hours at the other."""

_TOKEN = re.compile(r"\S+")
_NONBLANK = re.compile(r"\S")
_MOTION = re.compile(r"\s*MOTION\s*")  # the line that ends the hierarchy
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)  # ASCII digits only
_COUNT = re.compile(r"\d+", re.ASCII)
_DECIMAL = Context(prec=60)  # exact enough for 1 / frame time of any float64
_QUOTE = 80  # characters of a token or line quoted in a message


# ----------------------------------------------------------------------------- reading
class _Lines:
    """The lines of ``text`` one at a time (LF, CRLF or CR ends), numbered from 1 as
    ``text.split`` on normalised line ends would number them; nothing is split ahead.

    Attributes:
        number: the number of the line last returned (at the end: the count of lines).
        terminated: whether the line last returned ended with a line end.
    """

    def __init__(self, text: str, where: str, start: int = 0):
        self.text, self.where, self.pos = text, where, start
        self.number, self.terminated = 0, False
        self._next_end = {"\n": None, "\r": None}  # next index of each; -1: none left

    def _end(self, ch: str) -> int:
        """The index of the next ``ch`` at or after ``pos`` (``str.find``, each searched once
        per occurrence: a regex scan is 100 times slower)."""
        at = self._next_end[ch]
        if at is None or -1 < at < self.pos:
            at = self._next_end[ch] = self.text.find(ch, self.pos)
        return at

    def span(self) -> tuple[int, int] | None:
        """(start, end) in ``text`` of the next line, or None at the end."""
        text, pos = self.text, self.pos
        if pos > len(text):
            return None
        ends = [i for i in (self._end("\n"), self._end("\r")) if i >= 0]
        end = min(ends) if ends else len(text)
        self.terminated = bool(ends)
        self.pos = (end + 1 + (text.startswith("\r\n", end)) if ends else len(text) + 1)
        self.number += 1
        return pos, end

    def next(self) -> str | None:
        """The next line, or None at the end."""
        span = self.span()
        return None if span is None else self.text[span[0]:span[1]]

    def error(self, msg: str) -> BVHError:
        return BVHError(f"{self.where}: line {self.number}: {msg}")


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers, read lazily
    up to the first line that is ``MOTION`` (or the end of the text).

    Attributes:
        end: what running out of tokens means (``"end of file"`` or ``"'MOTION' (line k)"``),
            None until it happens.
        end_line: the line reported when tokens run out.
    """

    def __init__(self, lines: _Lines):
        self.lines, self.where = lines, lines.where
        self.end: str | None = None
        self.end_line = 0
        self.motion = False
        self._line_tokens = iter(())
        self._ahead: tuple[str, int] | None = None

    def _pull(self) -> tuple[str, int] | None:
        while True:
            m = next(self._line_tokens, None)
            if m is not None:
                return m.group(0), self.lines.number
            if self.end is not None:
                return None
            span = self.lines.span()  # tokens are found in place: no copy of a long line
            if span is None or _MOTION.fullmatch(self.lines.text, *span):
                self.motion = span is not None
                n = self.lines.number
                self.end = f"'MOTION' (line {n})" if self.motion else "end of file"
                self.end_line = n
                return None
            self._line_tokens = _TOKEN.finditer(self.lines.text, *span)

    def peek(self) -> tuple[str, int] | None:
        if self._ahead is None:
            self._ahead = self._pull()
        return self._ahead

    def error(self, msg: str, line: int | None = None) -> BVHError:
        if line is None:
            ahead = self.peek()
            line = ahead[1] if ahead is not None else self.end_line
        return BVHError(f"{self.where}: line {line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        tok = self.peek()
        if tok is None:
            raise self.error(f"unexpected {self.end}, expected {what}")
        self._ahead = None
        return tok

    def expect(self, word: str, context: str = "") -> int:
        tok, line = self.next(repr(word) + context)
        if tok != word:
            raise self.error(f"expected {word!r}{context}, found {_short(tok)}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(f"a number for {what}")
        return _number(tok, what, lambda msg: self.error(msg, line))

    def vector(self, what: str) -> list[float]:
        return [self.number(f"{what} ({axis})") for axis in "XYZ"]


def _short(tok: str) -> str:
    """``repr`` of a token or line, cut to its first 80 characters."""
    return repr(tok if len(tok) <= _QUOTE else tok[:_QUOTE - 3] + "...")


def _number(tok: str, what: str, error) -> float:
    """A finite decimal number (``1``, ``-.5``, ``3e-05``); anything else is ``error(msg)``."""
    if not _NUMBER.fullmatch(tok):
        if tok.lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise error(f"{what} is {_short(tok)}; NaN and infinity are not allowed")
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
        raise tk.error(f"duplicate joint name {_short(name)} (first defined at line {first}); a "
                       "BVH hierarchy is a tree, so a joint cannot appear twice", line)
    j = len(acc["names"])
    if j == MAX_JOINTS:
        raise tk.error(f"more than MAX_JOINTS={MAX_JOINTS} joints; if the file is right, raise "
                       "bayesmotion.data.bvh.MAX_JOINTS", line)
    acc["names"].append(name)
    acc["lines"][name] = line
    acc["parents"].append(parent)
    tk.expect("{", f" after joint {_short(name)}")
    tk.expect("OFFSET", f" in joint {_short(name)}")
    acc["offsets"].append(tk.vector(f"OFFSET of {_short(name)}"))
    tk.expect("CHANNELS", f" in joint {_short(name)}")
    acc["channels"].append(_channels(tk, name))
    return j


def _channels(tk: _Tokens, name: str) -> tuple[str, ...]:
    q = _short(name)
    n_tok, line = tk.next(f"the channel count of {q}")
    if len(n_tok) > 3 or not _COUNT.fullmatch(n_tok) or int(n_tok) > 6:
        raise tk.error(f"joint {q}: channel count must be 0-6, found {_short(n_tok)}", line)
    chans: list[str] = []
    for k in range(int(n_tok)):
        c, line = tk.next(f"channel {k + 1} of {n_tok} of joint {q}")
        if c not in VALID_CHANNELS:
            raise tk.error(f"joint {q}: channel {k + 1} of {n_tok} is {_short(c)}, not one "
                           f"of {', '.join(VALID_CHANNELS)} (wrong channel count?)", line)
        if c in chans:
            raise tk.error(f"joint {q}: channel {c!r} listed twice", line)
        chans.append(c)
    return tuple(chans)


def _end_site(tk: _Tokens, j: int, acc: dict, line: int) -> None:
    q = _short(acc["names"][j])
    tk.expect("Site", " after 'End'")
    if j in acc["end_sites"]:
        raise tk.error(f"joint {q} has two End Sites", line)
    tk.expect("{", " after 'End Site'")
    tk.expect("OFFSET", " in End Site")
    acc["end_sites"][j] = tk.vector(f"End Site OFFSET of {q}")
    tk.expect("}", f" closing the End Site of {q}")


def _open_list(names: list[str], stack: list[int]) -> str:
    """The open joints of ``stack`` for a message: the first and last three when there are more."""
    shown = [_short(names[k]) for k in (stack if len(stack) <= 6 else stack[:3] + stack[-3:])]
    return ", ".join(shown if len(stack) <= 6 else shown[:3] + ["..."] + shown[3:])


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
            raise tk.error(f"unbalanced braces: unexpected {tk.end} with {len(stack)} joint(s) "
                           f"still open ({_open_list(acc['names'], stack)}); expected 'JOINT', "
                           f"'End Site' or '}}'")
        tok, line = tk.next("'JOINT', 'End Site' or '}'")
        if tok == "}":
            stack.pop()
        elif tok == "JOINT":
            stack.append(_open_joint(tk, j, acc))
        elif tok == "End":
            _end_site(tk, j, acc, line)
        else:
            raise tk.error(f"in joint {_short(acc['names'][j])}: expected 'JOINT', 'End Site' or "
                           f"'}}', found {_short(tok)}", line)
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


def parse_bvh(text: str | bytes, where: str = "<string>", name: str = "", *,
              max_bytes: int | None = None, max_frames: int | None = None,
              final_newline: bool = False) -> Motion:
    """Parse BVH text into a :class:`Motion`.

    Args:
        text: the file content (``bytes`` are decoded as UTF-8, else Latin-1).
        where: names the source in error messages.
        name: the motion's name.
        max_bytes: the longest text accepted, in bytes (``str``: characters); default
            :data:`MAX_BYTES`.
        max_frames: the most frames the text may declare; default :data:`MAX_FRAMES`.
        final_newline: refuse a last frame line without a line end (a file cut short);
            :func:`read_bvh` sets it.
    Returns:
        the motion; ``values`` is (frames, channels) in file order.
    Raises:
        BVHError: malformed content, with the line number and the problem, or a limit passed.
    """
    max_bytes = _limit(max_bytes, MAX_BYTES, "max_bytes")
    max_frames = _limit(max_frames, MAX_FRAMES, "max_frames")
    if len(text) > max_bytes:
        unit = "characters" if isinstance(text, str) else "bytes"
        raise BVHError(f"{where}: {len(text)} {unit} is more than max_bytes={max_bytes}; pass a "
                       "larger max_bytes= to read it")
    if isinstance(text, bytes | bytearray | memoryview):
        text = _decode(bytes(text))
    start = 1 if text.startswith("\ufeff") else 0  # a byte-order mark
    _check_text(text, start, where)
    lines = _Lines(text, where, start)
    tk = _Tokens(lines)
    skeleton = _parse_hierarchy(tk)
    if not tk.motion:
        raise BVHError(f"{where}: line {tk.end_line}: no MOTION section after the hierarchy")
    values, fps = _parse_motion(lines, skeleton, max_frames, final_newline)
    try:
        return Motion(skeleton, values, fps, name)
    except BayesmotionError as e:  # defensive: _parse_motion checks what Motion checks
        raise BVHError(f"{where}: line {tk.end_line}: invalid motion: {e}") from None


def _limit(value, default: int, name: str) -> int:
    value = default if value is None else value
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise BayesmotionError(f"{name} must be a positive int, got {value!r}")
    return int(value)


def _check_text(text: str, start: int, where: str) -> None:
    if not _NONBLANK.search(text, start):
        raise BVHError(f"{where}: line 1: the file is empty")
    nul = text.find("\x00")
    if nul >= 0:
        line = 1 + text.count("\n", 0, nul) + text.count("\r", 0, nul) - text.count("\r\n", 0, nul)
        raise BVHError(f"{where}: line {line}: NUL byte: binary data, not a BVH text file")


def _header(lines: _Lines, key: str) -> str:
    """The text after ``key`` on the next non-blank line."""
    line = lines.next()
    while line is not None and not line.strip():
        line = lines.next()
    if line is None:
        raise lines.error(f"unexpected end of file, expected '{key}'")
    line = line.strip()
    if not line.startswith(key):
        raise lines.error(f"expected '{key}', found {_short(line)}")
    return line[len(key):].strip()


def _parse_motion(lines: _Lines, skeleton: Skeleton, max_frames: int,
                  final_newline: bool) -> tuple[np.ndarray, float]:
    """(frames, channels) values and fps from the lines after ``MOTION``."""
    motion_line = lines.number
    frames_txt = _header(lines, "Frames:")
    if len(frames_txt) > 12 or not _COUNT.fullmatch(frames_txt):
        raise lines.error(f"frame count {_short(frames_txt)} is not a non-negative integer "
                          "below 10**12")
    n_frames = int(frames_txt)
    if n_frames == 0:
        raise lines.error("the file has zero frames ('Frames: 0')")
    if n_frames > max_frames:
        raise lines.error(f"'Frames: {n_frames}' is more than max_frames={max_frames}; pass a "
                          "larger max_frames= to read it")
    if skeleton.n_channels == 0:
        raise BVHError(f"{lines.where}: line {motion_line}: the hierarchy declares no channels, "
                       "so frames cannot be stored")
    fps = _fps(_header(lines, "Frame Time:"), lines.error)
    return _frames(lines, n_frames, skeleton, final_newline), fps


def _fps(ft_txt: str, error) -> float:
    """Frames per second from the ``Frame Time:`` text (see the module docstring).

    ``1 / ft`` is computed in decimal from the text, so the writer can always pick a text that
    reads back to a given float64 fps exactly.
    """
    ft = _number(ft_txt, "the frame time", error)
    if not ft > 0:
        raise error(f"frame time must be positive, got {_short(ft_txt)}")
    ft_dec = Decimal(ft_txt)
    fps = float(_DECIMAL.divide(1, ft_dec))
    if not math.isfinite(fps):
        raise error(f"frame time {_short(ft_txt)} is too small (fps overflows)")
    lo, hi = FRAME_TIME_RANGE
    if not lo <= ft <= hi:
        raise error(f"frame time {_short(ft_txt)} s is outside {lo:g} to {hi:g} s ({1 / hi:g} to "
                    f"{1 / lo:g} fps): not a motion-capture frame rate")
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


def _frames(lines: _Lines, n_frames: int, skeleton: Skeleton, final_newline: bool) -> np.ndarray:
    """The frame lines into an (n_frames, C) array, one line at a time."""
    C = skeleton.n_channels
    # a frame line holds C numbers and C - 1 separators, so the rest of the text bounds the rows
    fits = (len(lines.text) - lines.pos + 1) // (2 * C) + 1
    values = np.empty((min(n_frames, fits), C))
    k, last_ended = 0, True
    while (span := lines.span()) is not None:
        if not _NONBLANK.search(lines.text, *span):
            continue
        if k == n_frames:
            raise lines.error(f"more frame lines than 'Frames: {n_frames}'")
        toks, line = _frame_tokens(lines.text, *span, C)
        if len(toks) != C:
            found = len(toks) if len(toks) < C else _count_tokens(lines.text, *span, C)
            raise lines.error(f"expected {C} channel values (frame {k + 1} of {n_frames}), "
                              f"found {found}")
        values[k] = _row(toks, line, lines.error, skeleton)
        k, last_ended = k + 1, lines.terminated
    if k < n_frames:
        raise lines.error(f"the file is truncated: 'Frames: {n_frames}' but only {k} frame lines")
    if final_newline and not last_ended:
        raise lines.error("the last frame line has no line end, so the file may have been cut "
                          "inside its last number; if the file is complete, end it with a "
                          "newline")
    return values


def _frame_tokens(text: str, start: int, end: int, C: int) -> tuple[list[str], str]:
    """At most C + 1 tokens of the line text[start:end], and the line (its tokens joined when
    it is long). A line of up to 100 characters per value (every real file's) is split, the
    fast way; a longer one is scanned in place, so a huge line is never copied or split whole."""
    if end - start <= 100 * C:
        line = text[start:end]
        return line.split(maxsplit=C), line
    toks = [m.group(0) for m in itertools.islice(_TOKEN.finditer(text, start, end), C + 1)]
    return toks, " ".join(toks)


def _count_tokens(text: str, start: int, end: int, C: int) -> str:
    """The number of tokens of the line text[start:end] (more than ``C``), counted in place."""
    n = sum(1 for _ in itertools.islice(_TOKEN.finditer(text, start, end), C + 100_001))
    return str(n) if n <= C + 100_000 else f"more than {C + 100_000}"


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


def read_bvh(path: str | os.PathLike, *, max_bytes: int | None = None,
             max_frames: int | None = None) -> Motion:
    """Read a BVH file.

    Only a regular file is opened (a FIFO, a device or a folder is refused at once, before it
    is opened), and one larger than ``max_bytes`` is refused before it is read. A last frame
    line without a line end is refused as a file cut short (module docstring).

    Args:
        path: file path.
        max_bytes: the largest file read; default :data:`MAX_BYTES`.
        max_frames: the most frames the file may declare; default :data:`MAX_FRAMES`.
    Returns:
        the :class:`Motion` (name = file stem).
    Raises:
        BVHError: unreadable file, a limit passed, or malformed content, with the line number.
    """
    path = Path(path)
    limit = _limit(max_bytes, MAX_BYTES, "max_bytes")
    text = _decode(_read_file(path, limit))  # the bytes are freed once decoded
    return parse_bvh(text, where=str(path), name=path.stem, max_bytes=limit,
                     max_frames=max_frames, final_newline=True)


def _read_file(path: Path, limit: int) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes; BVHError otherwise."""
    try:
        with open_regular(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size > limit:
                raise BVHError(f"{path}: cannot read file: {size} bytes is more than "
                               f"max_bytes={limit}; pass a larger max_bytes= to read it")
            raw = read_at_most(f, limit)
    except ValueError:
        raise BVHError(f"{str(path)!r}: cannot read file: the path contains a NUL byte") from None
    except OSError as e:
        raise BVHError(f"{path}: cannot read file: {e.strerror or e}") from None
    if len(raw) > limit:
        raise BVHError(f"{path}: cannot read file: it grew past max_bytes={limit} while being "
                       "read")
    return raw


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
    lo, hi = FRAME_TIME_RANGE
    if not 1 / hi <= motion.fps <= 1 / lo:
        raise BayesmotionError(f"fps {motion.fps:g} is outside the {1 / hi:g} to {1 / lo:g} fps "
                               "that read_bvh accepts (bayesmotion.data.bvh.FRAME_TIME_RANGE)")
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
