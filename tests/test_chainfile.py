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
    reader = hold_lock(h5, 60.0)  # a notebook holding the file open for the whole run
    try:
        with pytest.raises(BlockingIOError):  # the premise: emcee's next save would fail
            h5py.File(str(h5), "a")
        post = run(h5, 40)  # the run writes copies of the file: the reader's lock is no matter
        assert reader.poll() is None, "the reader let go before the run ended"
    finally:
        reader.kill()
        reader.wait()
    assert not waits, "the run waited for the reader"
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


DIE_WHILE_WRITING = textwrap.dedent("""
    import os, signal, sys
    import h5py
    sys.path.insert(0, sys.argv[3])
    from bayesmotion.inference import chainfile
    from tests.test_chainfile import run

    chainfile.COMMIT_RATIO = 0.0  # every step commits: the kill point is the same every time

    setattr_, writes = h5py.AttributeManager.__setitem__, [0]

    def dying(self, key, value):  # killed inside an HDF5 update, before the file is closed
        setattr_(self, key, value)
        if key == "iteration":  # the last attribute a step's write sets
            writes[0] += 1
            if writes[0] == int(sys.argv[2]):
                os.kill(os.getpid(), signal.SIGKILL)

    h5py.AttributeManager.__setitem__ = dying
    run(sys.argv[1], 60)
""")


@pytest.mark.parametrize("die_at", [1, 2, 4])
def test_a_run_killed_inside_a_write_leaves_a_file_that_resumes(tmp_path, die_at):
    """Killed while HDF5 updates the file (the chain's rows, acceptance counts and random state
    written, the file not closed), emcee's in-place writes leave a file whose acceptance counts
    disagree with its iteration; here the file is as of the last commit (absent when the kill
    came while the file was being created)."""
    h5 = tmp_path / "chain.h5"
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, "-c", DIE_WHILE_WRITING, str(h5), str(die_at), root],
                          capture_output=True, text=True)
    assert proc.returncode == -9, proc.stderr[-2000:]  # killed where it meant to be
    kept = chainfile.check_chain_file(h5).get("mcmc")  # complete and consistent
    # the first write creates the file; then each step's commit adds one
    assert kept == (None if die_at == 1 else die_at - 2)
    resumed = run(h5, 60)
    whole = run(tmp_path / "whole.h5", 60)
    np.testing.assert_array_equal(resumed.chains, whole.chains)  # bit for bit


class Interrupting(GaussianTarget):
    """Raises KeyboardInterrupt at its ``at``-th batch of log-densities."""

    def __init__(self, at):
        super().__init__(MU, SD)
        batch, self.calls = self.logp_batch, [0]

        def counted(xs):
            self.calls[0] += 1
            if self.calls[0] == at:
                raise KeyboardInterrupt
            return batch(xs)

        self.logp_batch = counted


def test_an_interrupted_run_keeps_every_step_it_took(tmp_path, monkeypatch):
    monkeypatch.setattr(chainfile, "COMMIT_RATIO", 1e12)  # only the first step commits itself
    saved, save = [], ChainFile.save_step
    monkeypatch.setattr(ChainFile, "save_step", lambda be, *a: (saved.append(1), save(be, *a)))
    h5 = tmp_path / "chain.h5"
    with pytest.raises(KeyboardInterrupt), warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        run_emcee(Interrupting(at=30), MU, n_walkers=8, n_steps=100, burn=0, thin=1, seed=3,
                  backend=h5, progress=False, init="ball", ball=1e-2, moves=None)
    kept = emcee.backends.HDFBackend(str(h5), read_only=True).get_chain()
    assert len(saved) > 1 and len(kept) == len(saved)  # the steps held in memory are in
    np.testing.assert_array_equal(kept, run(tmp_path / "whole.h5", 100).chains[:, :len(kept)]
                                  .transpose(1, 0, 2))


def _held(tmp_path, monkeypatch, n=3, name="chain.h5", accepted=(True, True, True, True)):
    """A ChainFile that has saved ``n`` steps of 4 walkers in 2 coordinates, of which only the
    first is committed, and the steps."""
    monkeypatch.setattr(chainfile, "COMMIT_RATIO", 1e12)
    be = ChainFile(str(tmp_path / name))
    be.reset(4, 2)
    be.grow(n, None)
    rng = np.random.default_rng(2)
    rows = [emcee.State(rng.normal(size=(4, 2)), log_prob=rng.normal(size=4),
                        random_state=np.random.RandomState(i).get_state()) for i in range(n)]
    for r in rows:
        be.save_step(r, np.array(accepted))
    return be, rows


