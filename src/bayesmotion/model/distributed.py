"""What runs on a Dask cluster needs: the model sent once as its file's bytes, loaded once per
worker process, and a client (the caller's, one to a scheduler's address, or a local cluster).

The model travels as the bytes of its model file (the checked, pickle-free format of
:mod:`bayesmotion.model.archive`), so a worker never unpickles a model; tasks carry only small
arguments (file paths, a posterior draw's parameters). Used by
:func:`bayesmotion.emotion.batch.infer_many` and by
:meth:`bayesmotion.inference.posterior.Posterior.generate`.

Dask is an optional dependency: ``pip install "bayesmotion[distributed]"``.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from pathlib import Path

from bayesmotion.errors import BayesmotionError

_MODELS: dict[str, object] = {}  # per process: model file digest -> loaded model


def worker_env() -> dict[str, str]:
    """Environment of the local cluster's worker processes: one thread each for XLA's CPU pool
    (``PJRT_NPROC``) and OpenBLAS, as the cluster runs one process per core; a value the caller
    set in this process's environment is kept."""
    return {k: os.environ.get(k, "1") for k in ("PJRT_NPROC", "OPENBLAS_NUM_THREADS")}


def model_bytes(model) -> bytes:
    """The bytes of a model file: read from a path (and the file checked by loading it here,
    so its errors name the user's file), or written from a FittedHGPDM."""
    if isinstance(model, str | os.PathLike):
        from bayesmotion.model.io import load

        data = Path(model).read_bytes()
        _MODELS[hashlib.sha256(data).hexdigest()] = load(model)  # kept: found by digest
        return data
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "model.npz"
        model.save(path)
        return path.read_bytes()


def worker_model(data: bytes):
    """The model of these file bytes, loaded once per process."""
    key = hashlib.sha256(data).hexdigest()
    if key not in _MODELS:
        from bayesmotion.model.io import load

        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "model.npz"
            path.write_bytes(data)
            _MODELS[key] = load(path)
    return _MODELS[key]


def check_workers(workers) -> None:
    if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
        raise BayesmotionError(f"workers must be an integer >= 1, got {workers!r}")


@contextlib.contextmanager
def dask_client(client=None, scheduler: str | None = None, workers: int = 2, what: str = ""):
    """The client to run on: ``client`` as given (kept open), else one connected to
    ``scheduler`` (an address such as ``tcp://10.0.0.5:8786``), else a ``LocalCluster`` of
    ``workers`` processes, one thread each (:func:`worker_env`); those two are closed at the
    end."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise BayesmotionError(f'{what or "this"} runs on Dask: pip install '
                               f'"bayesmotion[distributed]"') from None
    if client is not None:
        yield client
        return
    check_workers(workers)
    if scheduler is not None:
        own, cluster = Client(scheduler), None
    else:
        # ":0": any free port for the scheduler's HTTP server (with None it tries 8787 and
        # warns when another cluster holds it)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", env=worker_env())
        own = Client(cluster)
    try:
        yield own
    finally:
        own.close()
        if cluster is not None:
            cluster.close()
