"""Shared fixtures: paths to the real motion-capture sets beside the checkout."""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

# Two pytest-xdist workers share one machine: on a GPU, JAX must not grab 75% of its memory
# in each of them.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
# The command line turns JAX's persistent compilation cache on (bayesmotion.compile_cache): the
# tests, which call it in-process and in subprocesses, keep it off unless a test turns it on in
# a folder of its own, so they neither read nor fill the user's cache.
os.environ["BAYESMOTION_COMPILE_CACHE"] = "off"
# One private compilation cache for the whole test run instead: JAX reads this variable when it
# is imported, in the pytest process, in both xdist workers (which inherit it from the first)
# and in every subprocess and notebook kernel a test starts, so a program compiled by one of
# them (the same code and shapes: the fixtures' models, the CLI's and the notebooks' calls) is
# read back by the others instead of being compiled again, and again after
# release_compiled_programs (below) drops it from a worker's memory. The folder is made with
# mkdtemp (mode 0700: whoever can write to a compilation cache can make its readers run code)
# and removed when the run ends (pytest_sessionfinish). A compiled program is keyed by its
# code, shapes, flags and JAX version, so the answers are those of a compilation.
_OWN_CACHE = "JAX_COMPILATION_CACHE_DIR" not in os.environ
if _OWN_CACHE:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="bayesmotion-tests-jax-")
    # every program, as bayesmotion.enable_compilation_cache does: JAX's default (1 s) leaves
    # out the many small programs each new process (a CLI call, a notebook kernel) compiles
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

# How much work XLA puts into optimising each compiled program. Most tests fit or infer on
# small models at shapes of their own, so compiling dominates them, and XLA's optimisation
# passes cost more than they save: those tests compile with jax_disable_most_optimizations
# (the same programs with fewer optimisations; their answers agree with the optimised ones to
# rounding, test_compile_effort.py). The tests marked ``optimized``, whose long chains and fits
# run for longer than they compile, compile as users' programs do (unoptimised, those seven
# ran 400 s longer in all). Measured on a 2-core CPU, two workers: the whole suite's summed
# test time 2,580 s this way against 3,127 s with every test optimised (21:47 against 26:29
# wall). BAYESMOTION_TEST_COMPILE=optimized compiles every test as users' programs are
# compiled. JAX_DISABLE_MOST_OPTIMIZATIONS is what JAX reads in the subprocesses and notebook
# kernels a test starts; pytest_runtest_setup sets it, and the in-process flag, for each test.
_COMPILE_ALL_OPTIMISED = os.environ.get("BAYESMOTION_TEST_COMPILE", "auto") == "optimized"
if _COMPILE_ALL_OPTIMISED:
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "false"

# The test modules import arviz; two workers importing it for the first time on one day race on
# its daily stamp file. import_arviz survives that race, so each worker imports arviz through it
# before any test module does.
from bayesmotion.inference.diagnostics import import_arviz  # noqa: E402

import_arviz()


def pytest_sessionfinish(session, exitstatus):
    """The pytest process (not an xdist worker) removes the run's compilation cache."""
    if _OWN_CACHE and not hasattr(session.config, "workerinput"):
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)


def pytest_collection_modifyitems(session, config, items):
    """The files that hold slow tests first, each file's tests in their own order. With
    ``--dist loadfile`` a worker takes the next whole file when it is free, so a file of several
    minutes taken last keeps the run waiting while the other worker has nothing left to do;
    taken first, the short files fill in around it."""
    heavy = {item.path for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: item.path not in heavy)  # stable: the order within a file holds


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Each test's compilation effort (above), set before its fixtures are."""
    if _COMPILE_ALL_OPTIMISED:
        return
    import jax

    unoptimised = item.get_closest_marker("optimized") is None
    if jax.config.values["jax_disable_most_optimizations"] != unoptimised:
        # the programs already compiled in this process were compiled the other way: drop
        # them, so that the test runs what its own setting compiles (the persistent cache
        # keys each program by its compile options and keeps both)
        jax.clear_caches()
        jax.config.update("jax_disable_most_optimizations", unoptimised)
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "true" if unoptimised else "false"


def pytest_runtest_teardown(item, nextitem):
    """Between test files, drop JAX's compiled programs once the worker's memory mappings pass a
    quarter of the kernel's limit (``bayesmotion._config.release_compiled_programs``). A worker
    runs half the suite in one process and compiles enough programs to near the limit (65,530),
    where XLA's next compilation fails and takes the worker down."""
    if nextitem is None or nextitem.path != item.path:
        from bayesmotion._config import release_compiled_programs

        release_compiled_programs(fraction=0.25)

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CMU_DIR = SHARED / "cmu-handshake"
BANDAI_DIR = SHARED / "bandai-emotion"


