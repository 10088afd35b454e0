"""Data specifications accepted by the CLI: ``builtin:handshakes``, a BVH folder with a labels
CSV, or a Bandai dataset root."""

from __future__ import annotations

import csv
from pathlib import Path

from bayesmotion.data.bvh import read_bvh
from bayesmotion.data.motion import MotionDataset, Trial
from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.datasets.handshakes import load_handshakes
from bayesmotion.errors import BayesmotionError


def load_data(spec: str, fps: float | None = None) -> MotionDataset:
    """Load a dataset from a specification string.

    * ``builtin:handshakes`` -- the built-in emotional handshakes (``load_handshakes``);
    * a folder with ``labels.csv`` (columns ``file, emotion`` and optionally ``couple, content,
      trial, actor``; ``content`` names the action): rows with the same ``trial`` value form
      one trial, their actors ordered by the
      integer ``actor`` column (0, 1); a row without a ``trial`` value is a one-actor trial;
      ``fps`` resamples every file (needed when the files' frame rates differ);
    * a Bandai Namco dataset-1 root (files ``dataset-1_*.bvh``).
    """
    if spec.startswith("builtin:"):
        name = spec.split(":", 1)[1]
        if name != "handshakes":
            raise BayesmotionError(f"unknown built-in dataset {name!r}; try builtin:handshakes")

        return load_handshakes(fps=fps or 20.0)
    root = Path(spec)
    if not root.exists():
        raise BayesmotionError(f"{spec}: no such file or folder")
    if (root / "labels.csv").is_file():
        return _from_labels(root, fps)
    if list(root.glob("dataset-1_*.bvh")) or list((root / "data").glob("dataset-1_*.bvh")):
        return load_bandai(root, fps=fps)
    raise BayesmotionError(f"{spec}: expected builtin:handshakes, a folder with labels.csv, or "
                           f"a Bandai dataset root")


def _from_labels(root: Path, fps):
    with open(root / "labels.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "file" not in rows[0] or "emotion" not in rows[0]:
        raise BayesmotionError(f"{root / 'labels.csv'}: needs columns file, emotion[, couple, "
                               f"content, trial, actor]")
    groups: dict[str, list] = {}
    for i, r in enumerate(rows):
        groups.setdefault(r.get("trial") or f"row{i}", []).append(r)
    trials = []
    for name, rs in groups.items():
        try:
            actors = [int(r.get("actor") or 0) for r in rs]
        except ValueError:
            raise BayesmotionError(f"{root / 'labels.csv'}: trial {name!r}: the actor column "
                                   f"must hold integers 0, 1, got "
                                   f"{[r.get('actor') for r in rs]}") from None
        if sorted(actors) != list(range(len(rs))):
            raise BayesmotionError(f"{root / 'labels.csv'}: trial {name!r} has actors {actors}; "
                                   f"expected 0{', 1' if len(rs) > 1 else ''} once each")
        for col in ("emotion", "couple", "content"):
            if len({r.get(col) or "" for r in rs}) > 1:
                raise BayesmotionError(f"{root / 'labels.csv'}: the rows of trial {name!r} "
                                       f"disagree on {col}")
        rs = [r for _, r in sorted(zip(actors, rs, strict=True), key=lambda ar: ar[0])]
        motions = tuple(read_bvh(root / r["file"]) for r in rs)
        if fps:
            motions = tuple(m.resample(fps) for m in motions)
        labels = {"emotion": rs[0]["emotion"]}
        for col in ("couple", "content"):
            if rs[0].get(col):
                labels[col] = rs[0][col]
        trials.append(Trial(motions, labels, name))
    return MotionDataset(trials, name=str(root))
