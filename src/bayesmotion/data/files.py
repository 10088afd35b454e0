"""Safe file access: atomic writes (a file is replaced whole or left untouched, never
half-written) and reads of regular files only (a FIFO or a device is never opened).

The temporary file of a write to ``dir/name.ext`` is ``dir/.name.ext.<pid>.<8 random>.tmp.ext``.
A process killed while writing (``kill -9``, power loss) leaves it behind; the next atomic write
to the same target removes such leftovers: files whose names match that exact pattern, that
were last modified over :data:`STALE_SECONDS` ago and whose writer (the ``<pid>`` in the name)
is no longer running on this machine. Nothing else in the folder is touched.
"""

from __future__ import annotations

import contextlib
import os
import re
import stat
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

STALE_SECONDS = 60.0
"""A leftover temporary file is removed only when last modified longer ago than this (guards
writers on other machines sharing the folder, whose pids mean nothing here)."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` (``os.replace``).

    On any exception the temporary file is removed and an existing ``path`` is left untouched.
    Stale temporary files of earlier, interrupted writes to ``path`` are removed first (module
    docstring). The file gets the usual permissions (``0o666 & ~umask``, or those of the file
    it replaces).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(path)
    # the temporary name ends in path's suffix, for writers that pick a format by it (Pillow)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.",
                               suffix=f".tmp{path.suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _mode_for(path))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _temporary_pattern(path: Path) -> re.Pattern:
    """Names of :func:`atomic_path`'s temporaries of ``path``; group 1 is the writer's pid
    (absent in names written before it was recorded)."""
    name, suffix = re.escape(path.name), re.escape(path.suffix)
    return re.compile(rf"\.{name}\.(?:(\d{{1,10}})\.)?[a-z0-9_]{{8}}\.tmp{suffix}")


def remove_stale_temporaries(path: str | os.PathLike, min_age: float | None = None) -> list[Path]:
    """Remove the temporary files that interrupted atomic writes to ``path`` left (module
    docstring); returns those removed. Errors are ignored: cleaning never fails a write.

    Args:
        path: the target of the writes.
        min_age: seconds since the last modification; default :data:`STALE_SECONDS`.
    """
    path = Path(path)
    pattern = _temporary_pattern(path)
    cutoff = time.time() - (STALE_SECONDS if min_age is None else min_age)
    removed = []
    with contextlib.suppress(OSError), os.scandir(path.parent) as entries:
        for entry in entries:
            m = pattern.fullmatch(entry.name)
            if m is None or (m.group(1) is not None and _running(int(m.group(1)))):
                continue
            with contextlib.suppress(OSError):
                st = entry.stat(follow_symlinks=False)
                if stat.S_ISREG(st.st_mode) and st.st_mtime < cutoff:
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
    return removed


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists on this machine (True where that cannot be told)."""
    if os.name != "posix":  # os.kill(pid, 0) would terminate the process on Windows
        return True
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True  # exists under another user, or cannot be told: keep the file
    return True


def _mode_for(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def atomic_write_text(path: Path, text: str) -> Path:
    """Write ``text`` (UTF-8, LF kept as is) to ``path`` through a temporary file."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return path


# ------------------------------------------------------------------------------ reading
class NotRegularFileError(OSError):
    """The path names a directory, FIFO, device or socket, not a regular file."""


_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _check_regular(st: os.stat_result) -> None:
    if not stat.S_ISREG(st.st_mode):
        kind = next((k for test, k in _KINDS if test(st.st_mode)), "not a regular file")
        raise NotRegularFileError(f"it is {kind}, not a regular file")


@contextlib.contextmanager
def open_regular(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """``path`` opened for binary reading, if it is a regular file.

    It is checked before it is opened (``stat``: a FIFO would block ``open``, a device would
    read without end) and again after (``fstat`` of the open file, in case the path changed in
    between; opened with ``O_NONBLOCK``, so a FIFO swapped in cannot block either).

    Raises:
        NotRegularFileError: not a regular file (an OSError: the message says what it is).
        OSError: missing or unreadable.
        ValueError: the path contains a NUL byte.
    """
    _check_regular(os.stat(path))
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    with open(fd, "rb") as f:
        _check_regular(os.fstat(f.fileno()))
        yield f


def read_at_most(f: BinaryIO, limit: int) -> bytes:
    """Up to ``limit + 1`` bytes of an open file (so a caller can tell it is over ``limit``).

    The first read is sized by the file's stated size, as ``read(n)`` allocates n bytes before
    reading (a file in /proc states size 0, so the rest is read in 1 MiB pieces)."""
    size = os.fstat(f.fileno()).st_size
    data = f.read(min(size, limit) + 1)
    if len(data) <= size:
        return data
    parts, n = [data], len(data)
    while n <= limit and (more := f.read(min(2**20, limit + 1 - n))):
        parts.append(more)
        n += len(more)
    return b"".join(parts)
