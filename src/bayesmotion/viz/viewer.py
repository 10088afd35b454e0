"""An interactive 3-D motion viewer as one self-contained HTML page (no network, no library).

The page plays generated or recorded motion, scrubs through time, orbits the camera (drag;
the wheel zooms), overlays sampled rollouts as faint skeletons and the mean +- 2 sd of
every joint position as a translucent disc, and switches between the clips it was given (e.g.
one per emotion and an interpolation series precomputed by the report). Its script is plain
JavaScript written for this page, drawing on a 2-D canvas with a perspective projection, so the
file works offline and carries no third-party code.

Clips come from a :class:`~bayesmotion.model.rollout.Rollout` (:func:`rollout_clip`), from
motions such as a BVH file read with :func:`bayesmotion.data.read_bvh` (:func:`motion_clip`), or
from files on disk (:func:`load_clips`: BVH files or rollout files written by
:meth:`Rollout.save <bayesmotion.model.rollout.Rollout.save>`). :func:`viewer_html` makes the
page, :func:`viewer_fragment` the part that :mod:`bayesmotion.app.report` embeds, and
:func:`write_viewer` writes a page atomically. ``bayesmotion view FILE...`` is the same from the
command line.

Positions are data coordinates with Y up (both data sets); the page draws Y up.
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayesmotion.data.bvh import read_bvh
from bayesmotion.data.files import atomic_write_text
from bayesmotion.data.motion import Motion, Trial
from bayesmotion.errors import BayesmotionError
from bayesmotion.model.rollout import Rollout, load_rollout
from bayesmotion.viz.plots import HIDDEN_JOINTS

COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")
"""Actor colours (matplotlib's tab:blue, tab:red, tab:green, tab:purple, as the figures)."""
MAX_SAMPLES = 8
"""Sampled rollouts drawn per clip at most (more add little but page weight)."""
DECIMALS = 2
"""Decimals kept of each position in the page (data units, centimetres in both data sets)."""


@dataclass(frozen=True)
class ViewerClip:
    """One clip the viewer can show.

    Attributes:
        name: shown in the clip list.
        fps: frames per second.
        parents: per actor, the parent row of each joint (-1 for a root).
        hidden: per actor, rows not drawn (nor their bones).
        mean: per actor, (T, J, 3) positions.
        sd: per actor, (T, J) standard deviation of each joint's position (the root mean
            square over x, y, z), or None.
        samples: per actor, (S, T, J, 3) sampled positions, or None.
        group: a heading for the clip list (e.g. ``"emotion"``, ``"interpolation"``).
    """

    name: str
    fps: float
    parents: tuple[tuple[int, ...], ...]
    hidden: tuple[frozenset, ...]
    mean: tuple[np.ndarray, ...]
    sd: tuple[np.ndarray, ...] | None = None
    samples: tuple[np.ndarray, ...] | None = None
    group: str = ""

    def __post_init__(self):
        A = len(self.mean)
        if A == 0 or len(self.parents) != A or len(self.hidden) != A:
            raise BayesmotionError(f"clip {self.name!r}: give parents, hidden and mean for each "
                                   f"of the same actors (got {len(self.parents)}, "
                                   f"{len(self.hidden)}, {A})")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise BayesmotionError(f"clip {self.name!r}: fps must be positive, got {self.fps}")
        T = self.mean[0].shape[0]
        for a, m in enumerate(self.mean):
            if m.ndim != 3 or m.shape[2] != 3 or m.shape[0] != T or T == 0:
                raise BayesmotionError(f"clip {self.name!r}: actor {a}'s positions must be "
                                       f"(T, J, 3) with the same T > 0 for every actor, got "
                                       f"{m.shape}")
            if m.shape[1] != len(self.parents[a]):
                raise BayesmotionError(f"clip {self.name!r}: actor {a} has {m.shape[1]} joints "
                                       f"but {len(self.parents[a])} parents")
            if not np.all(np.isfinite(m)):
                raise BayesmotionError(f"clip {self.name!r}: actor {a}'s positions are not all "
                                       "finite")
        if self.sd is not None:
            for a, s in enumerate(self.sd):
                if s.shape != self.mean[a].shape[:2] or not np.all(np.isfinite(s)):
                    raise BayesmotionError(f"clip {self.name!r}: actor {a}'s sd must be finite "
                                           f"and (T, J) = {self.mean[a].shape[:2]}, got "
                                           f"{s.shape}")
        if self.samples is not None:
            for a, s in enumerate(self.samples):
                if s.ndim != 4 or s.shape[1:] != self.mean[a].shape or not np.all(np.isfinite(s)):
                    raise BayesmotionError(f"clip {self.name!r}: actor {a}'s samples must be "
                                           f"finite and (S, T, J, 3) with (T, J, 3) = "
                                           f"{self.mean[a].shape}, got {s.shape}")

    @property
    def n_frames(self) -> int:
        return self.mean[0].shape[0]

    def to_json(self) -> dict:
        """The clip as the page's script reads it (positions rounded to :data:`DECIMALS`)."""
        def r(x):
            return np.round(np.asarray(x, dtype=np.float64), DECIMALS).tolist()

        actors = []
        for a in range(len(self.mean)):
            bones = [[j, p] for j, p in enumerate(self.parents[a])
                     if p >= 0 and not {j, p} & self.hidden[a]]
            shown = [j for j in range(len(self.parents[a])) if j not in self.hidden[a]]
            actors.append({
                "color": COLORS[a % len(COLORS)], "bones": bones, "joints": shown,
                "mean": r(self.mean[a]),
                "sd": None if self.sd is None else r(self.sd[a]),
                "samples": (None if self.samples is None or len(self.samples[a]) == 0
                            else r(self.samples[a])),
            })
        return {"name": self.name, "group": self.group, "fps": float(self.fps),
                "n_frames": self.n_frames, "actors": actors}


def _hidden(names: Sequence[str], hide: Sequence = HIDDEN_JOINTS) -> frozenset:
    return frozenset(names.index(h) for h in hide if h in names)


def rollout_clip(r: Rollout, name: str, group: str = "",
                 max_samples: int = MAX_SAMPLES) -> ViewerClip:
    """A rollout's mean motion, its +- 2 sd discs (the one-step predictive variance, plus the
    samples' spread when it has samples) and up to ``max_samples`` sampled rollouts."""
    var = np.asarray(r.positions_var, dtype=np.float64)
    if r.sample_var is not None and "positions" in r.sample_var:
        var = var + np.asarray(r.sample_var["positions"], dtype=np.float64)
    sd = np.sqrt(np.mean(np.maximum(var, 0.0), axis=-1))  # (A, T, J)
    samples = None
    if r.samples is not None and "positions" in r.samples and max_samples > 0:
        s = np.asarray(r.samples["positions"])[:max_samples]  # (S, A, T, J, 3)
        samples = tuple(s[:, a] for a in range(s.shape[1]))
    A = r.positions.shape[0]
    return ViewerClip(name=name, fps=float(r.fps),
                      parents=tuple(tuple(sk.parents) for sk in r.skeletons),
                      hidden=tuple(_hidden(sk.names) for sk in r.skeletons),
                      mean=tuple(np.asarray(r.positions[a], dtype=np.float64) for a in range(A)),
                      sd=tuple(sd), samples=samples, group=group)


def motion_clip(motions, name: str, group: str = "") -> ViewerClip:
    """Recorded (or generated) motions, one per actor: a Motion, a Trial, or a sequence of
    Motions of the same length and frame rate."""
    if isinstance(motions, Trial):
        motions = motions.actors
    elif isinstance(motions, Motion):
        motions = (motions,)
    motions = tuple(motions)
    if not motions or not all(isinstance(m, Motion) for m in motions):
        raise BayesmotionError("motion_clip takes a Motion, a Trial or a sequence of Motions")
    if len({m.n_frames for m in motions}) != 1 or len({m.fps for m in motions}) != 1:
        raise BayesmotionError(f"clip {name!r}: the actors' motions differ in length or frame "
                               f"rate: {[(m.n_frames, m.fps) for m in motions]}")
    return ViewerClip(name=name, fps=float(motions[0].fps),
                      parents=tuple(tuple(m.skeleton.parents) for m in motions),
                      hidden=tuple(_hidden(m.skeleton.names) for m in motions),
                      mean=tuple(m.positions() for m in motions), group=group)


def load_clips(paths) -> list[ViewerClip]:
    """Clips from files: rollout files (``.npz``, :meth:`Rollout.save`), one clip each, or BVH
    files, together one clip with one actor per file (same length and frame rate)."""
    paths = [Path(p) for p in ([paths] if isinstance(paths, str | os.PathLike) else paths)]
    if not paths:
        raise BayesmotionError("give at least one file to view")
    suffixes = {p.suffix.lower() for p in paths}
    if suffixes == {".npz"}:
        return [rollout_clip(load_rollout(p), p.stem, group="rollout") for p in paths]
    if suffixes == {".bvh"}:
        return [motion_clip([read_bvh(p) for p in paths], " + ".join(p.stem for p in paths),
                            group="BVH")]
    raise BayesmotionError(f"cannot view {', '.join(p.name for p in paths)}: give rollout "
                           "files (.npz, each one clip) or BVH files (one clip, a file per "
                           "actor), not both")


_STYLE = """
.bm-viewer{font-family:sans-serif;max-width:960px;border:1px solid #ccc;padding:6px;
  background:#fafafa}
.bm-viewer canvas{width:100%;height:auto;background:#fff;cursor:grab;touch-action:none;
  display:block}
.bm-viewer .bm-bar{display:flex;flex-wrap:wrap;gap:8px;align-items:center;margin-top:6px}
.bm-viewer .bm-time{flex:1;min-width:200px}
.bm-viewer .bm-note{color:#555;font-size:90%}
"""

# The page's script: one viewer per element of class "bm-viewer"; its clips are the JSON in
# the element's <script type="application/json">. Camera: orbit about the clip's centre
# (azimuth, elevation, distance), perspective projection; Y is up.
_SCRIPT = r"""
(function () {
  "use strict";
  function setup(root) {
    if (root.dataset.bmReady) return;  // each fragment's script sets up every viewer once
    root.dataset.bmReady = "1";
    var clips = JSON.parse(root.querySelector("script.bm-data").textContent);
    var canvas = root.querySelector("canvas"), ctx = canvas.getContext("2d");
    var playBtn = root.querySelector(".bm-play"), time = root.querySelector(".bm-time");
    var pick = root.querySelector(".bm-clip"), label = root.querySelector(".bm-frame");
    var showSamples = root.querySelector(".bm-samples"), showSd = root.querySelector(".bm-sd");
    var view = {az: -0.6, el: 0.25, zoom: 1.0}, clip = null, frame = 0, playing = false;
    var last = null, box = null, pending = null;
    clips.forEach(function (c, i) {
      var o = document.createElement("option");
      o.value = String(i);
      o.textContent = (c.group ? c.group + ": " : "") + c.name;
      pick.appendChild(o);
    });
    function bounds(c) {
      var lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
      c.actors.forEach(function (a) {
        a.mean.forEach(function (f) {
          a.joints.forEach(function (j) {
            for (var k = 0; k < 3; k++) {
              lo[k] = Math.min(lo[k], f[j][k]); hi[k] = Math.max(hi[k], f[j][k]);
            }
          });
        });
      });
      if (!(hi[0] >= lo[0])) { lo = [0, 0, 0]; hi = [0, 0, 0]; }  // no joint drawn
      var size = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-6);
      return {center: [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2],
              floor: lo[1], size: size};
    }
    function choose(i) {
      clip = clips[i]; box = bounds(clip); frame = 0;
      time.max = String(clip.n_frames - 1); time.value = "0";
      var hasSamples = clip.actors.some(function (a) { return a.samples; });
      var hasSd = clip.actors.some(function (a) { return a.sd; });
      showSamples.disabled = !hasSamples; showSd.disabled = !hasSd;
      draw();
    }
    function project(p) {
      var x = p[0] - box.center[0], y = p[1] - box.center[1], z = p[2] - box.center[2];
      var ca = Math.cos(view.az), sa = Math.sin(view.az);
      var ce = Math.cos(view.el), se = Math.sin(view.el);
      var x1 = ca * x + sa * z, z1 = -sa * x + ca * z;          // turn about Y
      var y2 = ce * y - se * z1, z2 = se * y + ce * z1;         // tilt about X
      var dist = 2.2 * box.size / view.zoom, depth = dist - z2;
      var near = 0.05 * box.size, s = 1.54 * Math.min(canvas.width, canvas.height) /
        Math.max(depth, near);  // pixels per data unit
      // [x, y, pixels per unit, in front of the camera]
      return [canvas.width / 2 + s * x1, canvas.height / 2 - s * y2, s, depth > near];
    }
    function line(a, b) {
      if (!a[3] || !b[3]) return;  // behind the camera
      ctx.beginPath(); ctx.moveTo(a[0], a[1]); ctx.lineTo(b[0], b[1]); ctx.stroke();
    }
    function skeleton(pose, actor, width, alpha) {
      ctx.globalAlpha = alpha; ctx.strokeStyle = actor.color; ctx.lineWidth = width;
      var q = pose.map(project);
      actor.bones.forEach(function (b) { line(q[b[0]], q[b[1]]); });
      return q;
    }
    function floor() {
      var s = 0.75 * box.size, n = 6, y = box.floor, c = box.center;
      ctx.globalAlpha = 1; ctx.strokeStyle = "#e2e2e2"; ctx.lineWidth = 1;
      for (var i = -n; i <= n; i++) {
        var t = i / n * s;
        line(project([c[0] + t, y, c[2] - s]), project([c[0] + t, y, c[2] + s]));
        line(project([c[0] - s, y, c[2] + t]), project([c[0] + s, y, c[2] + t]));
      }
    }
    function draw() {
      var w = canvas.clientWidth || canvas.width;
      if (canvas.width !== w) { canvas.width = w; canvas.height = Math.round(w * 0.6); }
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.clearRect(0, 0, canvas.width, canvas.height);
      ctx.lineCap = "round";
      floor();
      var f = Math.min(Math.floor(frame), clip.n_frames - 1);
      clip.actors.forEach(function (a) {
        if (a.samples && showSamples.checked) {
          a.samples.forEach(function (s) { skeleton(s[f], a, 1.5, 0.25); });
        }
      });
      clip.actors.forEach(function (a) {
        var q = skeleton(a.mean[f], a, 3, 1.0);
        if (a.sd && showSd.checked) {
          ctx.globalAlpha = 0.18; ctx.fillStyle = a.color;
          a.joints.forEach(function (j) {
            var r = 2 * a.sd[f][j] * q[j][2];
            if (r > 0.5 && q[j][3]) { ctx.beginPath(); ctx.arc(q[j][0], q[j][1], r, 0, 2 * Math.PI);
                           ctx.fill(); }
          });
        }
      });
      ctx.globalAlpha = 1;
      time.value = String(f);
      label.textContent = "frame " + (f + 1) + " / " + clip.n_frames + "  (" +
        (f / clip.fps).toFixed(2) + " s)";
    }
    function tick(now) {
      pending = null;
      if (!playing) { last = null; return; }
      if (last !== null) {
        frame += (now - last) / 1000 * clip.fps;
        if (frame >= clip.n_frames) frame = frame % clip.n_frames;
      }
      last = now; draw(); pending = window.requestAnimationFrame(tick);
    }
    function play(on) {
      playing = on; playBtn.textContent = on ? "pause" : "play";
      if (pending !== null) { window.cancelAnimationFrame(pending); pending = null; }
      last = null;
      if (on) pending = window.requestAnimationFrame(tick);
    }
    playBtn.addEventListener("click", function () { play(!playing); });
    time.addEventListener("input", function () { play(false); frame = +time.value; draw(); });
    pick.addEventListener("change", function () { choose(+pick.value); });
    showSamples.addEventListener("change", draw); showSd.addEventListener("change", draw);
    var drag = null;
    canvas.addEventListener("pointerdown", function (e) {
      drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", function (e) {
      if (!drag) return;
      view.az += (e.clientX - drag[0]) * 0.01;
      view.el = Math.max(-1.5, Math.min(1.5, view.el + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY]; draw();
    });
    ["pointerup", "pointercancel", "lostpointercapture"].forEach(function (n) {
      canvas.addEventListener(n, function () { drag = null; });
    });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      // the camera stays outside the clip's bounding sphere: distance 2.2 / zoom >= 1.1 sizes
      view.zoom = Math.max(0.2, Math.min(2.0, view.zoom * Math.exp(-e.deltaY * 0.001))); draw();
    }, {passive: false});
    window.addEventListener("resize", draw);
    choose(0);
  }
  document.querySelectorAll(".bm-viewer").forEach(setup);
})();
"""


def _data_json(clips: Sequence[ViewerClip]) -> str:
    if not clips:
        raise BayesmotionError("the viewer needs at least one clip")
    text = json.dumps([c.to_json() for c in clips], separators=(",", ":"), allow_nan=False)
    # inside <script> no "<" may appear ("</script>" would end it, "<!--" open a comment):
    # "\u003c" is the same character to JSON.parse
    return text.replace("<", "\\u003c")


def viewer_fragment(clips: Sequence[ViewerClip], note: str = "") -> str:
    """The viewer as an HTML fragment (style, controls, data, script) for a page."""
    note_html = f'<div class="bm-note">{html.escape(note)}</div>' if note else ""
    return (f"<style>{_STYLE}</style>"
            '<div class="bm-viewer"><canvas width="900" height="540"></canvas>'
            '<div class="bm-bar"><button type="button" class="bm-play">play</button>'
            '<input type="range" class="bm-time" min="0" max="0" value="0" '
            'aria-label="frame">'
            '<span class="bm-frame"></span></div>'
            '<div class="bm-bar"><select class="bm-clip" aria-label="clip"></select>'
            '<label><input type="checkbox" class="bm-samples" checked> sampled rollouts'
            '</label><label><input type="checkbox" class="bm-sd" checked> mean &plusmn; 2 sd'
            '</label><span class="bm-note">drag to turn, wheel to zoom</span></div>'
            f'{note_html}<script type="application/json" class="bm-data">{_data_json(clips)}'
            f"</script><script>{_SCRIPT}</script></div>")


def viewer_html(clips: Sequence[ViewerClip], title: str = "bayesmotion viewer",
                note: str = "") -> str:
    """A whole page holding the viewer (self-contained: no file or network access)."""
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title></head><body><h1 style='font-family:sans-serif'>{html.escape(title)}</h1>"
            f"{viewer_fragment(clips, note)}</body></html>")


def write_viewer(path, clips: Sequence[ViewerClip], title: str = "bayesmotion viewer",
                 note: str = "") -> Path:
    """Write :func:`viewer_html` to ``path`` atomically; returns the path."""
    return atomic_write_text(Path(path), viewer_html(clips, title, note))
