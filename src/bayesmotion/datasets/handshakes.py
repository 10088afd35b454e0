"""Built-in handshakes: the real CMU two-person handshake and an emotional set derived from it.

The CMU recording (subjects 18 and 19, trial 1; see ``datasets/builtin/ACKNOWLEDGEMENT.md``) ships
with the package. :func:`load_handshakes` turns it into a labelled emotion x couple x repetition
set with the transforms of :mod:`bayesmotion.data.emotion`. **The emotion labels are synthetic**:
every trial is the same real, neutral handshake transformed by a preset style, so the set is a
controlled benchmark with a known ground truth, not acted emotional data.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from typing import NamedTuple

import numpy as np

from bayesmotion.data.bvh import parse_bvh
from bayesmotion.data.emotion import (
    CMU_BODY_PARTS,
    EMOTION_PRESETS,
    EmotionStyle,
    add_bounce,
    add_posture,
    channel_categories,
    compose_styles,
    mean_posture,
    resample_at,
    scale_amplitude,
)
from bayesmotion.data.fk import euler_matrices
from bayesmotion.data.motion import Motion, MotionDataset, Trial
from bayesmotion.data.skeleton import UP_AXIS
from bayesmotion.errors import BayesmotionError

EMOTIONS = ("neutral", "happy", "angry", "sad")
HAND = "RightHand"
# Seconds before / after the hand contact at speed 1. After the shake subject 18 turns through a
# heading of -90 deg, the gimbal lock of the root's ZYX angles: Z and X jump by ~70 deg per frame
# at 2.14-2.23 s (frames 257-268). The window keeps even the fastest trial (speed <= 1.28) before
# that, and after the recording's start (contact at 1.025 s).
WINDOW = (0.8, 0.85)
COUPLES = {"c1": (0, 1), "c2": (1, 0)}  # couple -> (actor 0, actor 1) as (subject 18, 19) index
COUPLE_STYLES = {
    "c1": EmotionStyle(),
    "c2": EmotionStyle(speed=0.95, amplitude={"arms": 1.1, "torso": 0.9},
                       posture={"Spine1": (2, 0, 0), "Neck": (3, 0, 0)}, timing={"torso": 0.04}),
}
SPEED_JITTER, AMPLITUDE_JITTER = 0.025, 0.05  # uniform relative jitter per repetition
NOISE_DEG, NOISE_HZ, NOISE_TERMS = 0.8, (0.3, 1.2), 3  # smooth angle noise: random sinusoids


@lru_cache(maxsize=1)
def _cmu_motions() -> tuple[Motion, Motion]:
    root = resources.files("bayesmotion.datasets") / "builtin"
    out = []
    for stem in ("18_01", "19_01"):
        text = (root / f"{stem}.bvh").read_text(encoding="utf-8")
        m = parse_bvh(text, where=f"bayesmotion/datasets/builtin/{stem}.bvh", name=f"cmu_{stem}")
        out.append(m.select(slice(1, None)))  # frame 0 is an added T-pose
    return tuple(out)


def load_cmu_handshake(fps: float | None = None) -> Trial:
    """The real CMU handshake (subjects 18 and 19, trial 1) as one two-actor trial.

    Args:
        fps: resample to this rate (see :meth:`Motion.resample`); default the recorded 120.
    Returns:
        a :class:`Trial` of 303 frames at 120 fps: actor 0 is subject 18, actor 1 subject 19,
        in one world frame (Y up, CMU units of about 5.6 cm), labels ``{"source": "cmu"}``.
    """
    trial = Trial(_cmu_motions(), {"source": "cmu"}, "cmu_18_19_01")
    return trial if fps is None else trial.resample(fps)


def hand_positions(motion: Motion, joint: str = HAND) -> np.ndarray:
    """(T, 3) world position of one joint: the package's FK restricted to its chain.

    Evaluates ``R_w[j] = R_w[parent] R_local[j]``, ``p_w[j] = p_w[parent] + R_w[parent] t[j]``
    (as :mod:`bayesmotion.data.fk`) in NumPy along the root-to-``joint`` chain only; equal to
    ``motion.positions()[:, j]`` to float64 precision (tested) but without a JAX compilation per
    array shape, which would dominate the loading time.
    """
    sk, v = motion.skeleton, motion.values
    chain = [sk.index(joint)]
    while sk.parents[chain[-1]] >= 0:
        chain.append(sk.parents[chain[-1]])
    rot_idx, orders = sk.rotation_layout()
    pos_idx = sk.position_layout()
    R = np.broadcast_to(np.eye(3), (len(v), 3, 3))
    p = np.zeros((len(v), 3))
    for j in reversed(chain):
        t = np.repeat(sk.offsets[j][None], len(v), axis=0)
        for a in np.flatnonzero(pos_idx[j] >= 0):
            t[:, a] = v[:, pos_idx[j, a]]
        p = p + np.einsum("tij,tj->ti", R, t)
        if orders[j]:  # upper case: intrinsic, R = R_order[0] R_order[1] ...
            n = len(orders[j])
            R = R @ euler_matrices(orders[j], v[:, rot_idx[j, :n]])
    return p


def hand_distance(trial: Trial, joint: str = HAND) -> np.ndarray:
    """(T,) distance between the two actors' ``joint`` (default the right wrist, "RightHand")."""
    if trial.n_actors != 2:
        raise BayesmotionError(f"trial {trial.name!r} has {trial.n_actors} actor(s); hand "
                               f"distance needs two")
    a, b = (hand_positions(m, joint) for m in trial.actors)
    return np.linalg.norm(a - b, axis=-1)


