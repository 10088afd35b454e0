"""Matched transitions: switch emotion at the target's closest training frame, then blend.

``generate(emotion=Transition(source, target, start, length, match=True))`` builds one rollout
from two:

1. the rollout of ``source`` for frames ``0 .. start - 1`` (as ``generate`` would make it);
2. the **match**: the training frame ``j`` of a ``target`` trial (the other style factors as
   given) whose last ``order + 1`` poses ``Y[j - order .. j]`` are nearest, in the model's
   normalised pose space and summed over actors and frames, to the source rollout's last
   ``order + 1`` poses -- the transition points of motion graphs (Kovar, Gleicher & Pighin
   2002), searched over every target frame; with ``within = W > 0`` the source rollout runs
   on to frame ``start + W`` and the switch frame ``s`` is searched too: every ``s`` in
   ``start .. start + W`` against every target frame, the pair with the smallest distance
   taken;
3. the rollout of ``target`` started from the training latents ``I[j - order + 1 .. j]``,
   whose generated frames become frames ``s ..`` of the result;
4. the **blend**: the difference between the two rollouts at the switch (pose and velocity
   of the last source frame against the matched target frame, per pose channel) is added to
   the target's first ``length`` frames and decays to zero along the quintic that starts
   with that difference and its velocity and ends with zero value, velocity and acceleration
   (inertialization, Bollo 2016; a velocity that would carry the difference further away is
   dropped, so the decay does not overshoot). ``length = 0`` cuts without a blend.

The poses are blended, and the angles and positions decoded from them on the source's rig,
so the motion is continuous through the switch; the latents ``I`` and ``X`` are the two
rollouts' own, cut at the switch (the latent path jumps to the target's training latents
there). The predictive variances are each rollout's own. Sampled rollouts are matched and
continued path by path (sample ``k``'s target part is drawn with seed ``seed + 1 + k``).

Why: with one-hot style vectors each emotion's latent region is its own, so a switch of style
coordinates at an arbitrary frame maps the current latents through a mapping that has no data
there, and the pose jumps (``benchmarks/results/transition_lengths.json``).
"""

from __future__ import annotations

import numpy as np

from bayesmotion.errors import BayesmotionError
from bayesmotion.model.generate import (
    Transition,
    decode_mean,
    decode_samples,
    generate,
    is_extrapolated,
    resolve_style,
    start_trial,
)
from bayesmotion.model.rollout import Rollout


def blend_offsets(x0: np.ndarray, v0: np.ndarray, length: int) -> np.ndarray:
    """(length, ...) offsets f(1) .. f(length) of the quintic f with f(0) = x0, f'(0) = v0,
    f''(0) = 0 and f = f' = f'' = 0 at ``length`` (per entry of x0, in frames); a ``v0`` of the
    same sign as ``x0`` (moving away from zero) is taken as 0. Empty for ``length = 0``."""
    x0, v0 = np.asarray(x0, np.float64), np.asarray(v0, np.float64)
    if length <= 0:
        return np.zeros((0,) + x0.shape)
    v0 = np.where(x0 * v0 > 0, 0.0, v0)
    T = float(length)
    A = -(6 * v0 * T + 12 * x0) / (2 * T**5)
    B = (16 * v0 * T + 30 * x0) / (2 * T**4)
    C = -(12 * v0 * T + 20 * x0) / (2 * T**3)
    t = np.arange(1, length + 1, dtype=np.float64).reshape((-1,) + (1,) * x0.ndim)
    return A * t**5 + B * t**4 + C * t**3 + v0 * t + x0


def target_frames(model, target_coords: dict) -> list[tuple[int, int]]:
    """(trial, first frame) ... : each training trial whose labels are the target's (every
    factor whose coordinates are a vertex), with its first frame in the stacked data."""
    out, first = [], 0
    for r, rec in enumerate(model.trials):
        if all(model.levels[f][int(np.argmax(c))] == rec.labels[f]
               for f, c in target_coords.items()):
            out.append((r, first))
        first += rec.n_frames
    return out


