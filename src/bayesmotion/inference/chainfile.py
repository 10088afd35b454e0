"""The chain's HDF5 file: never half-written, safe to read while a run writes it, and checked
before it is trusted.

One concept: the file of one chain, as emcee's HDF5 layout: how it is written (a copy that
replaces it, in batches), opened (waiting for another process's lock) and checked.

A run killed at any moment (``kill -9``, an out-of-memory kill, a power cut after the last
commit reached the disk) leaves a complete chain file: the file as of its last commit, which a
resumed run continues bit for bit. HDF5 updates a file in place, and a process killed inside
such an update leaves it unreadable (``OSError: ... len not positive after adjustment for
EOA``) with every step it held; so :class:`ChainFile` never writes the chain's file in place.
Every write (emcee's ``reset`` and ``grow``, the saved steps, this package's attributes:
:func:`write_h5`) goes to a copy beside the file, which is flushed to disk and then replaces the
file in one ``os.replace`` (:func:`bayesmotion.data.files.atomic_path`; a killed write's copy
is removed by a later one).

Copying the file costs time (a commit of the built-in handshakes' default chain, 2,000 steps
of 54 walkers in 26 coordinates, 25 MB, takes 35 ms on this project's CPU), so saved steps are
committed in batches: a step is kept in memory until :data:`COMMIT_RATIO` times the last
commit's duration has passed since that commit ended, which holds the copying to about
``1 / COMMIT_RATIO`` of the run's time and loses at most that window's steps to a kill; where
one step takes longer than the window (on a CPU at the built-in size) every step is committed
as it is taken. At 0.068 s per step (that chain's step on one H200) saving costs 6.1% of the
run, against 8.1% for emcee's in-place writes, with at most 12 steps held
(``benchmarks/results/chain_file.json``). A read through the backend (``get_chain``,
``get_last_sample``, ...) commits first, and so do the package's runners when they stop, also
on an error or ``KeyboardInterrupt``. Another process reading the file sees the committed
steps.

Readers and the writer never wait for each other: the writer reads the file only to copy it,
under HDF5's shared lock, as readers do. Both wait for another process that holds the file
itself open for writing (a script of the user's), instead of failing with ``BlockingIOError``
or, as emcee's own ``initialized`` does, taking the locked file for an empty one that a resumed
run would reset. Every open of the chain's file in the package waits this way
(:func:`open_h5`). One run writes a file at a time: a commit that finds steps it did not write
is refused, naming the file. The copy is made in the file's folder, which must be writable and
have room for it; a symbolic link to the file stays a link, and the file it names is replaced.

A damaged file is refused, never reset or shrunk, so no saved step is lost:

* every open of a :class:`ChainFile` checks its group's layout (:func:`check_layout`): the
  attributes ``nwalkers``, ``ndim``, ``iteration``, ``has_blobs`` present and integers, the
  datasets ``chain`` (L, W, D), ``log_prob`` (L, W) and ``accepted`` (W,) present with the
  shapes the attributes give, ``0 <= iteration <= L``, and emcee's random state stored once a
  step is (emcee's own backend takes a negative stored iteration for an empty run and resets
  the file);
* :func:`check_chain_file` (run before a run resumes) and every read of the chain or the
  log-densities also refuse a non-finite value (NaN, inf) in the stored steps, naming the first
  such step;
* growing the datasets for more steps never shrinks them (emcee resizes them to
  ``iteration + new steps``, which cuts rows off a file a killed longer run had grown);
* every h5py error becomes a :class:`~bayesmotion.errors.BayesmotionError` naming the file.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time

import emcee
import numpy as np

from bayesmotion.data.files import atomic_path
from bayesmotion.errors import BayesmotionError

# how long a run waits for another process's lock on its file before stopping with an error
LOCK_WAIT_S = 120.0
#: the attribute where the independence move's adaptation length is stored with its chain
ADAPT_ATTR = "bayesmotion_adapt_steps"
#: the attribute where the steps at which the independence proposal is refitted are stored
REFIT_ATTR = "bayesmotion_refit_steps"
#: the groups bayesmotion's runs write: the joint chain (or the factorised upper one) and gamma's
GROUPS = ("mcmc", "gamma")
#: saved steps wait in memory until this many times the last commit's duration has passed
#: since it ended (module docstring): the copying takes about 1 / COMMIT_RATIO of the run
COMMIT_RATIO = 20.0
#: steps read at once when checking stored values
CHECK_BLOCK = 2048
# what h5py raises on a damaged file: OSError (unreadable objects, truncation), KeyError (a
# missing link), ValueError / TypeError / RuntimeError (bad selections, messages, datatypes)
_H5_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError)
_AFTER = ("the file is left as it is: pass another backend path (or repair it with h5py from "
          "a copy)")


@contextlib.contextmanager
def h5_errors(path, doing: str = "read"):
    """Turn an h5py error inside the block into a BayesmotionError naming ``path``."""
    try:
        yield
    except BayesmotionError:
        raise
    except _H5_ERRORS as e:
        why = " ".join(f"{type(e).__name__}: {e}".split())
        raise BayesmotionError(f"{path}: cannot {doing} this HDF5 chain file ({why}); "
                               f"{_AFTER}") from e


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
            why = " ".join(str(e).split())
            raise BayesmotionError(f"{path}: cannot open as an HDF5 chain file ({why}); pass "
                                   f"another backend path") from e


@contextlib.contextmanager
def write_h5(path):
    """The HDF5 file at ``path`` opened for writing, as a copy that replaces the file in one
    ``os.replace`` when the block ends without an error (module docstring); on an error, or a
    kill, the file is left as it was. A new file is created the same way.

    Raises:
        BayesmotionError: the existing file is not an HDF5 file h5py can open (named).
    """
    import h5py

    path = os.path.realpath(str(path))  # a symbolic link stays; the file it names is replaced
    with atomic_path(path) as tmp:
        exists = os.path.exists(path)
        if exists:
            with open_h5(path, "r"):  # waits while another process writes the file itself
                shutil.copyfile(path, tmp)
        try:
            f = h5py.File(str(tmp), "r+" if exists else "w")
        except OSError as e:
            why = " ".join(str(e).split())
            raise BayesmotionError(f"{path}: cannot open as an HDF5 chain file ({why}); pass "
                                   f"another backend path") from e
        try:
            yield f
            f.flush()
        finally:
            f.close()
        with open(tmp, "rb") as fd:  # on disk before it replaces the file
            os.fsync(fd.fileno())
    with contextlib.suppress(OSError):  # the replacement on disk too (not every system can)
        fd = os.open(os.path.dirname(path), os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


# --------------------------------------------------------------------------- checks
def _attr_int(attrs, key: str, where: str, low: int | None = None, kinds: str = "iu") -> int:
    if key not in attrs:
        raise BayesmotionError(f"{where} lacks its attribute {key!r}; {_AFTER}")
    value = np.asarray(attrs[key])
    if value.shape != () or value.dtype.kind not in kinds:
        raise BayesmotionError(f"{where}: attribute {key!r} is {value.tolist()!r}, expected an "
                               f"integer; {_AFTER}")
    value = int(value)
    if low is not None and value < low:
        raise BayesmotionError(f"{where}: attribute {key!r} is {value}, expected at least {low}; "
                               f"{_AFTER}")
    return value


def _dataset(g, key: str, where: str, kinds: str):
    import h5py

    obj = g.get(key)
    if not isinstance(obj, h5py.Dataset):
        raise BayesmotionError(f"{where} lacks its dataset {key!r}; {_AFTER}")
    if obj.dtype.kind not in kinds:
        raise BayesmotionError(f"{where}: dataset {key!r} holds {obj.dtype}, expected numbers; "
                               f"{_AFTER}")
    return obj


def check_layout(f, name: str, path) -> tuple[int, int, int]:
    """``(nwalkers, ndim, iteration)`` of group ``name`` of the open file ``f``, after checking
    that its attributes and datasets agree (module docstring); a BayesmotionError naming
    ``path`` says what does not."""
    import h5py

    where = f"{path}: chain group {name!r}"
    g = f.get(name)
    if not isinstance(g, h5py.Group):
        raise BayesmotionError(f"{where} is not a group (not a file emcee's HDF5 backend "
                               f"wrote); {_AFTER}")
    attrs = g.attrs
    W = _attr_int(attrs, "nwalkers", where, low=1)
    D = _attr_int(attrs, "ndim", where, low=1)
    it = _attr_int(attrs, "iteration", where)
    blobs = _attr_int(attrs, "has_blobs", where, kinds="iub")
    chain = _dataset(g, "chain", where, "f")
    log_prob = _dataset(g, "log_prob", where, "f")
    accepted = _dataset(g, "accepted", where, "fiu")
    L = chain.shape[0] if chain.ndim == 3 else -1
    if chain.ndim != 3 or chain.shape[1:] != (W, D):
        raise BayesmotionError(f"{where}: dataset 'chain' has shape {chain.shape}, its "
                               f"attributes say (steps, {W}, {D}); {_AFTER}")
    if log_prob.shape != (L, W):
        raise BayesmotionError(f"{where}: dataset 'log_prob' has shape {log_prob.shape}, "
                               f"expected {(L, W)} to match 'chain'; {_AFTER}")
    if accepted.shape != (W,):
        raise BayesmotionError(f"{where}: dataset 'accepted' has shape {accepted.shape}, "
                               f"expected {(W,)}; {_AFTER}")
    if it < 0:
        raise BayesmotionError(f"{where}: its stored iteration is {it}, negative (emcee would "
                               f"take the file for an empty one and reset it, losing its {L} "
                               f"stored rows); {_AFTER}")
    if it > L:
        raise BayesmotionError(f"{where}: its stored iteration {it} is past the end of its "
                               f"chain, which holds {L} steps; {_AFTER}")
    if blobs and not (isinstance(g.get("blobs"), h5py.Dataset) and g["blobs"].shape[:1] == (L,)):
        raise BayesmotionError(f"{where}: attribute 'has_blobs' is set but no dataset 'blobs' "
                               f"of {L} steps is stored; {_AFTER}")
    missing = [f"random_state_{i}" for i in range(5) if f"random_state_{i}" not in attrs]
    if it > 0 and missing:
        raise BayesmotionError(f"{where} lacks emcee's random state ({', '.join(missing)}), "
                               f"without which a resumed run cannot continue the chain; "
                               f"{_AFTER}")
    if ADAPT_ATTR in attrs:
        _attr_int(attrs, ADAPT_ATTR, where, low=0)
    if REFIT_ATTR in attrs:
        refit_attr(attrs, where)
    return W, D, it


def refit_attr(attrs, where: str) -> list[int]:
    """The stored refit steps (:data:`REFIT_ATTR`): increasing positive integers."""
    value = np.asarray(attrs[REFIT_ATTR])
    if (value.ndim != 1 or value.dtype.kind not in "iu" or np.any(value < 1)
            or np.any(np.diff(value) <= 0)):
        raise BayesmotionError(f"{where}: attribute {REFIT_ATTR!r} is {value.tolist()!r}, "
                               f"expected increasing positive integers; {_AFTER}")
    return [int(v) for v in value]


def _first_bad_step(values: np.ndarray) -> int | None:
    """Index along axis 0 of the first row holding a non-finite value, or None."""
    ok = np.isfinite(values).reshape(len(values), -1).all(axis=1)
    return None if ok.all() else int(np.argmin(ok))


def _check_accepted(accepted, iteration: int, where: str) -> np.ndarray:
    acc = np.asarray(accepted, dtype=np.float64)
    if not (np.all(np.isfinite(acc)) and np.all(acc >= 0) and np.all(acc <= iteration)):
        raise BayesmotionError(f"{where}: dataset 'accepted' holds counts outside [0, "
                               f"{iteration}] (the stored steps); {_AFTER}")
    return accepted


def check_steps(g, name: str, path, iteration: int) -> None:
    """Refuse a non-finite value in the ``iteration`` stored steps of group ``g``'s chain and
    log-densities, an acceptance count outside ``[0, iteration]`` and a random state NumPy
    cannot restore (read in blocks of :data:`CHECK_BLOCK` steps)."""
    where = f"{path}: chain group {name!r}"
    for key in ("chain", "log_prob"):
        ds = g[key]
        for start in range(0, iteration, CHECK_BLOCK):
            bad = _first_bad_step(ds[start:min(start + CHECK_BLOCK, iteration)])
            if bad is not None:
                raise BayesmotionError(f"{where}: stored step {start + bad} (of {iteration}) "
                                       f"holds a non-finite value (NaN or inf) in {key!r}, "
                                       f"which no run writes; the file is damaged and cannot "
                                       f"be resumed or read: {_AFTER}")
    _check_accepted(g["accepted"][...], iteration, where)
    if iteration > 0:
        state = tuple(g.attrs[f"random_state_{i}"] for i in range(5))
        try:
            np.random.RandomState().set_state(state)
        except (ValueError, TypeError, IndexError) as e:
            raise BayesmotionError(f"{where}: emcee's stored random state cannot be restored "
                                   f"({' '.join(str(e).split())}); {_AFTER}") from None


def check_chain_file(path, names=GROUPS) -> dict[str, int]:
    """Check every chain group of ``names`` that the file at ``path`` holds, layout
    (:func:`check_layout`) and stored values (:func:`check_steps`), before a run resumes it;
    returns group -> stored steps. Reads only; an absent file holds no group."""
    if not os.path.exists(str(path)):
        return {}
    out = {}
    with open_h5(path, "r") as f, h5_errors(path):
        for name in names:
            if name in f:
                W, D, it = check_layout(f, name, path)
                check_steps(f[name], name, path, it)
                out[name] = it
    return out


# --------------------------------------------------------------------------- the backend
class ChainFile(emcee.backends.HDFBackend):
    """emcee's HDF5 backend, whose writes replace the file whole (never half-written: a run
    killed at any moment leaves the file as of its last commit), whose saved steps are committed
    in batches (:data:`COMMIT_RATIO`, :meth:`commit`), whose every open waits for another
    process's lock (:func:`open_h5`) and checks the group's layout (:func:`check_layout`),
    whose reads refuse non-finite stored steps, and whose datasets never shrink (module
    docstring).

    Same arguments and file layout as :class:`emcee.backends.HDFBackend` (a file written by
    either reads with the other).
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._pending = []  # (step, coords, log_prob, blobs, accepted, random state) not yet
        # in the file, oldest first; step: the row the step takes in the file
        self._next = None  # the row of the next saved step, read from the file when None
        self._committed_at, self._commit_seconds = None, 0.0
        self._layout = None  # (nwalkers, ndim, has_blobs), read once after reset and grow

    def open(self, mode="r"):
        """The file opened for reading (``mode="r"``); any other mode commits the pending
        steps and opens a copy that replaces the file when the ``with`` block ends
        (:func:`write_h5`)."""
        if self.read_only and mode != "r":
            raise RuntimeError("The backend has been loaded in read-only mode. Set "
                               "`read_only = False` to make changes.")
        if mode != "r":
            self.commit()
            return self._writing()
        with h5_errors(self.filename, "open"):
            try:
                f = _waiting(lambda: super(ChainFile, self).open(mode), self.filename)
            except AttributeError as e:  # emcee reads g["chain"].dtype: a damaged layout
                raise BayesmotionError(f"{self.filename}: chain group {self.name!r} is not a "
                                       f"chain file's layout ({e}); {_AFTER}") from e
        try:
            with h5_errors(self.filename):
                if self.name in f:
                    check_layout(f, self.name, self.filename)
        except BaseException:
            f.close()
            raise
        return f

    @contextlib.contextmanager
    def _writing(self):
        """emcee's write access: a copy of the file (:func:`write_h5`), its group checked."""
        with h5_errors(self.filename, "write"), write_h5(self.filename) as f:
            if self.name in f:
                check_layout(f, self.name, self.filename)
                if not self.dtype_set and "chain" in f[self.name]:
                    self.dtype, self.dtype_set = f[self.name]["chain"].dtype, True
            yield f

    def commit(self) -> None:
        """Write the saved steps still held in memory to the file, in one replacement of the
        file (module docstring); nothing to do when none is held."""
        if not self._pending:
            return
        t0 = time.perf_counter()
        # the steps stay held until the file holds them: a failed write leaves the file as it
        # was and the steps for the next commit; an interrupted one that replaced the file
        # before it returned leaves steps the file holds, which the next commit drops
        with self._writing() as f:
            g = f[self.name]
            it, first, end = (int(g.attrs["iteration"]), self._pending[0][0],
                              self._pending[-1][0] + 1)
            if it not in (first, end):  # end: an interrupted commit wrote them all
                raise BayesmotionError(
                    f"{self.filename}: chain group {self.name!r} holds {it} steps where this "
                    f"run saved {first}: another run or process wrote the file meanwhile "
                    f"(one run per file); the file is left as it is, without this run's "
                    f"steps from {first} on")
            rows = self._pending if it == first else []
            if rows:
                n = len(rows)
                g["chain"][it:it + n] = np.stack([r[1] for r in rows])
                g["log_prob"][it:it + n] = np.stack([r[2] for r in rows])
                if rows[0][3] is not None:
                    g["blobs"][it:it + n] = np.stack([r[3] for r in rows])
                g["accepted"][:] += np.sum([r[4] for r in rows], axis=0)
                for i, v in enumerate(rows[-1][5]):
                    g.attrs[f"random_state_{i}"] = v
                g.attrs["iteration"] = it + n
        self._pending = []
        self._committed_at = time.perf_counter()
        self._commit_seconds = self._committed_at - t0

    def save_step(self, state, accepted):
        """Keep the step in memory and commit when due (:data:`COMMIT_RATIO`)."""
        self._check_step(state, accepted)
        if self._next is None:
            self._next = self.iteration
        self._pending.append((
            self._next, np.array(state.coords, dtype=self.dtype),
            np.array(state.log_prob, dtype=self.dtype),
            None if state.blobs is None else np.array(state.blobs), np.array(accepted),
            state.random_state))
        self._next += 1
        if (self._committed_at is None or time.perf_counter() - self._committed_at
                >= COMMIT_RATIO * self._commit_seconds):
            self.commit()

    @property
    def initialized(self) -> bool:
        """Whether the file holds this backend's group. Unlike emcee's, a file that is locked
        (waited for), unreadable or damaged (an error) is not taken for an empty one, which the
        caller would then reset."""
        if not os.path.exists(self.filename):
            return False
        with self.open() as f:
            return self.name in f

    def check(self) -> int:
        """Check the group's layout and stored values (:func:`check_steps`); returns the
        number of stored steps (0 for a file without the group)."""
        if not self.initialized:
            return 0
        self.commit()
        with self.open() as f, h5_errors(self.filename):
            it = int(f[self.name].attrs["iteration"])
            check_steps(f[self.name], self.name, self.filename, it)
        return it

    def get_value(self, name, flat=False, thin=1, discard=0):
        """emcee's ``get_value``, refusing a non-finite stored chain or log-density value (the
        message names its step)."""
        self._has_steps()
        self.commit()
        with h5_errors(self.filename):
            v = super().get_value(name, False, thin, discard)
        if name in ("chain", "log_prob") and v is not None:
            bad = _first_bad_step(v)
            if bad is not None:
                step = discard + thin - 1 + bad * thin
                raise BayesmotionError(f"{self.filename}: chain group {self.name!r}: stored "
                                       f"step {step} holds a non-finite value (NaN or inf) in "
                                       f"{name!r}, which no run writes; the file is damaged: "
                                       f"{_AFTER}")
        if flat and v is not None:
            v = v.reshape(v.shape[0] * v.shape[1], *v.shape[2:])
        return v

    def get_last_sample(self):
        """emcee's ``get_last_sample``, naming the file when it holds no step."""
        self._has_steps()
        self.commit()
        with h5_errors(self.filename):
            return super().get_last_sample()

    def _has_steps(self) -> None:
        """Refuse reading a file without this group or with no stored step (emcee raises an
        AttributeError about ``store == True`` there)."""
        if not self.initialized or self.iteration <= 0:
            raise BayesmotionError(f"{self.filename}: chain group {self.name!r} holds no stored "
                                   f"step (the group is missing or its stored iteration is "
                                   f"0): nothing to read; run sample_posterior with this "
                                   f"backend to write steps, or pass the file a run wrote")

    def grow(self, ngrow, blobs):
        """Room for ``ngrow`` more steps, never shrinking the datasets: a killed run leaves
        them sized for all its planned steps, and emcee would resize them to
        ``iteration + ngrow``."""
        self.commit()
        with self.open() as f, h5_errors(self.filename):
            g = f[self.name]
            have = g["chain"].shape[0] - int(g.attrs["iteration"])
        with h5_errors(self.filename, "write"):
            super().grow(max(int(ngrow), have), blobs)
        self._layout = None

    def _check_step(self, state, accepted) -> None:
        """emcee's checks of a step against the group's layout, which it reads from the file
        (four opens per step); here from the layout read once after :meth:`reset` and
        :meth:`grow`, the only writes that change it."""
        if self._layout is None:
            self._layout = (*self.shape, bool(self.has_blobs()))
        W, D, blobs = self._layout
        if state.coords.shape != (W, D):
            raise ValueError(f"invalid coordinate dimensions; expected {(W, D)}")
        if state.log_prob.shape != (W,):
            raise ValueError(f"invalid log probability size; expected {W}")
        if (state.blobs is not None) != blobs:
            raise ValueError("unexpected blobs" if state.blobs is not None
                             else "expected blobs, but none were given")
        if state.blobs is not None and len(state.blobs) != W:
            raise ValueError(f"invalid blobs size; expected {W}")
        if np.shape(accepted) != (W,):
            raise ValueError(f"invalid acceptance size; expected {W}")

    def reset(self, nwalkers, ndim):
        # the steps of the run being reset go with it
        self._pending, self._layout, self._next = [], None, None
        with h5_errors(self.filename, "write"):
            super().reset(nwalkers, ndim)

    @property
    def shape(self):
        with h5_errors(self.filename):
            return super().shape

    @property
    def iteration(self):
        """Saved steps: those in the file and those still held in memory."""
        with h5_errors(self.filename):
            stored = int(super().iteration)
        return max(stored, self._pending[-1][0] + 1) if self._pending else stored

    @property
    def accepted(self):
        """Accepted proposals per walker, refused outside ``[0, iteration]``."""
        self.commit()
        with self.open() as f, h5_errors(self.filename):
            g = f[self.name]
            return _check_accepted(g["accepted"][...], int(g.attrs["iteration"]),
                                   f"{self.filename}: chain group {self.name!r}")

    @property
    def random_state(self):
        self.commit()
        with h5_errors(self.filename):
            return super().random_state

    def has_blobs(self):
        with h5_errors(self.filename):
            return super().has_blobs()


@contextlib.contextmanager
def committing(*backends):
    """Commit the pending steps of every :class:`ChainFile` among ``backends`` when the block
    ends, also when it ends by an error (``KeyboardInterrupt`` included), which then goes on
    (a commit that fails then is passed over: the first error is the one to see): a stopped
    run keeps every step it took. Other backends (emcee's in-memory one) are left alone."""
    files = [b for b in backends if isinstance(b, ChainFile)]
    try:
        yield
    except BaseException:
        for b in files:
            with contextlib.suppress(Exception):
                b.commit()
        raise
    failed = None
    for b in files:  # each file's steps, even where another's commit fails
        try:
            b.commit()
        except Exception as e:
            failed = failed or e
    if failed is not None:
        raise failed