class _Contact(NamedTuple):
    """The recording at the hand contact."""

    t_c: float  # contact time in seconds (frame of minimal right-hand distance)
    d_min: float  # the minimal right-hand distance
    hands: np.ndarray  # (2, 3) right-hand positions of subjects 18, 19 at contact
    roots: np.ndarray  # (2, 3) root positions at contact
    refs: tuple[np.ndarray, np.ndarray]  # (C,) mean posture of each subject over the window


@lru_cache(maxsize=1)
def _contact() -> _Contact:
    trial = load_cmu_handshake()
    d = hand_distance(trial)
    k = int(np.argmin(d))
    hands = np.stack([hand_positions(m)[k] for m in trial.actors])
    roots = np.stack([m.values[k, m.skeleton.root_position_columns] for m in trial.actors])
    lo, hi = k - round(WINDOW[0] * trial.fps), k + round(WINDOW[1] * trial.fps)
    refs = tuple(mean_posture(m.select(slice(max(lo, 0), hi + 1))) for m in trial.actors)
    return _Contact(k / trial.fps, float(d[k]), hands, roots, refs)


def _clock(fps: float, speed: float, window: str, t_c: float, duration: float):
    """Output frame times (T',) around contact frame k_c, mapped to the recording's clock."""
    if window == "shake":
        k_c, k_after = round(WINDOW[0] * fps), round(WINDOW[1] * fps)
    else:  # "full": as much of the recording as the speed allows
        k_c = int(np.floor(t_c / speed * fps + 1e-9))
        k_after = int(np.floor((duration - t_c) / speed * fps + 1e-9))
    t_out = np.arange(k_c + k_after + 1) / fps
    return t_c + speed * (t_out - k_c / fps), k_c


def _jitter(rng: np.random.Generator) -> EmotionStyle:
    amp = {c: 1 + rng.uniform(-AMPLITUDE_JITTER, AMPLITUDE_JITTER) for c in ("torso", "arms")}
    return EmotionStyle(speed=1 + rng.uniform(-SPEED_JITTER, SPEED_JITTER), amplitude=amp)