def _nearest(model, lasts: np.ndarray, target_coords: dict) -> tuple[int, int, int, float]:
    """(candidate index, trial, frame within it, squared distance): over every candidate window
    ``lasts`` (S, A, m, D) and every target training frame ``j`` whose poses
    ``Y[j - m + 1 .. j]`` (all actors) it is compared with, the nearest pair; on a tie the
    earliest candidate, then the first trial, then the earliest frame."""
    S, m = lasts.shape[0], lasts.shape[2]
    rows = []  # per target trial: (trial, (S,) distances, (S,) frames)
    for r, first in target_frames(model, target_coords):
        T = model.trials[r].n_frames
        if T < max(m, model.spec.order):
            continue
        # windows ending at j = m - 1 .. T - 1, against every candidate: (S, T - m + 1)
        d = sum(((np.lib.stride_tricks.sliding_window_view(
                     np.asarray(model.data.Y[a][first:first + T]), m, axis=0)[None]
                  - lasts[:, a].transpose(0, 2, 1)[:, None]) ** 2).sum((2, 3))
                for a in range(model.n_actors))
        j = np.argmin(d, axis=1)
        rows.append((r, d[np.arange(S), j], j + m - 1))
    if not rows:
        raise BayesmotionError("a matched Transition needs a training trial of the target "
                               f"with at least {max(m, model.spec.order)} frames")
    d = np.stack([row[1] for row in rows], axis=1)  # (S, trials)
    i, k = np.unravel_index(int(np.argmin(d)), d.shape)
    r, _, j = rows[k]
    return int(i), int(r), int(j[i]), float(d[i, k])


def match_frame(model, last: np.ndarray, target_coords: dict) -> tuple[int, int, float]:
    """(trial, frame within it, squared distance): the target training frame ``j`` whose poses
    ``Y[j - m + 1 .. j]`` (all actors) are nearest to ``last`` (A, m, D)."""
    _, r, j, d = _nearest(model, np.asarray(last)[None], target_coords)
    return r, j, d


def match_switch(model, Y: np.ndarray, first: int, last: int,
                 target_coords: dict) -> tuple[int, int, int, float]:
    """(switch frame s, trial, frame within it, squared distance): over every switch frame
    ``s`` in ``first .. last`` (the source poses ``Y`` (A, >= last, D) before ``s`` are matched),
    the one whose :func:`match_frame` is nearest, all compared at once; the earliest on a
    tie."""
    m = model.spec.order + 1
    lasts = np.stack([Y[:, s - m:s] for s in range(first, last + 1)])
    i, r, j, d = _nearest(model, lasts, target_coords)
    return first + i, r, j, d


def _splice_poses(src_Y: np.ndarray, tgt_Y: np.ndarray, start: int, o: int,
                  length: int) -> np.ndarray:
    """(A, T, D) poses: the source's frames before ``start``, then the target's generated
    frames with the switch's difference blended out over ``length`` frames."""
    out = np.concatenate([src_Y[:, :start], tgt_Y[:, o:]], axis=1)
    x0 = src_Y[:, start - 1] - tgt_Y[:, o - 1]
    v0 = (src_Y[:, start - 1] - src_Y[:, start - 2]) - (tgt_Y[:, o - 1] - tgt_Y[:, o - 2])
    L = min(length, out.shape[1] - start)
    if L > 0:
        out[:, start:start + L] += np.swapaxes(blend_offsets(x0, v0, length)[:L], 0, 1)
    return out


def check_matched(model, t: Transition, n_frames: int) -> int:
    """The first switch frame of a matched Transition, checked against the model and the
    length (the last is that plus ``t.within``)."""
    o = model.spec.order
    if not isinstance(t.target, str):
        raise BayesmotionError("a matched Transition's target must be a level name (it is "
                               f"matched against that level's training frames), got {t.target!r}")
    if isinstance(t.start, bool) or not isinstance(t.start, int | np.integer) \
            or not o + 1 <= t.start < n_frames:
        raise BayesmotionError(f"a matched Transition's start must be an integer in "
                               f"[{o + 1}, {n_frames - 1}] (frames before it come from the "
                               f"source), got {t.start!r}")
    if isinstance(t.length, bool) or not isinstance(t.length, int | np.integer) \
            or t.length < 0:
        raise BayesmotionError(f"a Transition's length must be an integer >= 0, got "
                               f"{t.length!r}")
    if isinstance(t.within, bool) or not isinstance(t.within, int | np.integer) \
            or not 0 <= t.within <= n_frames - 1 - t.start:
        raise BayesmotionError(f"a matched Transition's within must be an integer in "
                               f"[0, {n_frames - 1 - t.start}] (the switch comes at frame "
                               f"{n_frames - 1} at the latest), got {t.within!r}")
    return int(t.start)


