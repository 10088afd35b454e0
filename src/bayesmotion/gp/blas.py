"""OpenBLAS threads for bayesmotion's large host-side factorisations.

bayesmotion keeps scipy's OpenBLAS on one thread (``_config``). :func:`blas_threads` raises it
to the core count for the calling thread only, around the LAPACK calls of
:func:`bayesmotion.gp.linalg.cholesky_inverse`, and only while no other process keeps the cores
busy.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import os
import time

import scipy

from bayesmotion import _config


@contextlib.contextmanager
def blas_threads():
    """scipy's OpenBLAS uses every available core for the calling thread only, when
    bayesmotion chose the one-thread default (``_config``) and the other processes have left
    the cores idle lately (:class:`_OtherLoad`); a no-op for other BLAS builds or when the
    caller set ``OPENBLAS_NUM_THREADS`` themselves.

    Why the load check: OpenBLAS's threads busy-wait, so next to another busy process raised
    threads take cycles from it and from each other, and one thread is faster; alone on the
    machine raised threads are about as fast or faster
    (``benchmarks/results/blas_threads.json``)."""
    set_local = _set_threads_local()
    n = len(os.sched_getaffinity(0)) if set_local is not None else 1
    if n < 2 or not _OTHER_LOAD.idle():
        yield
        return
    prev = set_local(n)
    try:
        yield
    finally:
        set_local(prev)


def others_cores(d_busy_s: float, d_own_s: float, d_wall_s: float) -> float:
    """Cores the other processes kept busy over a window: machine busy time (from /proc/stat)
    minus this process's CPU time, per second of wall time."""
    return (d_busy_s - d_own_s) / d_wall_s


class _OtherLoad:
    """Whether the rest of the machine left the cores idle in the last window (>= 0.25 s;
    ticks are 10 ms). Linux only; elsewhere, and before the first window, it says no."""

    WINDOW_S = 0.25
    IDLE_BELOW = 0.5  # cores used by other processes

    def __init__(self):
        self.last = None
        self.is_idle = False

    def idle(self) -> bool:
        now = self._sample()
        if now is None:
            return False
        if self.last is None:
            self.last = now
        elif now[2] - self.last[2] >= self.WINDOW_S:
            d = [b - a for a, b in zip(self.last, now, strict=True)]
            self.is_idle = others_cores(*d) < self.IDLE_BELOW
            self.last = now
        return self.is_idle

    @staticmethod
    def _sample():
        """(machine busy seconds, this process's CPU seconds, wall seconds) or None."""
        try:
            with open("/proc/stat") as f:
                ticks = [int(v) for v in f.readline().split()[1:]]
        except (OSError, ValueError):
            return None
        busy = sum(ticks[:8]) - ticks[3] - ticks[4]  # all but idle and iowait (guest is in user)
        t = os.times()
        return busy / os.sysconf("SC_CLK_TCK"), t.user + t.system, time.monotonic()


_OTHER_LOAD = _OtherLoad()


@functools.cache
def _set_threads_local():
    """``openblas_set_num_threads_local`` of the OpenBLAS bundled with scipy's wheels (OpenBLAS
    >= 0.3.27), or None."""
    if not _config.BLAS_THREADS_DEFAULTED or not hasattr(os, "sched_getaffinity"):
        return None
    libs = glob.glob(os.path.join(os.path.dirname(scipy.__file__), os.pardir, "scipy.libs",
                                  "libscipy_openblas*"))
    for path in libs:
        fn = getattr(ctypes.CDLL(path), "openblas_set_num_threads_local", None)
        if fn is not None:
            fn.argtypes, fn.restype = [ctypes.c_int], ctypes.c_int
            return fn
    return None