def _smooth_noise(motion: Motion, rng: np.random.Generator) -> Motion:
    """Add a few random low-frequency sinusoids to every categorised rotation channel."""
    on = channel_categories(motion.skeleton, CMU_BODY_PARTS) != ""
    A = rng.normal(0.0, NOISE_DEG / np.sqrt(NOISE_TERMS), (NOISE_TERMS, on.sum()))
    f = rng.uniform(*NOISE_HZ, (NOISE_TERMS, on.sum()))
    phi = rng.uniform(0, 2 * np.pi, (NOISE_TERMS, on.sum()))
    t = np.arange(motion.n_frames)[:, None, None] / motion.fps
    v = motion.values.copy()
    v[:, on] += (A * np.sin(2 * np.pi * f * t + phi)).sum(axis=1)
    return motion.replace(values=v)


def _emote(src: Motion, ref: np.ndarray, style: EmotionStyle, times: np.ndarray, fps: float,
           k_c: int, rng: np.random.Generator) -> Motion:
    m = resample_at(src, times, fps=fps, timing=style.timing, categories=CMU_BODY_PARTS)
    m = scale_amplitude(m, style.amplitude, reference=ref, categories=CMU_BODY_PARTS)
    m = add_posture(m, style.posture)
    if style.bounce > 0:  # phase 0 at contact, alike for both actors
        m = add_bounce(m, style.bounce * m.skeleton.size(), style.bounce_hz,
                       phase=-2 * np.pi * style.bounce_hz * k_c / fps)
    return _smooth_noise(m, rng)


def _horizontal(x: np.ndarray) -> np.ndarray:
    x = np.array(x, dtype=np.float64)
    x[..., UP_AXIS] = 0.0
    return x


def _translate(motion: Motion, shift: np.ndarray) -> Motion:
    v = motion.values.copy()
    cols = motion.skeleton.root_position_columns
    v[:, cols[cols >= 0]] += shift[cols >= 0]
    return motion.replace(values=v)


def _separation(rel: np.ndarray, u: np.ndarray, d_target: float, span: float = 0.5) -> float:
    """Extra separation alpha along ``u`` making ``min_t |rel(t) + alpha u|`` hit ``d_target``.

    A grid search over ``|alpha| <= span * d_target`` (resolution ``d_target / 400``); of equally
    good values the smallest ``|alpha|`` wins.
    """
    alphas = np.linspace(-span, span, 401) * d_target
    d = np.linalg.norm(rel[None] + alphas[:, None, None] * u, axis=-1).min(axis=1)
    return float(alphas[np.argmin(np.abs(d - d_target) + 1e-9 * np.abs(alphas))])


def _meet(pair: tuple[Motion, Motion], subjects: tuple[int, int], k_c: int, c: _Contact):
    """Translate both actors horizontally (constant over the trial) so the hands meet.

    1. Each actor's right hand at the contact frame is put above its recorded contact position.
    2. Both actors move apart (or together) along the line between the recorded roots, by half
       of ``alpha`` each, with ``alpha`` such that the minimal hand distance is the recording's.
    """
    h = [hand_positions(m) for m in pair]
    shifts = [_horizontal(c.hands[s] - hk[k_c]) for s, hk in zip(subjects, h, strict=True)]
    u = _horizontal(c.roots[subjects[1]] - c.roots[subjects[0]])
    u /= np.linalg.norm(u)
    alpha = _separation((h[1] + shifts[1]) - (h[0] + shifts[0]), u, c.d_min)
    return _translate(pair[0], shifts[0] - alpha / 2 * u), _translate(pair[1],
                                                                       shifts[1] + alpha / 2 * u)