def matched_transition(model, factor: str, t: Transition, n_frames: int, n_samples: int = 0,
                       start=None, seed: int = 0, lookahead: float = 0.0,
                       sample_memory: int = 0, dynamics_style: str = "requested",
                       **styles) -> Rollout:
    """The rollout of a matched Transition of style factor ``factor`` (module docstring);
    ``styles`` holds every other factor's value, as given to ``generate``."""
    s0 = check_matched(model, t, n_frames)
    o = model.spec.order
    common = {"seed": seed, "lookahead": lookahead, "sample_memory": sample_memory,
              "dynamics_style": dynamics_style}

    def run(value, frames, first, n, **kw):
        return generate(model, n_frames=frames, n_samples=n, start=first,
                        **{**styles, factor: value}, **{**common, **kw})

    # the source runs to the last frame the switch may come at
    src = run(t.source, s0 + t.within, start, n_samples)

    def coords_switching_at(switch):
        return {f: resolve_style(model, f, styles.get(f, model.levels[f][0]) if f != factor
                                 else t._replace(start=switch), n_frames)
                for f in model.spec.factors if f in model.levels}

    target_coords = {f: c[-1] for f, c in coords_switching_at(s0).items()}
    slices = model.trial_slices()

    def continue_from(Y, n, seed_k):
        s, r, j, dist = match_switch(model, Y, s0, s0 + t.within, target_coords)
        I0 = np.asarray(model.params["I"][slices[r]])[j - o + 1:j + 1]
        tgt = run(t.target, n_frames - s + o, I0, n, seed=seed_k)
        return tgt, (s, r, j, dist)

    def cut(a, b, s):
        return np.concatenate([a[..., :s, :], b[..., o:, :]], axis=-2)

    tgt, (s, r, j, dist) = continue_from(src.Y, 0, seed)
    # the style coordinates switch where the mean rollout does
    coords = coords_switching_at(s)
    trial0 = start_trial(model, {f: c[:1] for f, c in coords.items()}, start)
    Y = _splice_poses(src.Y, tgt.Y, s, o, t.length)
    mean = decode_mean(model, cut(src.X, tgt.X, s), cut(src.X_var, tgt.X_var, s)[..., 0], Y,
                       cut(src.Y_var, tgt.Y_var, s)[..., 0], trial0)
    I = np.concatenate([src.I[:s], tgt.I[o:]])
    I_var = np.concatenate([src.I_var[:s], tgt.I_var[o:]])
    samples = sample_var = None
    if n_samples:
        paths = {"I": [], "X": [], "Y": []}
        for k in range(n_samples):  # each path at its own best switch frame
            tk, (sk, *_) = continue_from(src.samples["Y"][k], 1, seed + 1 + k)
            paths["I"].append(np.concatenate([src.samples["I"][k, :sk],
                                              tk.samples["I"][0, o:]]))
            paths["X"].append(cut(src.samples["X"][k], tk.samples["X"][0], sk))
            paths["Y"].append(_splice_poses(src.samples["Y"][k], tk.samples["Y"][0], sk, o,
                                            t.length))
        samples = {k: np.stack(v) for k, v in paths.items()}
        samples.update(decode_samples(model, samples["Y"], trial0))
        sample_var = {k: v.var(0) for k, v in samples.items()}
    desc = (f"{src.start}; from frame {s} the target continues training trial {r} "
            f"({model.trials[r].name}) after its frame {j} (pose distance {np.sqrt(dist):.3g})")
    return Rollout(fps=model.fps, styles=coords,
                   extrapolated=any(is_extrapolated(c) for c in coords.values()), start=desc,
                   n_observed=o, I=I, I_var=I_var, skeletons=mean.pop("skeletons"),
                   samples=samples, sample_var=sample_var, **mean)
