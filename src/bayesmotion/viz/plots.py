"""Sanity views: stick figures of poses and mean +- k sd bands over time.

Figures are made without pyplot (``matplotlib.figure.Figure`` on the Agg canvas), so nothing is
shown, nothing global is left open and nothing needs closing; in a notebook display ``ax.figure``.
Files are written atomically (temporary file, then ``os.replace``).

Poses come as a :class:`~bayesmotion.data.Motion`, a :class:`~bayesmotion.data.Trial`, a
sequence of them, or raw positions ``(T, J, 3)`` (``(A, T, J, 3)`` for A actors) with
``parents``. Both data sets have Y up; the 3-D views draw data ``(x, y, z)`` at plot
``(x, -z, y)``, a rotation (not a mirror), so Y is vertical and left stays left.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from bayesmotion.data.files import atomic_path
from bayesmotion.data.motion import Motion, Trial
from bayesmotion.errors import BayesmotionError

ACTOR_COLORS = ("tab:blue", "tab:red", "tab:green", "tab:purple")
SPREAD_ALPHA = 0.2
HIDDEN_JOINTS = ("joint_Root",)
"""Joints not drawn by default: Bandai's ``joint_Root`` is a fixed world origin, not a body part
(drawn, it would be a long bone from the origin to the hips)."""


@dataclass(frozen=True)
class Track:
    """One skeleton over time, with positions computed only for the frames drawn.

    Attributes:
        source: a :class:`Motion` (positions by forward kinematics) or (T, J, 3) positions.
        parents: (J,) parent row of each position row, -1 for a root (End Sites included).
        fps: frames per second, None for raw positions.
        end_sites: append a motion's End Sites after its joints.
        hidden: rows not drawn (nor their bones).
    """

    source: Motion | np.ndarray
    parents: tuple[int, ...]
    fps: float | None = None
    end_sites: bool = False
    hidden: frozenset[int] = frozenset()

    @property
    def n_frames(self) -> int:
        return self.source.n_frames if isinstance(self.source, Motion) else len(self.source)

    @property
    def bones(self) -> np.ndarray:
        """(B, 2) child and parent rows of every drawn bone."""
        return np.array([(j, p) for j, p in enumerate(self.parents)
                         if p >= 0 and not {j, p} & self.hidden], dtype=int).reshape(-1, 2)

    @property
    def shown(self) -> np.ndarray:
        """Indices of the rows drawn."""
        return np.array([j for j in range(len(self.parents)) if j not in self.hidden], dtype=int)

    def positions(self, frames) -> np.ndarray:
        """(F, J, 3) world positions at ``frames`` (F indices; one FK call for a Motion)."""
        frames = np.atleast_1d(np.asarray(frames, dtype=int))
        if isinstance(self.source, Motion):
            return self.source.select(frames).positions(with_end_sites=self.end_sites)
        return self.source[frames]


def motion_track(m: Motion, end_sites: bool = False, hide: Sequence = HIDDEN_JOINTS) -> Track:
    """A motion's track (End Sites appended, parented to their joints, if asked)."""
    sk = m.skeleton
    ends = tuple(j for j, _ in sorted(sk.end_sites.items())) if end_sites else ()
    hidden = {sk.names.index(h) if isinstance(h, str) else int(h) for h in hide
              if not isinstance(h, str) or h in sk.names}
    return Track(m, sk.parents + ends, m.fps, end_sites, frozenset(hidden))