def load_handshakes(seed: int = 0, fps: float = 20.0, n_repetitions: int = 3,
                    window: str = "shake") -> MotionDataset:
    """The built-in emotional handshake set, derived from the real CMU handshake.

    **Synthetic emotion labels on real motion.** Each trial is the real CMU handshake
    (:func:`load_cmu_handshake`) with both actors transformed alike by
    ``compose_styles(EMOTION_PRESETS[emotion], COUPLE_STYLES[couple], jitter)``:

    * couples: ``"c1"`` = (subject 18, subject 19) as recorded; ``"c2"`` = the roles swapped
      (subject 19 is actor 0) with its own style (slower 0.95x, larger arm and smaller torso
      amplitude, a slightly flexed spine and neck, the torso lagging the arms by 40 ms);
    * repetitions: per-repetition jitter of speed (+-2.5 %) and torso/arm amplitude (+-5 %), and
      smooth noise on every non-root joint angle (three random sinusoids of 0.3-1.2 Hz, about
      0.8 deg in all), deterministic from ``(seed, couple, emotion, repetition)``;
    * time: both actors share one clock ``tau(t) = t_c + speed (t - t_c')`` anchored at the hand
      contact ``t_c`` (the frame of minimal right-hand distance, by FK), so the contact stays
      synchronised and a faster emotion covers more of the approach and release (the preset's
      ``peak_shift`` is not used: it would move the contact);
    * amplitude is scaled about each subject's mean posture over the neutral shake window;
    * reach compensation: posture and amplitude changes move the hands (a larger arm amplitude
      reaches further: without compensation the hands come up to about 30 % closer than recorded).
      Afterwards each actor's root is translated horizontally, by one constant vector for the
      whole trial: first so that its right hand at the contact frame is above its recorded
      contact position, then both apart (or together) along the line between the recorded
      roots, half each, so that the trial's minimal right-hand distance equals the
      recording's (6.66 CMU units between the wrists, matched to 0.25 %). The extra
      separation is up to about 2 units (11 cm, angry) in the default set; heights are kept.

    Args:
        seed: non-negative integer; the same seed gives bit-identical values.
        fps: frame rate of the trials (120 = the recording's; 20 is enough for the model).
        n_repetitions: repetitions per emotion and couple.
        window: ``"shake"``: 0.8 s before to 0.85 s after contact (times ``speed`` on the
            recording's clock), the same number of frames in every trial (34 at 20 fps, 199 at
            120 fps); it ends before subject 18 turns away, whose root Euler angles pass through
            gimbal lock (jumps of ~70 deg in Hips Z and X). ``"full"``: the whole recording at
            the trial's speed, so the frame count varies with the emotion, turn included.
    Returns:
        a :class:`MotionDataset` of ``4 x 2 x n_repetitions`` two-actor trials with labels
        ``emotion`` (levels neutral, happy, angry, sad), ``couple`` (c1, c2) and ``repetition``
        ("0", "1", ...).
    """
    if not (isinstance(seed, int | np.integer) and seed >= 0):
        raise BayesmotionError(f"seed must be a non-negative integer, got {seed!r}")
    if not (np.isfinite(fps) and fps > 0):
        raise BayesmotionError(f"fps must be positive, got {fps}")
    if not (isinstance(n_repetitions, int | np.integer) and n_repetitions >= 1):
        raise BayesmotionError(f"n_repetitions must be a positive integer, got {n_repetitions!r}")
    if window not in ("shake", "full"):
        raise BayesmotionError(f"window must be 'shake' or 'full', got {window!r}")
    src, contact = _cmu_motions(), _contact()
    trials = []
    for ci, (couple, subjects) in enumerate(COUPLES.items()):
        for ei, emotion in enumerate(EMOTIONS):
            for rep in range(n_repetitions):
                rng = np.random.default_rng([int(seed), ci, ei, rep])
                style = compose_styles(EMOTION_PRESETS[emotion], COUPLE_STYLES[couple],
                                       _jitter(rng))
                times, k_c = _clock(fps, style.speed, window, contact.t_c, src[0].duration)
                pair = tuple(_emote(src[s], contact.refs[s], style, times, fps, k_c, rng)
                             for s in subjects)
                trials.append(Trial(_meet(pair, subjects, k_c, contact),
                                    {"emotion": emotion, "couple": couple,
                                     "repetition": str(rep)}, f"{couple}_{emotion}_{rep}"))
    levels = {"emotion": EMOTIONS, "couple": tuple(COUPLES),
              "repetition": tuple(str(r) for r in range(n_repetitions))}
    return MotionDataset(tuple(trials), levels, "handshakes")
