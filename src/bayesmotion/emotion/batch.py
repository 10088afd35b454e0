"""Emotion inference over many clips on a Dask cluster: :func:`infer_many`.

Each clip is one :func:`~bayesmotion.emotion.infer.infer_emotion` call, run as a task on a
``dask.distributed`` cluster: a ``LocalCluster`` of ``workers`` processes (one thread each) by
default (one XLA and one OpenBLAS thread per worker process,
:func:`~bayesmotion.model.distributed.worker_env`), or any cluster given by its scheduler's
address or a ``Client``. The model travels to
each worker once, as the bytes of its model file (the checked, pickle-free format of
:mod:`bayesmotion.model.archive`), and each worker loads it once; a task then carries only its
clip's file paths, which every worker must be able to read (a shared file system on a
multi-machine cluster). When this process has the compilation cache on
(:mod:`bayesmotion.compile_cache`; the command line does), the workers of a ``LocalCluster``
started here use the same cache folder, so the workers of a later run read the programs
instead of compiling them.

Results stream to a CSV table as they finish, one row per clip, flushed and synced to disk
row by row, so an interrupted run leaves every finished row (and at most one partial line, which
the next run drops). Run again with the same table and the clips already answered are not
redone; clips whose row holds an error are tried again. A clip that fails (an unreadable file,
a skeleton the model does not know) gets its error in its row and does not stop the others.

Columns: ``clip``, ``files`` (``;``-separated), ``label``, ``label_set_90`` (``;``-separated),
``p_<level>`` (label probabilities) and ``mean_<level>`` (posterior mean coordinates) for each
emotion level, ``out_of_distribution``, ``ood_score``, ``in_distribution_weight``,
``n_frames``, ``seconds`` (of the ``infer_emotion`` call on its worker), ``finished`` (when it
ended, Unix time), ``worker``, ``error``.

Dask is an optional dependency: ``pip install "bayesmotion[distributed]"``.
"""

from __future__ import annotations

import csv
import io
import os
import re
import socket
import time
import uuid
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bayesmotion._config import release_compiled_programs
from bayesmotion.compile_cache import cache_stats, enable_compilation_cache
from bayesmotion.emotion.projection import START_JITTER
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.distributed import check_workers, dask_client, model_bytes, worker_model
from bayesmotion.validate import check_pad_to, check_projection_starts

FIXED = ("clip", "files", "label", "label_set_90")
TAIL = ("out_of_distribution", "ood_score", "in_distribution_weight", "unseen_levels",
        "n_frames", "seconds",
        "finished", "worker", "error")
_ACTOR_FILE = re.compile(r"(?P<clip>.+)_actor(?P<actor>\d+)$")


def columns(levels: Sequence[str]) -> list[str]:
    """The table's columns for a model with these emotion levels."""
    return [*FIXED, *(f"p_{lv}" for lv in levels), *(f"mean_{lv}" for lv in levels), *TAIL]


def find_clips(folder, n_actors: int) -> dict[str, tuple[str, ...]]:
    """The clips of a folder of BVH files, name -> files: each file one clip for a one-actor
    model; for two or more actors, files named ``<clip>_actor<a>.bvh`` (as ``generate``
    writes them), grouped by clip."""
    folder = Path(folder)
    if not folder.is_dir():
        raise BayesmotionError(f"{folder}: not a folder of BVH files")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".bvh")
    if not files:
        raise BayesmotionError(f"{folder}: holds no .bvh file")
    if n_actors == 1:
        return {p.stem: (str(p),) for p in files}
    groups: dict[str, dict[int, str]] = {}
    for p in files:
        m = _ACTOR_FILE.fullmatch(p.stem)
        if m is None:
            raise BayesmotionError(f"{p.name}: the model has {n_actors} actors, so each clip "
                                   f"is one file per actor named <clip>_actor<a>.bvh")
        groups.setdefault(m["clip"], {})[int(m["actor"])] = str(p)
    bad = [c for c, g in groups.items() if sorted(g) != list(range(n_actors))]
    if bad:
        raise BayesmotionError(f"{folder}: clips without exactly one file for each of the "
                               f"{n_actors} actors (actor0 ... actor{n_actors - 1}): "
                               f"{sorted(bad)[:5]}")
    return {c: tuple(g[a] for a in range(n_actors)) for c, g in groups.items()}


