"""BVH reader and writer.

``read_bvh`` accepts any rotation order per joint, 0-6 channels per joint, End Sites, CRLF/LF
line ends, tabs and scientific notation. Any problem raises :class:`~bayesmotion.BVHError`
naming the line. ``write_bvh`` writes the shortest decimal that reads back to the same float64
(``repr``), so read -> write -> read is exact; ``precision=k`` writes k decimals instead.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from ..errors import BVHError
from .motion import Motion
from .skeleton import VALID_CHANNELS, Skeleton

_TOKEN = re.compile(r"\S+")


class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their 1-based line numbers."""

    def __init__(self, lines: list[str], where: str):
        self.items = [(m.group(0), i + 1) for i, line in enumerate(lines)
                      for m in _TOKEN.finditer(line)]
        self.pos = 0
        self.where = where
        self.last_line = len(lines)

    def error(self, msg: str, line: int | None = None) -> BVHError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.last_line
        return BVHError(f"{self.where}: line {line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of file, expected {what}")
        tok = self.items[self.pos]
        self.pos += 1
        return tok

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok != word:
            raise self.error(f"expected {word!r}, found {tok!r}", line)
        return line

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            x = float(tok)
        except ValueError:
            raise self.error(f"expected a number for {what}, found {tok!r}", line) from None
        if not math.isfinite(x):
            raise self.error(f"{what} is not finite ({tok!r})", line)
        return x


def _parse_joint(tk: _Tokens, parent: int, acc: dict) -> None:
    name_tok, line = tk.next("a joint name")
    if name_tok == "{":
        raise tk.error("joint has no name", line)
    if name_tok in acc["names"]:
        raise tk.error(f"duplicate joint name {name_tok!r}", line)
    j = len(acc["names"])
    acc["names"].append(name_tok)
    acc["parents"].append(parent)
    tk.expect("{")
    tk.expect("OFFSET")
    acc["offsets"].append([tk.number(f"OFFSET of {name_tok}") for _ in range(3)])
    tk.expect("CHANNELS")
    n_tok, line = tk.next("a channel count")
    if not n_tok.isdigit() or int(n_tok) > 6:
        raise tk.error(f"joint {name_tok!r}: channel count must be 0-6, found {n_tok!r}", line)
    chans = []
    for _ in range(int(n_tok)):
        c, line = tk.next("a channel name")
        if c not in VALID_CHANNELS:
            raise tk.error(f"joint {name_tok!r}: unknown channel {c!r}", line)
        if c in chans:
            raise tk.error(f"joint {name_tok!r}: channel {c!r} listed twice", line)
        chans.append(c)
    acc["channels"].append(tuple(chans))
    while True:
        tok, line = tk.next("'JOINT', 'End Site' or '}'")
        if tok == "}":
            return
        if tok == "JOINT":
            _parse_joint(tk, j, acc)
        elif tok == "End":
            tk.expect("Site")
            if j in acc["end_sites"]:
                raise tk.error(f"joint {name_tok!r} has two End Sites", line)
            tk.expect("{")
            tk.expect("OFFSET")
            acc["end_sites"][j] = [tk.number("End Site OFFSET") for _ in range(3)]
            tk.expect("}")
        else:
            raise tk.error(f"expected 'JOINT', 'End Site' or '}}', found {tok!r}", line)


def parse_bvh(text: str, where: str = "<string>", name: str = "") -> Motion:
    """Parse BVH text into a :class:`Motion`. ``where`` names the source in error messages."""
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    motion_at = next((i for i, l in enumerate(lines) if l.strip() == "MOTION"), None)
    if motion_at is None:
        raise BVHError(f"{where}: line {len(lines)}: no MOTION section found")
    tk = _Tokens(lines[:motion_at], where)
    tk.expect("HIERARCHY")
    tk.expect("ROOT")
    acc = {"names": [], "parents": [], "offsets": [], "channels": [], "end_sites": {}}
    _parse_joint(tk, -1, acc)
    if tk.peek() is not None:
        raise tk.error(f"unexpected {tk.peek()!r} after the root joint (one ROOT per file)")
    skeleton = Skeleton(acc["names"], acc["parents"], np.array(acc["offsets"]),
                        acc["channels"], acc["end_sites"])
    values, fps = _parse_motion(lines, motion_at, skeleton.n_channels, where)
    return Motion(skeleton, values, fps, name)


