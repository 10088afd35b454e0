"""Data specifications accepted by the CLI: ``builtin:handshakes``, a BVH folder with a labels
CSV, or a Bandai dataset root."""

from __future__ import annotations

import csv
from pathlib import Path

from .data.bvh import read_bvh
from .data.motion import MotionDataset, Trial
from .errors import BayesmotionError


def load_data(spec: str, fps: float | None = None) -> MotionDataset:
    """Load a dataset from a specification string.

    * ``builtin:handshakes`` -- the built-in emotional handshakes (``load_handshakes``);
    * a folder with ``labels.csv`` (columns ``file, emotion, couple``; rows with the same
      ``trial`` column, or consecutive rows of one couple with ``actor`` 0/1, form two-actor
      trials; otherwise each file is a one-actor trial);
    * a Bandai Namco dataset-1 root (files ``dataset-1_*.bvh``).
    """
    if spec.startswith("builtin:"):
        name = spec.split(":", 1)[1]
        if name != "handshakes":
            raise BayesmotionError(f"unknown built-in dataset {name!r}; try builtin:handshakes")
        from .data.handshakes import load_handshakes

        return load_handshakes(fps=fps or 20.0)
    root = Path(spec)
    if not root.exists():
        raise BayesmotionError(f"{spec}: no such file or folder")
    if (root / "labels.csv").is_file():
        return _from_labels(root, fps)
    if list(root.glob("dataset-1_*.bvh")) or list((root / "data").glob("dataset-1_*.bvh")):
        from .data.bandai import load_bandai

        return load_bandai(root, fps=fps)
    raise BayesmotionError(f"{spec}: expected builtin:handshakes, a folder with labels.csv, or "
                           f"a Bandai dataset root")


def _from_labels(root: Path, fps):
    with open(root / "labels.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows or "file" not in rows[0] or "emotion" not in rows[0]:
        raise BayesmotionError(f"{root / 'labels.csv'}: needs columns file, emotion[, couple, "
                               f"trial, actor]")
    groups: dict[str, list] = {}
    for i, r in enumerate(rows):
        groups.setdefault(r.get("trial") or f"row{i}", []).append(r)
    trials = []
    for name, rs in groups.items():
        rs = sorted(rs, key=lambda r: int(r.get("actor") or 0))
        motions = tuple(read_bvh(root / r["file"]) for r in rs)
        labels = {"emotion": rs[0]["emotion"]}
        if rs[0].get("couple"):
            labels["couple"] = rs[0]["couple"]
        trials.append(Trial(motions, labels, name))
    ds = MotionDataset(trials, name=str(root))
    return ds.resample(fps) if fps else ds