def _named(clips, n_actors: int) -> dict[str, tuple[str, ...]]:
    """Clips given as a folder, a dict name -> file(s), or a sequence of files (one-actor
    models) or of per-actor file tuples."""
    if isinstance(clips, str | os.PathLike):
        return find_clips(clips, n_actors)
    if isinstance(clips, dict):
        items = clips.items()
    else:
        items = []
        for c in clips:
            paths = (c,) if isinstance(c, str | os.PathLike) else tuple(c)
            stem = Path(paths[0]).stem
            m = _ACTOR_FILE.fullmatch(stem)
            items.append((m["clip"] if m and len(paths) > 1 else stem, paths))
    out: dict[str, tuple[str, ...]] = {}
    for name, paths in items:
        paths = (paths,) if isinstance(paths, str | os.PathLike) else tuple(paths)
        if len(paths) != n_actors:
            raise BayesmotionError(f"clip {name!r}: give one file per actor ({n_actors}), got "
                                   f"{len(paths)}")
        if name in out:
            raise BayesmotionError(f"two clips are named {name!r}; give a dict name -> files")
        out[str(name)] = tuple(str(p) for p in paths)
    if not out:
        raise BayesmotionError("no clip to infer")
    return out


def infer_row(model, name: str, paths: Sequence[str], kwargs: dict) -> dict:
    """One clip's row of the table (an ``error`` row instead of raising)."""
    from bayesmotion.emotion.infer import infer_emotion
    from bayesmotion.emotion.ood import OutOfDistributionWarning, UnseenStyleWarning

    levels = list(model.levels["emotion"])
    row = dict.fromkeys(columns(levels), "")
    row.update(clip=name, files=";".join(paths), worker=f"{socket.gethostname()}:{os.getpid()}")
    release_compiled_programs()  # clips of many lengths compile anew: keep the maps bounded
    t = time.perf_counter()
    try:
        with warnings.catch_warnings():  # the flag is in the row
            warnings.simplefilter("ignore", OutOfDistributionWarning)
            warnings.simplefilter("ignore", UnseenStyleWarning)
            ep = infer_emotion(model, list(paths) if len(paths) > 1 else paths[0], **kwargs)
    except Exception as e:  # noqa: BLE001 -- a failing clip is reported in its row
        row.update(error=f"{type(e).__name__}: {' '.join(str(e).split())}",
                   seconds=time.perf_counter() - t, finished=time.time())
        return row
    row.update(label=ep.label, label_set_90=";".join(ep.label_set(0.9)),
               out_of_distribution=bool(ep.out_of_distribution),
               ood_score=float(ep.info["ood"]["score"]),
               in_distribution_weight=ep.info.get("in_distribution_weight", ""),
               unseen_levels=";".join(f"{lv}:{'+'.join(ls)}"
                                      for lv, ls in ep.info["unseen_levels"].items()),
               n_frames=int(ep.info["n_frames"]), seconds=time.perf_counter() - t,
               finished=time.time())
    for lv, p, m in zip(levels, ep.probabilities, ep.mean, strict=True):
        row[f"p_{lv}"], row[f"mean_{lv}"] = float(p), float(m)
    return row


def _task(data: bytes, name: str, paths: tuple[str, ...], kwargs: dict,
          cache_dir: str | None = None) -> dict:
    if cache_dir is not None:  # the caller's compilation cache, on this machine's workers
        enable_compilation_cache(cache_dir)
    return infer_row(worker_model(data), name, paths, kwargs)