def tracks(obj, parents=None, end_sites: bool = False,
           hide: Sequence = HIDDEN_JOINTS) -> list[Track]:
    """Skeleton tracks from a Motion, Trial, positions array or a sequence of them.

    Args:
        obj: ``Motion``, ``Trial``, ``(T, J, 3)`` / ``(A, T, J, 3)`` positions, or a list.
        parents: (J,) parents of raw positions; may also be a ``{J: parents}`` dict.
        end_sites: draw End Sites of motions.
        hide: joints not to draw, by name (motions) or row index.
    Returns:
        one :class:`Track` per actor.
    """
    if isinstance(obj, Motion):
        return [motion_track(obj, end_sites, hide)]
    if isinstance(obj, Trial):
        return [motion_track(a, end_sites, hide) for a in obj.actors]
    if isinstance(obj, list | tuple) and obj and all(
            isinstance(i, Motion | Trial) or hasattr(i, "shape") for i in obj):
        return [t for item in obj for t in tracks(item, parents, end_sites, hide)]
    try:
        pos = np.asarray(obj, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise BayesmotionError(f"cannot draw a {type(obj).__name__}: pass a Motion, a Trial "
                               f"or (T, J, 3) positions ({e})") from None
    if pos.ndim == 4:
        return [t for p in pos for t in tracks(p, parents, end_sites, hide)]
    pos = pos[None] if pos.ndim == 2 else pos
    if pos.ndim != 3 or pos.shape[-1] != 3 or 0 in pos.shape:
        raise BayesmotionError(f"positions must be (T, J, 3) or (A, T, J, 3), got {pos.shape}")
    hidden = frozenset(int(h) for h in hide if not isinstance(h, str))
    return [Track(pos, _parents_for(parents, pos.shape[1]), hidden=hidden)]


def _parents_for(parents, J: int) -> tuple[int, ...]:
    if isinstance(parents, dict):
        parents = parents.get(J)
    if parents is None:
        raise BayesmotionError(f"raw positions with {J} joints need `parents` (one index per "
                               "joint, -1 for the root) to know the bones")
    parents = tuple(int(p) for p in parents)
    if len(parents) != J or any(not -1 <= p < J or p == j for j, p in enumerate(parents)):
        raise BayesmotionError(f"parents must give one index in [-1, {J}) per joint ({J} joints, "
                               f"no self-parent), got {len(parents)} entries: {parents[:8]}...")
    return parents


def scene(obj, spread=None, parents=None, end_sites: bool = False,
          hide: Sequence = HIDDEN_JOINTS) -> tuple[list[Track], list[Track]]:
    """The actors' tracks and the faint ``spread`` tracks.

    Raw spread arrays take the bones of the actor with as many joints (or ``parents``), and
    hide the joints that actor's track hides (e.g. Bandai's static ``joint_Root``, which would
    otherwise be drawn as a bone from the world origin to the hips). List samples sample by
    sample, the actors inside each (``samples.reshape(-1, T, J, 3)`` of an (S, A, T, J, 3)
    array), so that :func:`spread_colors` gives each its actor's colour.
    """
    main = tracks(obj, parents, end_sites, hide)
    if spread is None:
        return main, []
    known = {len(t.parents): t.parents for t in main}
    if parents is not None and not isinstance(parents, dict):
        known.setdefault(len(parents), tuple(parents))
    hidden_of = {t.parents: t.hidden for t in main}
    extra = [replace(t, hidden=t.hidden | hidden_of.get(t.parents, frozenset()))
             for t in tracks(spread, known, end_sites, hide)]
    return main, extra


def spread_colors(n_main: int, n_extra: int, colors: Sequence) -> list:
    """Colours of faint tracks: when their count is a multiple of the actors' (whole samples,
    listed sample by sample with the actors inside) track i takes actor ``i % n_main``'s
    colour, else the first one's."""
    if n_main > 1 and n_extra % n_main == 0:
        return [colors[(i % n_main) % len(colors)] for i in range(n_extra)]
    return [colors[0]] * n_extra


# ------------------------------------------------------------------------------ 3-D drawing
def to_plot(p: np.ndarray) -> np.ndarray:
    """Data ``(..., [x, y, z])`` (Y up) -> plot ``(..., [x, -z, y])`` (plot z up)."""
    return np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)


