"""A chain's HDF5 file read by another process while a run writes or resumes it."""

import os
import subprocess
import sys
import textwrap
import warnings

import emcee
import h5py
import numpy as np
import pytest

from bayesmotion.errors import BayesmotionError
from bayesmotion.inference import chainfile
from bayesmotion.inference.chainfile import ChainFile, open_h5
from bayesmotion.inference.emcee_runner import run_emcee
from bayesmotion.inference.posterior import ChainTooShortWarning

from .test_posterior import GaussianTarget

LOCKER = textwrap.dedent("""
    import sys, time, h5py
    with h5py.File(sys.argv[1], sys.argv[3]):
        print("locked", flush=True)
        time.sleep(float(sys.argv[2]))
""")
MU, SD = np.array([1.0, -2.0]), np.array([0.5, 2.0])


@pytest.fixture(autouse=True)
def hdf5_locking(monkeypatch):
    """HDF5's file locking on, as by default (a test elsewhere may turn it off)."""
    monkeypatch.delenv("HDF5_USE_FILE_LOCKING", raising=False)


def hold_lock(path, seconds: float, mode: str = "r") -> subprocess.Popen:
    """Another process holding ``path`` open (``mode="r"``: a notebook watching the chain;
    ``"a"``: a script writing to it); returns once it holds the lock."""
    env = {k: v for k, v in os.environ.items() if k != "HDF5_USE_FILE_LOCKING"}
    proc = subprocess.Popen([sys.executable, "-c", LOCKER, str(path), str(seconds), mode],
                            stdout=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline().strip()
    proc.stdout.close()
    assert line == "locked"
    return proc


def run(h5, n_steps):
    """A short chain of a known target into ``h5`` (a look, not a result: too short a chain
    for its autocorrelation time, which the warning says)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        return run_emcee(GaussianTarget(MU, SD), MU, n_walkers=8, n_steps=n_steps, burn=0,
                          thin=1, seed=3, backend=h5, progress=False, init="ball", ball=1e-2,
                          moves=None)


def count_waits(monkeypatch) -> list:
    """Record the lock waits of :func:`open_h5` (it still sleeps)."""
    waits, sleep = [], chainfile.time.sleep
    monkeypatch.setattr(chainfile.time, "sleep", lambda s: (waits.append(s), sleep(s)))
    return waits


def test_a_run_resumes_a_file_another_process_is_reading(tmp_path, monkeypatch):
    h5 = tmp_path / "chain.h5"
    run(h5, 20)
    before = emcee.backends.HDFBackend(str(h5), read_only=True).get_chain()
    waits = count_waits(monkeypatch)
    reader = hold_lock(h5, 2.0)
    try:
        with pytest.raises(BlockingIOError):  # the premise: emcee's next save would fail
            h5py.File(str(h5), "a")
        post = run(h5, 40)  # waits for the reader instead
    finally:
        reader.wait()
    assert waits, "the run never met the reader's lock"
    after = emcee.backends.HDFBackend(str(h5), read_only=True).get_chain()
    assert after.shape == (40, 8, 2) and post.chains.shape == (8, 40, 2)
    np.testing.assert_array_equal(after[:20], before)  # nothing saved was lost


def test_a_file_another_process_writes_is_not_taken_for_an_empty_one(tmp_path, monkeypatch):
    h5 = tmp_path / "chain.h5"
    run(h5, 10)
    waits = count_waits(monkeypatch)
    writer = hold_lock(h5, 1.5, mode="a")
    try:
        # emcee's check reads a file it cannot open as empty: its run would reset it
        assert not emcee.backends.HDFBackend(str(h5)).initialized
        assert ChainFile(str(h5)).initialized  # waits for the writer
    finally:
        writer.wait()
    assert waits
    assert emcee.backends.HDFBackend(str(h5), read_only=True).iteration == 10


def test_a_lock_held_too_long_is_a_clear_error(tmp_path):
    h5 = tmp_path / "chain.h5"
    run(h5, 5)
    reader = hold_lock(h5, 3.0)
    try:
        with pytest.raises(BayesmotionError, match="held this HDF5 file locked"):
            open_h5(h5, "a", wait_s=0.3)
    finally:
        reader.kill()
        reader.wait()
    with open_h5(h5, "a", wait_s=0.3) as f:  # free again
        assert f["mcmc"].attrs["iteration"] == 5


def test_a_file_that_is_not_hdf5_is_named_and_left_alone(tmp_path):
    path = tmp_path / "notes.h5"
    path.write_text("my notes, not a chain\n")
    with pytest.raises(BayesmotionError, match="cannot open as an HDF5 chain file"):
        run(path, 5)
    assert path.read_text() == "my notes, not a chain\n"
    assert not ChainFile(str(tmp_path / "absent.h5")).initialized


def test_chainfile_reads_what_emcee_wrote(tmp_path):
    h5 = tmp_path / "chain.h5"
    run(h5, 6)
    ours, theirs = ChainFile(str(h5), read_only=True), emcee.backends.HDFBackend(str(h5),
                                                                               read_only=True)
    assert ours.initialized and ours.iteration == theirs.iteration == 6
    np.testing.assert_array_equal(ours.get_chain(), theirs.get_chain())
    with pytest.raises(RuntimeError, match="read-only"):
        ours.open("a")