def test_saved_steps_are_committed_in_batches_that_reads_see(tmp_path, monkeypatch):
    be, rows = _held(tmp_path, monkeypatch, n=5, accepted=(True, False, True, True))
    on_disk = emcee.backends.HDFBackend(be.filename, read_only=True)
    assert on_disk.iteration == 1 and be.iteration == 5  # the first committed, four held
    np.testing.assert_array_equal(be.get_chain(), np.stack([r.coords for r in rows]))  # commits
    assert on_disk.iteration == 5
    np.testing.assert_array_equal(on_disk.get_log_prob(), np.stack([r.log_prob for r in rows]))
    np.testing.assert_array_equal(on_disk.accepted, [5, 0, 5, 5])
    state = np.random.RandomState()
    state.set_state(tuple(on_disk.random_state))
    np.testing.assert_array_equal(state.get_state()[1], rows[-1].random_state[1])


def test_a_failed_commit_loses_nothing(tmp_path, monkeypatch):
    be, rows = _held(tmp_path, monkeypatch)
    copy = chainfile.shutil.copyfile

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(chainfile.shutil, "copyfile", full_disk)
    with pytest.raises(BayesmotionError, match="cannot write this HDF5 chain file .*No space"):
        be.commit()
    assert emcee.backends.HDFBackend(be.filename, read_only=True).iteration == 1  # as it was
    assert [p.name for p in tmp_path.iterdir()] == ["chain.h5"]  # no copy left behind
    monkeypatch.setattr(chainfile.shutil, "copyfile", copy)
    be.commit()  # the held steps, once there is room
    np.testing.assert_array_equal(emcee.backends.HDFBackend(be.filename, read_only=True)
                                  .get_chain(), np.stack([r.coords for r in rows]))


def test_a_commit_interrupted_after_the_file_was_replaced_is_not_written_twice(tmp_path,
                                                                               monkeypatch):
    be, rows = _held(tmp_path, monkeypatch)
    fsync, calls = chainfile.os.fsync, []

    def interrupted(fd):  # the copy's fsync, then the folder's, after the file was replaced
        calls.append(fd)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return fsync(fd)

    monkeypatch.setattr(chainfile.os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        be.commit()
    monkeypatch.setattr(chainfile.os, "fsync", fsync)
    assert be.iteration == 3
    be.commit()  # what the runner does as the interrupt goes on
    on_disk = emcee.backends.HDFBackend(be.filename, read_only=True)
    assert on_disk.iteration == 3
    np.testing.assert_array_equal(on_disk.accepted, [3, 3, 3, 3])
    np.testing.assert_array_equal(on_disk.get_chain(), np.stack([r.coords for r in rows]))


def test_a_file_another_run_wrote_meanwhile_is_refused(tmp_path, monkeypatch):
    be, _ = _held(tmp_path, monkeypatch)
    other = ChainFile(be.filename)
    other.save_step(emcee.State(np.zeros((4, 2)), log_prob=np.zeros(4),
                                random_state=np.random.RandomState(9).get_state()),
                    np.ones(4, dtype=bool))  # its first step commits: the file holds 2
    with pytest.raises(BayesmotionError, match="holds 2 steps where this run saved 1: another"):
        be.commit()
    assert emcee.backends.HDFBackend(be.filename, read_only=True).iteration == 2


def test_a_chain_file_behind_a_symbolic_link_is_written_through_it(tmp_path, monkeypatch):
    (tmp_path / "runs").mkdir()
    link = tmp_path / "chain.h5"
    link.symlink_to(tmp_path / "runs" / "chain.h5")
    be, rows = _held(tmp_path, monkeypatch)  # ChainFile("tmp/chain.h5"), the link
    be.commit()
    assert link.is_symlink()
    target = emcee.backends.HDFBackend(str(tmp_path / "runs" / "chain.h5"), read_only=True)
    np.testing.assert_array_equal(target.get_chain(), np.stack([r.coords for r in rows]))


def test_committing_saves_every_file_and_lets_the_first_error_go_on(tmp_path, monkeypatch):
    good, rows = _held(tmp_path, monkeypatch, name="good.h5")
    bad, _ = _held(tmp_path, monkeypatch, name="bad.h5")
    commit = ChainFile.commit

    def failing(be):
        if be is bad:
            raise BayesmotionError("disk full")
        return commit(be)

    monkeypatch.setattr(ChainFile, "commit", failing)
    with pytest.raises(KeyboardInterrupt):  # the error that stopped the run, not the commit's
        with chainfile.committing(bad, good):
            raise KeyboardInterrupt
    assert emcee.backends.HDFBackend(good.filename, read_only=True).iteration == 3
    good2, _ = _held(tmp_path, monkeypatch, name="good2.h5")
    with pytest.raises(BayesmotionError, match="disk full"), chainfile.committing(bad, good2):
        pass
    assert emcee.backends.HDFBackend(good2.filename, read_only=True).iteration == 3