class Table:
    """The CSV table: read what an earlier run finished, append rows durably."""

    def __init__(self, path, cols: list[str]):
        self.path, self.cols = Path(path), cols

    def finished(self) -> dict[str, dict]:
        """Rows of clips already answered (no error); error rows and a partial last line are
        dropped from the file (atomically) so the run appends after whole, good rows."""
        if not self.path.exists():
            return {}
        text = self.path.read_text(encoding="utf-8")
        if text and not text.endswith("\n"):  # an interrupted write: drop the partial line
            text = text[:text.rfind("\n") + 1]
        header = next(csv.reader(io.StringIO(text, newline="")), None)
        if header is not None and header != self.cols:
            raise BayesmotionError(f"{self.path}: its columns are not this model's "
                                   f"({', '.join(self.cols[:6])}, ...); give another table")
        rows = list(csv.DictReader(io.StringIO(text, newline="")))
        good = {r["clip"]: r for r in rows if not r["error"]}
        self._rewrite(list(good.values()))
        return good

    def _rewrite(self, rows: list[dict]) -> None:
        from bayesmotion.data.files import atomic_write_text

        buf = io.StringIO(newline="")
        w = csv.DictWriter(buf, self.cols, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        atomic_write_text(self.path, buf.getvalue())

    def append(self, row: dict) -> None:
        new = not self.path.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a", encoding="utf-8", newline="") as f:
            w = csv.DictWriter(f, self.cols, lineterminator="\n")
            if new:
                w.writeheader()
            w.writerow(row)
            f.flush()
            os.fsync(f.fileno())


def infer_many(model, clips, out=None, *, client=None, workers: int = 2,
               scheduler: str | None = None, progress: bool = True,
               **infer_kwargs) -> list[dict]:
    """Infer the emotion of many clips in parallel on Dask; rows stream to ``out``.

    Args:
        model: a FittedHGPDM or the path of a model file.
        clips: a folder of BVH files (:func:`find_clips`), a dict name -> file(s), or a
            sequence of files (one-actor models) or of per-actor file tuples.
        out: the CSV table to write (module docstring); an existing one is resumed. None: no
            table, rows returned only.
        client: a ``dask.distributed.Client`` to run on (kept open).
        workers: processes of the ``LocalCluster`` started when neither ``client`` nor
            ``scheduler`` is given (closed at the end).
        scheduler: the address of a running scheduler (e.g. ``tcp://10.0.0.5:8786``).
        progress: a progress bar over the clips.
        **infer_kwargs: passed to every :func:`~bayesmotion.emotion.infer.infer_emotion` call
            (e.g. ``seed``, ``couple``, ``n_steps``). A model fitted with ``relative_to`` needs
            ``styles={label: group}``: every clip of the run is read against that group.
    Returns:
        one row (dict of the table's columns) per clip, in the order given; rows found in
        ``out`` from an earlier run are returned as read (:func:`parse_row`).
    """
    try:
        from dask.distributed import as_completed
    except ImportError:
        raise BayesmotionError('infer_many runs on Dask: pip install "bayesmotion[distributed]"'
                               ) from None
    from tqdm.auto import tqdm

    check_projection_starts(infer_kwargs.get("emotion_starts", "vertices"),
                            infer_kwargs.get("level_starts", 1),
                            infer_kwargs.get("start_jitter", START_JITTER))
    check_pad_to(infer_kwargs.get("pad_to"))
    data = model_bytes(model)
    fitted = worker_model(data)
    rel = fitted.spec.relative_to
    if rel is not None and rel not in (infer_kwargs.get("styles") or {}):
        raise BayesmotionError(f"the model reads poses relative to their {rel!r}, and clip "
                               f"files carry no labels: give every clip's {rel!r} as "
                               f"styles={{{rel!r}: ...}} (one of {list(fitted.codecs[0].groups)}"
                               f"; one run reads every clip against that group)")
    named = _named(clips, fitted.n_actors)
    check_workers(workers)
    cols = columns(list(fitted.levels["emotion"]))
    table = Table(out, cols) if out is not None else None
    done = ({c: parse_row(r) for c, r in table.finished().items()} if table is not None
            else {})
    todo = {c: p for c, p in named.items() if c not in done}
    rows = dict(done)
    if todo:
        # workers started here (not a given cluster's) use this process's compilation cache
        cache_dir = cache_stats()["directory"] if client is None and scheduler is None else None
        with dask_client(client, scheduler, workers, "infer_many") as client:
            shared = client.scatter(data, broadcast=True, hash=False)
            run = uuid.uuid4().hex[:8]
            futures = {client.submit(_task, shared, c, p, infer_kwargs, cache_dir, pure=False,
                                     key=f"bayesmotion-infer-{run}-{i}"): c
                       for i, (c, p) in enumerate(todo.items())}
            bar = tqdm(total=len(named), initial=len(done), desc="infer_many (clips)",
                       disable=not progress)
            for fut in as_completed(futures):
                name = futures[fut]
                try:
                    row = fut.result()
                except Exception as e:  # noqa: BLE001 -- a lost worker: report in the row
                    row = dict.fromkeys(cols, "")
                    row.update(clip=name, files=";".join(todo[name]),
                               error=f"{type(e).__name__}: {' '.join(str(e).split())}")
                rows[name] = row
                if table is not None:
                    table.append(row)
                bar.update()
            bar.close()
    return [rows[c] for c in named]


def parse_row(row: dict) -> dict:
    """A row as read from the table -> typed: numbers as floats (NaN where empty, as in an
    error row), ``n_frames`` an int, ``out_of_distribution`` a bool (None where empty)."""
    out = dict(row)
    for k, v in row.items():
        if k.startswith(("p_", "mean_")) or k in ("ood_score", "in_distribution_weight",
                                                  "seconds", "finished"):
            out[k] = float(v) if v not in ("", None) else np.nan
    out["n_frames"] = int(row["n_frames"]) if row.get("n_frames") else None
    out["out_of_distribution"] = {"True": True, "False": False}.get(
        row.get("out_of_distribution"))
    return out


def read_table(path) -> list[dict]:
    """The rows of a table written by :func:`infer_many`, typed (:func:`parse_row`)."""
    with open(path, encoding="utf-8", newline="") as f:
        return [parse_row(r) for r in csv.DictReader(f)]
