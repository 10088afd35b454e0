"""The chain's HDF5 file, safe to read while a run writes it.

emcee's :class:`~emcee.backends.HDFBackend` reopens the file for every step it saves. HDF5 locks
a file while any process holds it open, so a reader watching the chain (a notebook calling
``HDFBackend(path, read_only=True).get_chain()``, ``h5py.File(path)``) made the next save fail
with ``BlockingIOError`` and stopped the run. Worse, while another process held the file open for
writing, emcee's ``initialized`` took it for an empty one, and a resumed run would then reset it,
losing every saved step.

:class:`ChainFile` waits for such a lock instead (a reader like the one above holds it for
milliseconds to a second), and tells a locked or unreadable file from an empty one. Every open
of the chain's file in the package waits this way.
"""

from __future__ import annotations

import os
import time

import emcee

from bayesmotion.errors import BayesmotionError

# how long a run waits for another process's lock on its file before stopping with an error
LOCK_WAIT_S = 120.0


def open_h5(path, mode: str = "r", wait_s: float | None = None):
    """``h5py.File(path, mode)``, waiting up to ``wait_s`` seconds (default ``LOCK_WAIT_S``)
    while another process holds the file locked.

    Raises:
        BayesmotionError: the lock outlasted ``wait_s``, or the file exists but is not an HDF5
            file h5py can open (named, with h5py's reason).
    """
    import h5py

    return _waiting(lambda: h5py.File(str(path), mode), path, wait_s)


def _waiting(open_file, path, wait_s: float | None = None):
    """``open_file()``, retried while it meets another process's HDF5 lock (see
    :func:`open_h5`)."""
    wait_s = LOCK_WAIT_S if wait_s is None else wait_s
    deadline, delay = time.monotonic() + wait_s, 0.005
    while True:
        try:
            return open_file()
        except BlockingIOError as e:  # errno 11: another process holds the HDF5 lock
            if time.monotonic() >= deadline:
                raise BayesmotionError(
                    f"{path}: another process has held this HDF5 file locked for over "
                    f"{wait_s:.0f} s (a reader that keeps it open, or a second run writing the "
                    f"same file); close it and resume the run with the same backend, nothing "
                    f"saved is lost") from e
            time.sleep(delay)
            delay = min(2 * delay, 0.5)
        except OSError as e:
            raise BayesmotionError(f"{path}: cannot open as an HDF5 chain file ({e}); pass "
                                   f"another backend path") from e


class ChainFile(emcee.backends.HDFBackend):
    """emcee's HDF5 backend, whose every open waits for another process's lock
    (:func:`open_h5`).

    Same arguments and file layout as :class:`emcee.backends.HDFBackend` (a file written by
    either reads with the other).
    """

    def open(self, mode="r"):
        return _waiting(lambda: super(ChainFile, self).open(mode), self.filename)

    @property
    def initialized(self) -> bool:
        """Whether the file holds this backend's group. Unlike emcee's, a file that is locked
        (waited for) or unreadable (an error) is not taken for an empty one, which the caller
        would then reset."""
        if not os.path.exists(self.filename):
            return False
        with self.open() as f:
            return self.name in f