def new_axes3d(figsize=(5.0, 5.0), dpi: float = 100) -> Axes:
    """A 3-D Axes on a fresh Agg figure (no pyplot)."""
    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig.add_subplot(projection="3d")


def frame_axes(ax: Axes, positions: list[np.ndarray], elev: float = 15.0,
               azim: float = -60.0) -> None:
    """Equal scaling on all three axes, limits covering every pose given, Y drawn up.

    Args:
        ax: a 3-D Axes.
        positions: arrays (..., 3) of data positions to keep in view.
        elev: view elevation in degrees.
        azim: view azimuth in degrees.
    """
    pts = to_plot(np.concatenate([p.reshape(-1, 3) for p in positions]))
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if not len(pts):
        raise BayesmotionError("no finite position to draw")
    lo, hi = pts.min(0), pts.max(0)
    center, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2 * 1.05, 1e-9)
    ax.set_xlim(center[0] - half, center[0] + half)
    ax.set_ylim(center[1] - half, center[1] + half)
    ax.set_zlim(center[2] - half, center[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("X")
    ax.set_ylabel("-Z")
    ax.set_zlabel("Y (up)")
    ax.view_init(elev=elev, azim=azim)


def bone_segments(p: np.ndarray, track: Track) -> np.ndarray:
    """(B, 2, 3) plot coordinates of the track's bones. p: (J, 3) data positions."""
    q, b = to_plot(p), track.bones
    return np.stack([q[b[:, 0]], q[b[:, 1]]], axis=1)


def draw_skeleton(ax: Axes, p: np.ndarray, track: Track, color, faint: bool = False):
    """Bones (and, unless ``faint``, joint dots) of one pose p: (J, 3); returns both artists."""
    lines = Line3DCollection(bone_segments(p, track), colors=color,
                             linewidths=0.8 if faint else 2.0,
                             alpha=SPREAD_ALPHA if faint else 1.0)
    ax.add_collection3d(lines)
    if faint:
        return lines, None
    q = to_plot(p[track.shown])
    (dots,) = ax.plot(q[:, 0], q[:, 1], q[:, 2], "o", color=color, markersize=2.5)
    return lines, dots


def move_skeleton(artists, p: np.ndarray, track: Track) -> None:
    """Move the artists of :func:`draw_skeleton` to pose p: (J, 3)."""
    lines, dots = artists
    lines.set_segments(bone_segments(p, track))
    if dots is not None:
        q = to_plot(p[track.shown])
        dots.set_data_3d(q[:, 0], q[:, 1], q[:, 2])


def plot_pose(motions_or_positions, frame: int = 0, ax: Axes | None = None, *,
              parents=None, end_sites: bool = False, spread=None,
              hide: Sequence = HIDDEN_JOINTS, colors: Sequence | None = None,
              title: str | None = None, path: str | os.PathLike | None = None,
              dpi: float = 100, elev: float = 15.0, azim: float = -60.0) -> Axes:
    """Draw one frame as stick figures in 3-D (one colour per actor).

    Args:
        motions_or_positions: Motion, Trial, ``(T, J, 3)`` positions or a list (see module doc).
        frame: the frame index.
        ax: a 3-D Axes to draw into; a new figure when None.
        parents: (J,) parents for raw positions.
        end_sites: also draw motions' End Sites.
        spread: extra poses in the same forms (e.g. posterior samples), drawn faintly; see
            :func:`spread_colors` for their colours.
        hide: joints not drawn, by name or row (default :data:`HIDDEN_JOINTS`).
        colors: one colour per actor.
        title: Axes title (default ``"frame k"``).
        path: also save the figure here (PNG, SVG, PDF by suffix), atomically.
        dpi: resolution of the saved file.
        elev: view elevation in degrees.
        azim: view azimuth in degrees.
    Returns:
        the Axes.
    """
    main, extra = scene(motions_or_positions, spread, parents, end_sites, hide)
    for t in main + extra:
        if not -t.n_frames <= frame < t.n_frames:
            raise BayesmotionError(f"frame {frame} is out of range for {t.n_frames} frames")
    ax = new_axes3d(dpi=dpi) if ax is None else ax
    colors = ACTOR_COLORS if colors is None else colors
    for t, c in zip(extra, spread_colors(len(main), len(extra), colors), strict=True):
        draw_skeleton(ax, t.positions(frame)[0], t, c, faint=True)
    poses = [t.positions(frame)[0] for t in main]
    for a, (t, p) in enumerate(zip(main, poses, strict=True)):
        draw_skeleton(ax, p, t, colors[a % len(colors)])
    frame_axes(ax, [p[t.shown] for t, p in zip(main, poses, strict=True)], elev, azim)
    ax.set_title(f"frame {frame}" if title is None else title)
    if path is not None:
        save_figure(ax.figure, path, dpi)
    return ax


# ------------------------------------------------------------------------------ bands
def plot_bands(t, mean, sd, labels: Sequence[str], path: str | os.PathLike | None = None, *,
               ax: Axes | None = None, k: float = 2.0, title: str | None = None,
               xlabel: str = "time (s)", ylabel: str | None = None, dpi: float = 100) -> Axes:
    """Mean +- k sd bands of chosen coordinates over time (one colour per coordinate).

    Args:
        t: (T,) times.
        mean: (T, K) or (T,) means, e.g. predicted joint coordinates.
        sd: same shape as ``mean``, standard deviations (>= 0).
        labels: (K,) legend labels, e.g. ``["RightHand y"]``.
        path: also save the figure here (PNG by default), atomically.
        ax: a 2-D Axes to draw into; a new figure when None.
        k: band half-width in standard deviations (2: about 95% under a Gaussian).
        title: Axes title.
        xlabel: x-axis label.
        ylabel: y-axis label.
        dpi: resolution of the saved file.
    Returns:
        the Axes.
    """
    t, mean, sd = _band_arrays(t, mean, sd, labels)
    if ax is None:
        fig = Figure(figsize=(6.0, 3.5), dpi=dpi, layout="constrained")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
    for c, label in enumerate(labels):
        (line,) = ax.plot(t, mean[:, c], label=label, linewidth=1.5)
        ax.fill_between(t, mean[:, c] - k * sd[:, c], mean[:, c] + k * sd[:, c],
                        color=line.get_color(), alpha=0.25, linewidth=0)
    ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    ax.set_title(f"mean \u00b1 {k:g} sd" if title is None else title)
    ax.legend(fontsize="small")
    if path is not None:
        save_figure(ax.figure, path, dpi)
    return ax


def _band_arrays(t, mean, sd, labels):
    t = np.asarray(t, dtype=np.float64)
    mean, sd = (np.asarray(x, dtype=np.float64) for x in (mean, sd))
    mean, sd = (x[:, None] if x.ndim == 1 else x for x in (mean, sd))
    if t.ndim != 1 or mean.shape != sd.shape or mean.shape != (len(t), len(labels)):
        raise BayesmotionError(f"plot_bands needs t (T,), mean and sd (T, K) and K labels; got t "
                               f"{t.shape}, mean {mean.shape}, sd {sd.shape}, {len(labels)} "
                               "labels")
    if np.any(sd < 0) or not np.all(np.isfinite(sd)) or not np.all(np.isfinite(mean)):
        raise BayesmotionError("plot_bands: mean must be finite and sd finite and >= 0")
    return t, mean, sd


def save_figure(fig: Figure, path: str | os.PathLike, dpi: float = 100) -> Path:
    """Save ``fig`` atomically; the format comes from the suffix (PNG when there is none)."""
    path = Path(path)
    fmt = path.suffix[1:].lower() or "png"
    supported = fig.canvas.get_supported_filetypes()
    if fmt not in supported:
        raise BayesmotionError(f"cannot save a figure as {path.name!r}: the suffix must be one "
                               f"of {sorted(supported)}")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi)
    return path
