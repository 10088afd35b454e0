"""Animations of one or two actors (and faint samples) in one 3-D view, saved as GIF or MP4.

GIFs are written with Pillow (always available with matplotlib); MP4 needs ffmpeg on PATH.
The view has equal axis scaling, fixed limits over the whole clip and Y (the vertical axis of the
CMU and Bandai data) drawn up (see :mod:`bayesmotion.viz.plots`). Files are written atomically.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.animation import FFMpegWriter, PillowWriter, writers

from bayesmotion.data.files import atomic_path
from bayesmotion.errors import BayesmotionError
from bayesmotion.viz.plots import (
    ACTOR_COLORS,
    HIDDEN_JOINTS,
    Track,
    draw_skeleton,
    frame_axes,
    move_skeleton,
    new_axes3d,
    scene,
    spread_colors,
)


def animate(trial_or_motions, path: str | os.PathLike, fps: float | None = None,
            stride: int = 1, spread=None, *, parents=None, end_sites: bool = False,
            hide: Sequence = HIDDEN_JOINTS, colors: Sequence | None = None,
            title: str | None = None, figsize: tuple[float, float] = (5.0, 5.0),
            dpi: float = 80, elev: float = 15.0, azim: float = -60.0) -> Path:
    """Save an animation of every actor in one 3-D view.

    Args:
        trial_or_motions: a Trial, Motion(s), or ``(T, J, 3)`` / ``(A, T, J, 3)`` positions.
        path: ``.gif`` (Pillow) or ``.mp4`` (needs ffmpeg).
        fps: playback frame rate; default real time, the data's fps / ``stride`` (required for
            raw positions).
        stride: draw every ``stride``-th frame.
        spread: extra poses over the same frames (posterior samples: Trials, Motions,
            ``(T, J, 3)`` or ``(S, T, J, 3)`` arrays), drawn faintly
            (colours: :func:`bayesmotion.viz.plots.spread_colors`).
        parents: (J,) parents for raw positions.
        end_sites: also draw motions' End Sites.
        hide: joints not drawn, by name or row (default: Bandai's fixed ``joint_Root``).
        colors: one colour per actor.
        title: shown above the frame counter.
        figsize: frame size in inches.
        dpi: dots per inch.
        elev: view elevation in degrees.
        azim: view azimuth in degrees.
    Returns:
        the path written; it holds ``ceil(T / stride)`` images, each titled with its frame.
    Raises:
        BayesmotionError: bad arguments, frame counts that differ, or MP4 without ffmpeg.
    """
    main, extra = scene(trial_or_motions, spread, parents, end_sites, hide)
    T = _common_length(main + extra)
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise BayesmotionError(f"stride must be a positive int, got {stride!r}")
    writer = _writer(Path(path), _playback_fps(fps, main, stride))
    frames = np.arange(0, T, stride)
    tracks = main + extra
    P = [t.positions(frames) for t in tracks]  # (F, J, 3) each: one FK call per track
    colors = ACTOR_COLORS if colors is None else colors
    ax = new_axes3d(figsize, dpi)
    frame_axes(ax, [p[:, t.shown] for t, p in zip(main, P, strict=False)], elev, azim)
    styles = ([(colors[a % len(colors)], False) for a in range(len(main))]
              + [(c, True) for c in spread_colors(len(main), len(extra), colors)])
    artists = [draw_skeleton(ax, p[0], t, color, faint)
               for t, p, (color, faint) in zip(tracks, P, styles, strict=True)]
    with atomic_path(path) as tmp, writer.saving(ax.figure, str(tmp), dpi):
        for f, k in enumerate(frames):
            for a, t, p in zip(artists, tracks, P, strict=True):
                move_skeleton(a, p[f], t)
            ax.set_title(f"{title + chr(10) if title else ''}{_clock(k, main[0].fps)}")
            writer.grab_frame()
    return Path(path)


def _clock(k: int, fps: float | None) -> str:
    return f"frame {k}" if fps is None else f"frame {k}  ({k / fps:.2f} s)"


def _common_length(all_tracks: list[Track]) -> int:
    lengths = {t.n_frames for t in all_tracks}
    if len(lengths) != 1:
        raise BayesmotionError(f"every actor and spread sample must have the same number of "
                               f"frames, got {sorted(lengths)}")
    return lengths.pop()


def _playback_fps(fps: float | None, main: list[Track], stride: int) -> float:
    if fps is None:
        if main[0].fps is None:
            raise BayesmotionError("animate: raw positions have no frame rate; pass fps=")
        fps = main[0].fps / stride
    if not (math.isfinite(fps) and fps > 0):
        raise BayesmotionError(f"animate: fps must be positive, got {fps}")
    return float(fps)


def _writer(path: Path, fps: float):
    suffix = path.suffix.lower()
    if suffix == ".gif":
        return PillowWriter(fps=fps)
    if suffix == ".mp4":
        if not writers.is_available("ffmpeg"):
            raise BayesmotionError(f"cannot write {path}: MP4 needs ffmpeg on PATH, which was "
                                   "not found; install ffmpeg or save a .gif")
        return FFMpegWriter(fps=fps)
    raise BayesmotionError(f"cannot write {path}: animations are .gif or .mp4, not "
                           f"{path.suffix or 'a name without suffix'!r}")
