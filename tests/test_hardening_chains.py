"""Damaged chain files: every corruption is refused with a BayesmotionError naming the file,
before anything is written (the file's bytes are unchanged), and a resumed file never shrinks.

The files are written by the runner itself (a Gaussian target, as in test_chainfile.py) and then
damaged the way a crash, a disk or a hand edit would: attributes set out of range or removed,
datasets deleted, reshaped or resized, bytes of stored values flipped to NaN / inf in place,
the HDF5 header flipped, the file truncated.
"""

import contextlib
import io
import shutil
import time
import warnings

import emcee
import h5py
import numpy as np
import pytest

import bayesmotion as bm
from bayesmotion.app.cli import main
from bayesmotion.errors import BayesmotionError
from bayesmotion.inference.chainfile import (
    ADAPT_ATTR,
    REFIT_ATTR,
    ChainFile,
    check_chain_file,
)
from bayesmotion.inference.posterior import ChainTooShortWarning

from .test_chainfile import run

STEPS, W, D = 20, 8, 2


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A complete 20-step chain of 8 walkers in 2 dimensions, written by run_emcee."""
    path = tmp_path_factory.mktemp("good") / "chain.h5"
    run(path, STEPS)
    return path


def raw_offset(path, dataset: str, index: tuple) -> int:
    """Byte offset in the file of element ``index`` of a chunked, uncompressed dataset."""
    with h5py.File(path, "r") as f:
        ds = f[dataset]
        assert ds.compression is None
        start = tuple(i - i % c for i, c in zip(index, ds.chunks, strict=True))
        info = ds.id.get_chunk_info_by_coord(start)
        local = np.ravel_multi_index(tuple(i - s for i, s in zip(index, start, strict=True)),
                                     ds.chunks)
        return info.byte_offset + int(local) * ds.dtype.itemsize


def poke(path, offset: int, data: bytes) -> None:
    with open(path, "r+b") as f:
        f.seek(offset)
        f.write(data)


NAN = np.array([np.nan]).tobytes()
POS_INF = np.array([np.inf]).tobytes()
NEG_INF = np.array([-np.inf]).tobytes()


def flip_exponent(path, dataset, index):
    """Set every exponent bit of one stored float64: the value becomes NaN or inf."""
    off = raw_offset(path, dataset, index)
    with open(path, "r+b") as f:
        f.seek(off + 6)
        hi = f.read(2)
        f.seek(off + 6)
        f.write(bytes([hi[0] | 0xF0, hi[1] | 0x7F]))


def with_group(edit):
    def apply(path):
        with h5py.File(path, "a") as f:
            edit(f["mcmc"])
    return apply


def set_attr(key, value):
    return with_group(lambda g: g.attrs.__setitem__(key, value))


def del_attr(key):
    return with_group(lambda g: g.attrs.__delitem__(key))


def del_dataset(key):
    return with_group(lambda g: g.__delitem__(key))


def replace_dataset(key, data, **kw):
    def edit(g):
        del g[key]
        g.create_dataset(key, data=data, **kw)
    return with_group(edit)


def resize(*keys, n):
    def edit(g):
        for k in keys:
            g[k].resize(n, axis=0)
    return with_group(edit)


def group_to_dataset(path):
    with h5py.File(path, "a") as f:
        del f["mcmc"]
        f["mcmc"] = np.zeros(3)


def truncate(size_of):
    def apply(path):
        with open(path, "r+b") as f:
            f.truncate(size_of(path.stat().st_size))
    return apply


def xor_byte(offset):
    def apply(path):
        with open(path, "r+b") as f:
            f.seek(offset)
            b = f.read(1)
            f.seek(offset)
            f.write(bytes([b[0] ^ 0xFF]))
    return apply


CORRUPTIONS = {
    # (damage, words the message must hold)
    "iteration -1": (set_attr("iteration", -1), "negative"),
    "iteration past the end": (set_attr("iteration", STEPS + 5), "past the end"),
    "iteration a float": (set_attr("iteration", 2.5), "expected an integer"),
    "iteration a string": (set_attr("iteration", "twenty"), "expected an integer"),
    "iteration an array": (set_attr("iteration", np.arange(3)), "expected an integer"),
    "iteration removed": (del_attr("iteration"), "attribute 'iteration'"),
    "nwalkers mismatch": (set_attr("nwalkers", W + 2), "shape"),
    "ndim mismatch": (set_attr("ndim", D + 1), "shape"),
    "ndim zero": (set_attr("ndim", 0), "at least 1"),
    "nwalkers removed": (del_attr("nwalkers"), "attribute 'nwalkers'"),
    "has_blobs removed": (del_attr("has_blobs"), "attribute 'has_blobs'"),
    "has_blobs without blobs": (set_attr("has_blobs", True), "blobs"),
    "chain deleted": (del_dataset("chain"), "dataset 'chain'"),
    "log_prob deleted": (del_dataset("log_prob"), "dataset 'log_prob'"),
    "accepted deleted": (del_dataset("accepted"), "dataset 'accepted'"),
    "group is a dataset": (group_to_dataset, "not a group"),
    "chain of another shape": (replace_dataset("chain", np.zeros((STEPS, W, D + 1)),
                                               maxshape=(None, W, D + 1)), "'chain' has shape"),
    "chain of integers": (replace_dataset("chain", np.zeros((STEPS, W, D), dtype=np.int64)),
                          "expected numbers"),
    "log_prob shorter than chain": (resize("log_prob", n=STEPS - 5), "'log_prob' has shape"),
    "datasets shrunk below iteration": (resize("chain", "log_prob", n=STEPS - 5),
                                        "past the end"),
    "accepted of another shape": (replace_dataset("accepted", np.zeros(W + 1)),
                                  "'accepted' has shape"),
    "accepted negative": (replace_dataset("accepted", -np.ones(W)), "'accepted'"),
    "accepted NaN": (replace_dataset("accepted", np.full(W, np.nan)), "'accepted'"),
    "random state removed": (del_attr("random_state_1"), "random state"),
    "random state garbage": (set_attr("random_state_1", np.arange(3)), "random state"),
    "adaptation length negative": (set_attr(ADAPT_ATTR, -4), ADAPT_ATTR),
    "refit steps decreasing": (set_attr(REFIT_ATTR, np.array([400, 300])), REFIT_ATTR),
    "refit steps not integers": (set_attr(REFIT_ATTR, np.array([400.5])), REFIT_ATTR),
    "chain bit flip to NaN": (lambda p: flip_exponent(p, "mcmc/chain", (7, 5, 1)), "step 7"),
    "log_prob bit flip to NaN": (lambda p: flip_exponent(p, "mcmc/log_prob", (12, 3)),
                                 "step 12"),
    "log_prob overwritten with +inf": (
        lambda p: poke(p, raw_offset(p, "mcmc/log_prob", (0, 0)), POS_INF), "step 0"),
    "chain overwritten with -inf": (
        lambda p: poke(p, raw_offset(p, "mcmc/chain", (19, 0, 0)), NEG_INF), "step 19"),
    "last step NaN": (lambda p: poke(p, raw_offset(p, "mcmc/chain", (19, 7, 1)), NAN),
                      "step 19"),
    "header signature flipped": (xor_byte(0), "cannot open"),
    "superblock version flipped": (xor_byte(8), "cannot open"),
    "truncated to half": (truncate(lambda n: n // 2), "cannot open"),
    "truncated to its header": (truncate(lambda n: 96), "cannot open"),
    "emptied": (truncate(lambda n: 0), "cannot open"),
}


def damaged(good, tmp_path, name):
    path = tmp_path / "chain.h5"
    shutil.copyfile(good, path)
    damage, words = CORRUPTIONS[name]
    damage(path)
    return path, words


def test_there_are_at_least_25_corruptions():
    assert len(CORRUPTIONS) >= 25


@pytest.mark.parametrize("name", sorted(CORRUPTIONS))
def test_a_damaged_file_is_refused_and_left_untouched(good, tmp_path, name):
    path, words = damaged(good, tmp_path, name)
    before = path.read_bytes()
    with pytest.raises(BayesmotionError) as info:
        check_chain_file(path)
    message = str(info.value)
    assert str(path) in message and words in message, message
    assert "\n" not in message
    with pytest.raises(BayesmotionError) as info:  # a resumed run: refused before any write
        run(path, STEPS + 10)
    assert str(path) in str(info.value)
    assert path.read_bytes() == before, "a refused resume changed the file"


@pytest.mark.parametrize("name", sorted(CORRUPTIONS))
def test_reading_a_damaged_file_never_raises_a_raw_error(good, tmp_path, name):
    """Reading with ChainFile gives the stored steps or a BayesmotionError naming the file; a
    value it returns is never NaN or inf."""
    path, _ = damaged(good, tmp_path, name)
    be = ChainFile(str(path), read_only=True)
    for read in (lambda: be.get_chain(), lambda: be.get_log_prob(flat=True),
                 lambda: be.get_last_sample().coords, lambda: be.accepted):
        try:
            values = read()
        except BayesmotionError as e:
            assert str(path) in str(e)
        else:
            assert np.all(np.isfinite(values))


def test_iteration_minus_one_would_make_emcee_reset_the_file(good, tmp_path):
    """The premise: emcee's own backend reads the stored iteration -1 as 'nothing saved', and a
    run that sees no saved step starts the file anew, deleting the 20 saved steps."""
    path, _ = damaged(good, tmp_path, "iteration -1")
    assert emcee.backends.HDFBackend(str(path), read_only=True).iteration == -1
    with h5py.File(path, "r") as f:  # the steps are still there
        np.testing.assert_array_equal(f["mcmc/chain"][:], h5py.File(good, "r")["mcmc/chain"][:])


def test_a_damaged_gamma_group_is_refused_before_the_upper_one_is_touched(good, tmp_path):
    """The factorised layout: both groups are checked before either is reset or resumed."""
    path = tmp_path / "chain.h5"
    shutil.copyfile(good, path)
    with h5py.File(path, "a") as f:
        f.copy("mcmc", "gamma")
        # nothing saved in the first group: a run resets it (a write) before it reads gamma's
        f["mcmc"].attrs["iteration"] = 0
        f["mcmc/accepted"][:] = 0
        f["gamma"].attrs["iteration"] = -1
    before = path.read_bytes()
    with pytest.raises(BayesmotionError, match="chain group 'gamma'.*negative"):
        check_chain_file(path)
    with pytest.raises(BayesmotionError, match="chain group 'gamma'.*negative"):
        run(path, STEPS)
    assert path.read_bytes() == before


def test_resuming_never_shrinks_the_datasets_and_continues_bit_for_bit(tmp_path):
    """A run killed after 10 of 40 planned steps leaves datasets of 40 rows; resuming it for 20
    steps must not cut them to 20 (emcee's grow resizes to iteration + new steps), and the
    resumed chain is the uninterrupted one."""
    whole = tmp_path / "whole.h5"
    run(whole, STEPS)
    path = tmp_path / "chain.h5"
    run(path, 10)
    with h5py.File(path, "a") as f:  # as the killed 40-step run left it
        for k in ("chain", "log_prob"):
            f["mcmc"][k].resize(40, axis=0)
    run(path, STEPS)
    with h5py.File(path, "r") as f, h5py.File(whole, "r") as g:
        assert f["mcmc/chain"].shape[0] == 40 and f["mcmc"].attrs["iteration"] == STEPS
        np.testing.assert_array_equal(f["mcmc/chain"][:STEPS], g["mcmc/chain"][:])
        np.testing.assert_array_equal(f["mcmc/log_prob"][:STEPS], g["mcmc/log_prob"][:])
    assert check_chain_file(path) == {"mcmc": STEPS}
    np.testing.assert_array_equal(ChainFile(str(path), read_only=True).get_chain(),
                                  emcee.backends.HDFBackend(str(whole), read_only=True)
                                  .get_chain())


def test_a_valid_file_passes_and_reports_its_steps(good):
    assert check_chain_file(good) == {"mcmc": STEPS}
    assert ChainFile(str(good), read_only=True).check() == STEPS
    assert check_chain_file(good.parent / "absent.h5") == {}


# --------------------------------------------------------------------------- the public paths
@pytest.fixture(scope="module")
def model_chain(tiny_model, tmp_path_factory):
    """A 6-step chain file of the tiny model, written by sample_posterior, and the model file."""
    folder = tmp_path_factory.mktemp("model_chain")
    model = folder / "m.npz"
    tiny_model.save(model)
    h5 = folder / "chain.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        bm.sample_posterior(tiny_model, n_steps=6, backend=h5, progress=False, burn=1, thin=1,
                            independence=False)
    return model, h5


SAMPLE_CASES = ["iteration -1", "iteration past the end", "chain bit flip to NaN",
                "log_prob deleted", "truncated to half"]


def _damaged_copy(h5, tmp_path, name):
    """A copy of the chain file with corruption ``name`` applied (a NaN inside the stored steps
    for the bit flip, so the refusal cannot come from the random offset missing them)."""
    path = tmp_path / "chain.h5"
    shutil.copyfile(h5, path)
    damage, _ = CORRUPTIONS[name]
    if name == "chain bit flip to NaN":
        damage = lambda p: flip_exponent(p, "mcmc/chain", (3, 5, 1))  # noqa: E731
    damage(path)
    return path


@pytest.mark.parametrize("name", SAMPLE_CASES)
def test_sample_posterior_refuses_a_damaged_backend_before_any_work(model_chain, tiny_model,
                                                                    tmp_path, monkeypatch,
                                                                    name):
    _, h5 = model_chain
    path = _damaged_copy(h5, tmp_path, name)
    before = path.read_bytes()

    def no_target(*a, **k):
        raise AssertionError("the sampler was set up before the backend was checked")

    monkeypatch.setattr("bayesmotion.inference.sample.Target", no_target)
    with pytest.raises(BayesmotionError, match=str(path).replace(".", r"\.")):
        bm.sample_posterior(tiny_model, n_steps=12, backend=path, progress=False, burn=1,
                            thin=1, independence=False)
    assert path.read_bytes() == before


@pytest.mark.parametrize("name", SAMPLE_CASES)
def test_cli_sample_refuses_a_damaged_backend_with_one_line(model_chain, tmp_path, name):
    model, h5 = model_chain
    path = _damaged_copy(h5, tmp_path, name)
    before = sorted(p.name for p in tmp_path.iterdir()), path.read_bytes()
    err = io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stderr(err):
        code = main(["sample", str(model), "--out", str(tmp_path / "p.nc"), "--steps", "12",
                     "--backend", str(path), "--no-independence"])
    seconds = time.perf_counter() - t0
    lines = err.getvalue().strip().splitlines()
    assert code == 2 and len(lines) == 2, lines
    assert lines[0].startswith("error: ") and str(path) in lines[0]
    assert lines[1].startswith("hint: ")
    assert seconds < 5, f"took {seconds:.1f} s"
    assert (sorted(p.name for p in tmp_path.iterdir()), path.read_bytes()) == before


# --------------------------------------------------------------------------- property
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

SHAPES = {"chain": (STEPS, W, D), "log_prob": (STEPS, W), "accepted": (W,)}
ATTRS = ("nwalkers", "ndim", "iteration", "has_blobs")
VALUES = ("nan", "inf", "huge", "negative", "random bytes")


@st.composite
def corruptions(draw):
    """(where, index, kind, value): one stored element of a dataset (an index within its
    shape) or one integer attribute, replaced by NaN, +-inf, a huge or a negative number, or
    random bytes (a dataset element's 8 raw bytes; an attribute's value as a byte string)."""
    where = draw(st.sampled_from(sorted(SHAPES) + list(ATTRS)))
    kind = draw(st.sampled_from(VALUES))
    index = tuple(draw(st.integers(0, n - 1)) for n in SHAPES.get(where, ()))
    if kind == "nan":
        value = np.nan
    elif kind == "inf":
        value = draw(st.sampled_from([np.inf, -np.inf]))
    elif kind == "huge":
        value = (draw(st.floats(1e200, 1.7976931348623157e308)) if where in SHAPES
                 else draw(st.integers(2**31, 2**63 - 1)))
    elif kind == "negative":
        value = (draw(st.floats(-1e300, -1e-300)) if where in SHAPES
                 else draw(st.integers(-(2**63), -1)))
    else:
        value = draw(st.binary(min_size=8 if where in SHAPES else 1, max_size=8))
    return where, index, kind, value


def corrupt(path, where, index, kind, value) -> None:
    if where in SHAPES and kind == "random bytes":
        with h5py.File(path, "r") as f:
            ds = f["mcmc"][where]
            contiguous = ds.chunks is None
            start = ds.id.get_offset() if contiguous else None
        off = (start + int(np.ravel_multi_index(index, SHAPES[where])) * 8 if contiguous
               else raw_offset(path, f"mcmc/{where}", index))
        poke(path, off, value)
        return
    with h5py.File(path, "a") as f:
        g = f["mcmc"]
        if where in SHAPES:
            g[where][index] = value
        else:
            g.attrs[where] = np.bytes_(value) if kind == "random bytes" else value


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(corruptions())
def test_any_corruption_is_read_finite_or_refused_naming_the_file(good, tmp_path, damage):
    """Opening and reading a corrupted chain file with ChainFile (and checking it as a resumed
    run does) returns finite stored steps, a stored iteration within the datasets, or raises a
    BayesmotionError naming the file; never another exception."""
    path = tmp_path / "chain.h5"
    shutil.copyfile(good, path)
    corrupt(path, *damage)
    be = ChainFile(str(path), read_only=True)
    reads = {"iteration": lambda: be.iteration, "chain": be.get_chain,
             "log_prob": lambda: be.get_log_prob(flat=True), "accepted": lambda: be.accepted,
             "check": lambda: check_chain_file(path)["mcmc"]}
    got = {}
    for name, read in reads.items():
        try:
            got[name] = read()
        except BayesmotionError as e:
            assert str(path) in str(e), (name, damage, str(e))
        else:
            if name != "check":
                assert np.all(np.isfinite(got[name])), (name, damage)
    if "iteration" in got:
        with h5py.File(path, "r") as f:
            rows = min(f["mcmc/chain"].shape[0], f["mcmc/log_prob"].shape[0])
        assert 0 <= got["iteration"] <= rows, damage
        if "chain" in got:
            assert len(got["chain"]) == got["iteration"], damage
        if "check" in got:
            assert got["check"] == got["iteration"], damage


def test_stored_refit_steps_inside_the_adaptation_are_refused(tiny_model, tmp_path):
    # a window (adaptation end, refit step) would be empty: the file is refused on resume,
    # naming the attribute, and left as it was
    path = tmp_path / "chain.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        post = bm.sample_posterior(tiny_model, n_steps=16, backend=path, progress=False,
                                   burn=4, thin=1)
    assert post.info["adapt_steps"] == 4
    with h5py.File(path, "a") as f:
        assert f["mcmc"].attrs[REFIT_ATTR].tolist() == [250, 500, 1000]
        f["mcmc"].attrs[REFIT_ATTR] = np.array([3, 500])
    before = path.read_bytes()
    with pytest.raises(BayesmotionError, match="refit steps"):
        bm.sample_posterior(tiny_model, n_steps=20, backend=path, progress=False, burn=4,
                            thin=1)
    assert path.read_bytes() == before


def test_a_file_without_refit_steps_resumes_with_none(tiny_model, tmp_path):
    # a chain file written before the refits (no attribute) resumes with its one fitted
    # proposal, and a run without an adaptation has no refits
    from bayesmotion.inference.proposals import refit_steps

    assert refit_steps(0) == [] and refit_steps(150) == [250, 500, 1000]
    assert refit_steps(300) == [500, 1000]
    path = tmp_path / "chain.h5"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)
        bm.sample_posterior(tiny_model, n_steps=16, backend=path, progress=False, burn=4,
                            thin=1)
        with h5py.File(path, "a") as f:
            del f["mcmc"].attrs[REFIT_ATTR]
        post = bm.sample_posterior(tiny_model, n_steps=20, backend=path, progress=False,
                                   burn=4, thin=1)
    assert post.info["n_steps"] == 20 and post.info["refit_steps"] == []
    with h5py.File(path, "r") as f:
        assert REFIT_ATTR not in f["mcmc"].attrs