def _header(lines: list[str], i: int, key: str, where: str) -> str:
    if i >= len(lines):
        raise BVHError(f"{where}: line {i + 1}: unexpected end of file, expected '{key}'")
    line = lines[i].strip()
    if not line.startswith(key):
        raise BVHError(f"{where}: line {i + 1}: expected '{key}', found {line[:40]!r}")
    return line[len(key):].strip()


def _parse_motion(lines, motion_at, n_channels, where):
    frames_txt = _header(lines, motion_at + 1, "Frames:", where)
    if not frames_txt.isdigit():
        raise BVHError(f"{where}: line {motion_at + 2}: frame count {frames_txt!r} is not an integer")
    n_frames = int(frames_txt)
    if n_frames == 0:
        raise BVHError(f"{where}: line {motion_at + 2}: the file has zero frames")
    ft_txt = _header(lines, motion_at + 2, "Frame Time:", where)
    try:
        frame_time = float(ft_txt)
    except ValueError:
        raise BVHError(f"{where}: line {motion_at + 3}: frame time {ft_txt!r} is not a number") from None
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise BVHError(f"{where}: line {motion_at + 3}: frame time must be positive, got {ft_txt}")
    start = motion_at + 3
    rows = []
    for i in range(start, len(lines)):
        if len(rows) == n_frames:
            if lines[i].strip():
                raise BVHError(f"{where}: line {i + 1}: more frame lines than 'Frames: {n_frames}'")
            continue
        if not lines[i].strip():
            continue
        toks = lines[i].split()
        if len(toks) != n_channels:
            raise BVHError(f"{where}: line {i + 1}: expected {n_channels} channel values, "
                           f"found {len(toks)}")
        try:
            row = [float(t) for t in toks]
        except ValueError:
            bad = next(t for t in toks if not _is_float(t))
            raise BVHError(f"{where}: line {i + 1}: non-numeric value {bad!r}") from None
        if not all(math.isfinite(x) for x in row):
            raise BVHError(f"{where}: line {i + 1}: NaN or infinite channel value")
        rows.append(row)
    if len(rows) < n_frames:
        raise BVHError(f"{where}: line {len(lines)}: file is truncated: 'Frames: {n_frames}' "
                       f"but only {len(rows)} frame lines")
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 1e-4 * fps:  # "Frame Time: .0083333" means 120 fps
        fps = float(round(fps))
    return np.array(rows, dtype=np.float64).reshape(n_frames, n_channels), fps


def _is_float(t: str) -> bool:
    try:
        float(t)
        return True
    except ValueError:
        return False


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
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return parse_bvh(text, where=str(path), name=path.stem)


def _fmt(x: float, precision: int | None) -> str:
    if precision is None:
        s = repr(float(x))
        return s[:-2] if s.endswith(".0") else s
    return f"{x:.{precision}f}"


def format_bvh(motion: Motion, precision: int | None = None) -> str:
    """BVH text of a motion (see :func:`write_bvh`)."""
    sk = motion.skeleton
    out = ["HIERARCHY"]

    def joint(j: int, depth: int):
        ind = "\t" * depth
        kind = "ROOT" if sk.parents[j] < 0 else "JOINT"
        out.append(f"{ind}{kind} {sk.names[j]}")
        out.append(f"{ind}{{")
        off = " ".join(_fmt(v, precision) for v in sk.offsets[j])
        out.append(f"{ind}\tOFFSET {off}")
        out.append(f"{ind}\tCHANNELS {len(sk.channels[j])} {' '.join(sk.channels[j])}".rstrip())
        for c in sk.children(j):
            joint(c, depth + 1)
        if j in sk.end_sites:
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            off = " ".join(_fmt(v, precision) for v in sk.end_sites[j])
            out.append(f"{ind}\t\tOFFSET {off}")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    joint(0, 0)
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {repr(1.0 / motion.fps)}"]
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
    path = Path(path)
    text = format_bvh(motion, precision)
    return atomic_write_text(path, text)


def atomic_write_text(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file and ``os.replace``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", newline="\n") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path