@pytest.fixture(scope="session")
def cmu_files():
    """The two CMU handshake BVH files: the shared copies beside the checkout, else the
    byte-identical ones the package ships (bayesmotion/datasets/builtin)."""
    files = sorted(CMU_DIR.glob("*.bvh"))
    if not files:
        from importlib import resources

        builtin = resources.files("bayesmotion.datasets") / "builtin"
        files = sorted(Path(str(builtin)).glob("*_01.bvh"))
    assert [f.name for f in files] == ["18_01.bvh", "19_01.bvh"], files
    return files


@pytest.fixture(scope="session")
def bandai_root():
    if not (BANDAI_DIR / "data").is_dir():
        pytest.skip(f"shared Bandai data not found at {BANDAI_DIR}")
    return BANDAI_DIR


@pytest.fixture(scope="session")
def bandai_files(bandai_root):
    return sorted((bandai_root / "data").glob("*.bvh"))


@pytest.fixture(scope="session")
def handshake_data():
    """The built-in emotional handshakes at test size (10 fps: 17 frames per trial)."""
    from bayesmotion.datasets import load_handshakes

    return load_handshakes(fps=10.0)


@pytest.fixture(scope="session")
def handshake_model(handshake_data, tmp_path_factory):
    """H-GPDM MAP fit on the test-size built-in handshakes (shared by the slow tests)."""
    from bayesmotion import HGPDM

    return HGPDM().fit(handshake_data, max_iter=300, progress=False)


def make_tiny_dataset(fps=5.0):
    """Test-sized real style difference: the built-in handshakes' happy and sad trials of
    couple c1 at 5 fps (6 trials x 9 frames)."""
    import bayesmotion as bm

    ds = bm.load_handshakes(fps=fps).filter(couple="c1", emotion=["happy", "sad"])
    return bm.MotionDataset(ds.trials, {"emotion": ("happy", "sad"), "couple": ("c1",)})


def synthetic_walk(base, fps: float, n_frames: int, hz: float, swing: float):
    """``base``'s first pose walking: the hips travel forward (towards the toes) at 1.4 hip
    heights per second and bob; the legs swing ``swing`` degrees at ``hz`` steps per second in
    opposite phase, the knees bend, the arms swing against the legs."""
    import numpy as np

    from bayesmotion.data import Motion

    sk = base.skeleton

    def column(joint: str, channel: str) -> int:
        j = sk.index(joint)
        return sk.channel_offsets[j] + sk.channels[j].index(channel)

    t = np.arange(n_frames) / fps
    phase = 2 * np.pi * hz * t
    v = np.repeat(base.values[:1], n_frames, axis=0)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        v[:, column(f"{side}UpLeg", "Xrotation")] += sign * swing * np.sin(phase)
        v[:, column(f"{side}Leg", "Xrotation")] += 0.3 * swing * (1 - sign * np.cos(phase))
        v[:, column(f"{side}Arm", "Yrotation")] -= sign * 0.6 * swing * np.sin(phase)
    P = base.positions()[0]
    forward = np.cross(P[sk.index("RightUpLeg")] - P[sk.index("LeftUpLeg")], [0.0, 1.0, 0.0])
    forward[1] = 0.0
    forward *= np.sign(forward @ (P[sk.index("LeftToeBase")] - P[sk.index("LeftFoot")]))
    forward /= np.linalg.norm(forward)
    v[:, :3] += np.outer(1.4 * P[0, 1] * t, forward)
    v[:, 1] += 0.03 * P[0, 1] * np.cos(2 * phase)
    return Motion(sk, v, fps, "walk")


@pytest.fixture(scope="session")
def tiny_model():
    """A 6-trial, 54-frame model (latent dims 3) fitted for 60 iterations."""
    from bayesmotion import HGPDM

    return HGPDM(latent_dim=3, interaction_dim=3).fit(make_tiny_dataset(), max_iter=60,
                                                      progress=False)


@pytest.fixture(scope="module")
def client():
    """A Dask client of a LocalCluster of 2 worker processes (one thread each), per module."""
    distributed = pytest.importorskip("dask.distributed",
                                      reason="dask.distributed not installed")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=":0")
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()
