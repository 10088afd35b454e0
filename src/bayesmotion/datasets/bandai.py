"""The Bandai Namco Research Motion Dataset 1 (emotion subset) as a labelled MotionDataset.

Real, acted motion capture (Kobayashi et al. 2023, arXiv:2306.08861; CC BY-NC 4.0, so it is never
shipped with the package: download it from its publisher). Files are named
``dataset-1_{content}_{style}_{id}.bvh`` (content such as ``walk``, ``walk-back``, ``bow``; style
such as ``normal``, ``happy``); each clip is one actor on a 22-joint, 6-channel skeleton at 30 fps
with Y up.

Each clip becomes a one-actor :class:`~bayesmotion.data.Trial` labelled ``emotion`` (the style,
with Bandai's ``normal`` called ``neutral``), ``content`` and ``id``.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from bayesmotion.data.bvh import read_bvh
from bayesmotion.data.motion import MotionDataset, Trial
from bayesmotion.errors import BayesmotionError

FILE_NAME = re.compile(r"dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_(?P<id>[^_]+)\.bvh")
STYLE_TO_EMOTION = {"normal": "neutral"}
"""Bandai style -> emotion label; styles not listed keep their own name."""
EMOTION_ORDER = ("neutral", "happy", "angry", "sad")
"""Order of the ``emotion`` levels (those present come first, other styles follow sorted)."""
WALK_CONTENTS = ("walk", "walk-back", "walk-left", "walk-right")
"""The walk-like contents: one locomotion pattern in four directions."""


def emotion_of(style: str) -> str:
    """The emotion label of a Bandai style (``"normal"`` -> ``"neutral"``, others unchanged)."""
    return STYLE_TO_EMOTION.get(style, style)


def bandai_files(root: str | os.PathLike) -> dict[Path, dict[str, str]]:
    """The clips under ``root`` with their labels.

    Args:
        root: the dataset folder, either the one holding ``data/`` or ``data/`` itself.
    Returns:
        path -> ``{"emotion", "content", "id", "style"}``, sorted by file name. BVH files whose
        names do not follow ``dataset-1_{content}_{style}_{id}.bvh`` are left out.
    Raises:
        BayesmotionError: the folder is missing or holds no Bandai clip.
    """
    folder = _data_folder(Path(root))
    out = {}
    for path in sorted(folder.glob("*.bvh")):
        m = FILE_NAME.fullmatch(path.name)
        if m:
            out[path] = {"emotion": emotion_of(m["style"]), "content": m["content"],
                         "id": m["id"], "style": m["style"]}
    if not out:
        raise BayesmotionError(f"no Bandai clip (dataset-1_{{content}}_{{style}}_{{id}}.bvh) in "
                               f"{folder}")
    return out


def _data_folder(root: Path) -> Path:
    if (root / "data").is_dir():
        return root / "data"
    if root.is_dir():
        return root
    raise BayesmotionError(
        f"Bandai dataset folder not found: {root}. Pass the folder holding data/ (or data/ "
        "itself) of Bandai-Namco-Research-Motiondataset-1, downloaded from its publisher.")


def _as_set(value: str | Iterable[str] | None) -> set[str] | None:
    if value is None:
        return None
    return {value} if isinstance(value, str) else set(value)


def _select(files: dict, factor: str, wanted: set[str] | None, aliases=None) -> dict:
    """Files whose ``factor`` (or, for styles, its emotion name) is in ``wanted``."""
    if wanted is None:
        return files
    keys = (factor,) if aliases is None else (factor, aliases)
    kept = {p: lab for p, lab in files.items() if any(lab[k] in wanted for k in keys)}
    if not kept:
        have = sorted({lab[factor] for lab in files.values()})
        also = f" (or their {aliases} names)" if aliases else ""
        raise BayesmotionError(f"no Bandai clip matches {factor}={sorted(wanted)}; the folder "
                               f"has {factor} in {have}{also}")
    return kept


def load_bandai(root: str | os.PathLike, content: str | Iterable[str] | None = None,
                style: str | Iterable[str] | None = None,
                fps: float | None = None) -> MotionDataset:
    """Load the Bandai emotion clips as a one-actor dataset.

    Args:
        root: the dataset folder, either the one holding ``data/`` or ``data/`` itself.
        content: keep only these contents (a name or a list), e.g. :data:`WALK_CONTENTS`.
        style: keep only these styles, by Bandai name (``"normal"``) or emotion (``"neutral"``).
        fps: resample every clip to this rate (:meth:`MotionDataset.resample`); default 30.
    Returns:
        a :class:`MotionDataset` of one-actor trials named by file stem, labelled ``emotion``,
        ``content`` and ``id``; the ``emotion`` levels start with ("neutral", "happy", "angry",
        "sad") where present.
    Raises:
        BayesmotionError: missing folder, or no clip matches a filter (the error names it).
        BVHError: a clip is malformed.
    """
    files = bandai_files(root)
    files = _select(files, "content", _as_set(content))
    files = _select(files, "style", _as_set(style), aliases="emotion")
    trials = [Trial((read_bvh(p),), {k: lab[k] for k in ("emotion", "content", "id")}, p.stem)
              for p, lab in files.items()]
    emotions = {t.labels["emotion"] for t in trials}
    order = [e for e in EMOTION_ORDER if e in emotions] + sorted(emotions - set(EMOTION_ORDER))
    data = MotionDataset(tuple(trials), {"emotion": tuple(order)}, name="bandai")
    return data if fps is None else data.resample(fps)
