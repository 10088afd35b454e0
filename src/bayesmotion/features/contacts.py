"""Foot contacts of a motion and a foot-skate clean-up that keeps planted feet still.

**Contacts** (the rule :mod:`bayesmotion.evaluation.naturalness` measures foot sliding with): a
foot is in contact where its ankle or toe is within ``contact_height`` leg lengths of that
joint's lowest height in the clip (Y up), with no speed gate, since a speed gate would hide
exactly the sliding a clean-up has to remove. The contact point is whichever of ankle and toe is
nearer its own floor height in that frame (the heel at heel strike, the toe at push-off).

**Clean-up** (:func:`pin_feet`): a generated motion's legs and its root path come from separate
outputs of the model, so a planted foot can glide. The clean-up moves the whole body in the
ground plane so that the contact points stay where they are: over the step from frame t-1 to t
the root is displaced by

    delta_t = - sum_f w_tf d_tf / max(1, sum_f w_tf),    w_tf = c_tf / (1 + (v_tf / v0)^2),

where ``d_tf`` is foot f's contact-point displacement (x, z) over that step, ``v_tf`` its speed
(L/s), ``c_tf`` 1 when the foot is in contact at both t-1 and t (else 0) and ``v0`` the
``speed_scale``. The speed weight keeps steps at the edges of a contact, where at low frame
rates the foot is still arriving or already leaving, from dragging the body along; a foot that
glides slower than ``v0`` is held almost exactly (at ``v0 / 3`` 90 % of its glide is removed).
With one foot planted the body follows it; with both, their weighted mean. The displacements
are then smoothed ``smooth`` times by the binomial filter [1, 2, 1] / 4, so the root's velocity
changes over a few frames rather than at one. Only the root's horizontal translation changes:
joint angles, the root's height and its rotation are kept, so every frame's pose is the
original one. It is the root-correction step of Kovar, Schreiner & Gleicher's footskate
clean-up (2002); alone it leaves a foot whose own leg slides relative to the body (both feet
planted, moving apart) with that part of its sliding.

**Legs** (:func:`plant_legs`, ``pin_feet(..., legs=True)``): their inverse kinematics on the
legs, after the root. Over each contact run of a foot the contact point's weighted glide
``Q_t = sum_u w_u d_u`` (the steps and weights above, summed from the run's first frame) is
taken out around its mean: the foot is shifted in the ground plane by ``mean(Q) - Q_t``, so
with full weights the contact point stays exactly where it was on average through the run.
Between runs the shift is interpolated linearly (held before the first run and after the
last). Each ankle is then put at its shifted position, at its own height, by two-bone inverse
kinematics on hip and knee (:func:`bayesmotion.data.ik.two_bone_ik`: the knee keeps its bending
plane, the bones their lengths), and the ankle's rotation is set so that the foot keeps its
orientation in the world, which keeps the toe's height and so the contacts. Only the hips',
knees' and ankles' rotation channels change, written back in the file's Euler orders nearest
their old values. A shift beyond the leg's reach is met as nearly as the straight leg allows.

On the real Bandai walks and runs at 10 fps (which glide little) the clean-up changes the
jerk by less than 3 % and lowers the measured sliding to 0.70-0.95 of its value; after a
uniform glide of 0.3 L/s is added to those clips, it brings their sliding back to 0.74-0.96 of
the clips' own (``tests/test_contacts.py`` checks both). On generated clips:
``benchmarks/results/foot_contacts.json``.
"""

from __future__ import annotations

import numpy as np

from bayesmotion.data.fk import layout_key, numpy_transforms
from bayesmotion.data.ik import euler_channels, two_bone_ik
from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError
from bayesmotion.features.joint_map import JointMap, resolve_indices
from bayesmotion.features.movement import foot_contacts, leg_length
from bayesmotion.features.pose import semantic_positions

CONTACT_HEIGHT = 0.03
"""Default contact threshold in leg lengths: a swinging toe clears the floor by only
0.05-0.15 L in the Bandai walks, so without a speed gate the threshold must be tighter than
:func:`~bayesmotion.features.movement.foot_contacts`' 0.1 L (0.03 L is about 2.5 cm)."""
SPEED_SCALE = 1.0
"""Default ``speed_scale`` (L/s) of :func:`pin_feet`: contact steps faster than this count
less (module docstring)."""
SMOOTH = 1
"""Default passes of the [1, 2, 1] / 4 filter over :func:`pin_feet`'s displacements."""
GROUND = (0, 2)
"""The ground plane's axes (x, z); Y is up."""


def toe_leads(p: dict[str, np.ndarray], side: str) -> np.ndarray:
    """(T,) True where foot ``side``'s ("l" or "r") toe, not its ankle, is the contact point:
    the toe is nearer its own floor height (lowest height in the clip) than the ankle is."""
    h = {j: p[j][:, 1] - p[j][:, 1].min() for j in (f"{side}_foot", f"{side}_toe")}
    return h[f"{side}_toe"] <= h[f"{side}_foot"]


def sliding_contacts(p: dict[str, np.ndarray], fps: float, L: float,
                     contact_height: float = CONTACT_HEIGHT) -> np.ndarray:
    """(T, 2) bool left/right contacts by height alone (module docstring)."""
    return foot_contacts(p, fps, L, contact_height, contact_speed=np.inf)


def contact_steps(p: dict[str, np.ndarray]) -> np.ndarray:
    """(T, 2, 2) ground-plane displacement of each foot's contact point (left, right) from the
    previous frame, in the positions' unit; row 0 is zero. The contact point is chosen at
    frame t (:func:`toe_leads`) and its own joint's displacement is taken, so a switch from
    heel to toe is not a jump."""
    out = []
    for s in "lr":
        d = {j: np.diff(p[j][:, GROUND], axis=0, prepend=p[j][:1, GROUND])
             for j in (f"{s}_foot", f"{s}_toe")}
        out.append(np.where(toe_leads(p, s)[:, None], d[f"{s}_toe"], d[f"{s}_foot"]))
    return np.stack(out, axis=1)


def step_weights(contacts: np.ndarray, steps: np.ndarray, speed_scale: float) -> np.ndarray:
    """(T, 2) weights ``w_tf`` of the steps t-1 -> t (module docstring) from (T, 2) contacts and
    (T, 2) contact-point speeds in the unit of ``speed_scale``."""
    c = np.asarray(contacts, dtype=np.float64)
    both = np.minimum(c, np.concatenate([c[:1], c[:-1]]))
    return both / (1.0 + (steps / speed_scale) ** 2)


def binomial_smooth(x: np.ndarray, passes: int) -> np.ndarray:
    """``passes`` applications of [1, 2, 1] / 4 along axis 0, edges repeated."""
    for _ in range(passes):
        padded = np.concatenate([x[:1], x, x[-1:]])
        x = 0.25 * padded[:-2] + 0.5 * padded[1:-1] + 0.25 * padded[2:]
    return x


def pin_offset(positions: np.ndarray, skeleton_or_names, fps: float,
               joint_map: JointMap | None = None, *, contact_height: float = CONTACT_HEIGHT,
               speed_scale: float = SPEED_SCALE, smooth: int = SMOOTH) -> np.ndarray:
    """(T, 3) translation that keeps planted feet still (module docstring; its Y is 0).

    Args:
        positions: (T, J, 3) world joint positions, Y up.
        skeleton_or_names: the skeleton or its (J,) joint names.
        fps: frames per second.
        joint_map: which joints play the semantic roles (auto-detected when None).
        contact_height: contact threshold in leg lengths.
        speed_scale: L/s; contact steps faster than this count less (> 0).
        smooth: passes of the [1, 2, 1] / 4 filter over the displacements (>= 0).
    """
    if not (isinstance(speed_scale, int | float) and np.isfinite(speed_scale)
            and speed_scale > 0):
        raise BayesmotionError(f"speed_scale must be a positive number of leg lengths per "
                               f"second, got {speed_scale!r}")
    if isinstance(smooth, bool) or not isinstance(smooth, int | np.integer) or smooth < 0:
        raise BayesmotionError(f"smooth must be an integer >= 0, got {smooth!r}")
    p = semantic_positions(positions, skeleton_or_names, joint_map)
    L = leg_length(p)
    d = contact_steps(p)
    w = step_weights(sliding_contacts(p, fps, L, contact_height),
                     np.linalg.norm(d, axis=-1) * fps / L, speed_scale)
    delta = -np.einsum("tf,tfk->tk", w, d) / np.maximum(w.sum(1, keepdims=True), 1.0)
    out = np.zeros((positions.shape[0], 3))
    out[:, GROUND] = np.cumsum(binomial_smooth(delta, int(smooth)), axis=0)
    return out


def root_translation_columns(skeleton: Skeleton) -> np.ndarray:
    """Column indices of the root's (Xposition, Zposition) channels in a frame row."""
    names = skeleton.channels[0]
    try:
        return np.array([names.index("Xposition"), names.index("Zposition")])
    except ValueError:
        raise BayesmotionError(f"the root joint {skeleton.names[0]!r} has no Xposition and "
                               f"Zposition channels ({', '.join(names)}): its path cannot be "
                               "moved") from None


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each maximal run of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


def foot_corrections(p: dict[str, np.ndarray], fps: float, L: float, *,
                     contact_height: float = CONTACT_HEIGHT,
                     speed_scale: float = SPEED_SCALE) -> np.ndarray:
    """(T, 2, 3) ground-plane shift of each foot (left, right) that holds its contact point
    still through each contact (module docstring, "Legs"); Y is 0.

    Over a contact run the contact point's weighted glide ``Q_t = sum w_u d_u`` is taken out
    around its mean (``mean(Q) - Q_t``), so the held point sits where it was on average;
    between runs the shift is interpolated linearly, and before the first and after the last
    it is held.
    """
    contacts = sliding_contacts(p, fps, L, contact_height)
    d = contact_steps(p)
    w = step_weights(contacts, np.linalg.norm(d, axis=-1) * fps / L, speed_scale)
    T = contacts.shape[0]
    out = np.zeros((T, 2, 3))
    for f in range(2):
        frames, shifts = [], []
        for a, b in _runs(contacts[:, f]):
            Q = np.cumsum(w[a:b, f, None] * d[a:b, f], axis=0)
            Q -= Q[0]
            frames.append(np.arange(a, b))
            shifts.append(Q.mean(0) - Q)
        if frames:
            frames, shifts = np.concatenate(frames), np.concatenate(shifts)
            for k, axis in enumerate(GROUND):
                out[:, f, axis] = np.interp(np.arange(T), frames, shifts[:, k])
    return out


def plant_legs(values: np.ndarray, skeleton: Skeleton, fps: float,
               joint_map: JointMap | None = None, *, contact_height: float = CONTACT_HEIGHT,
               speed_scale: float = SPEED_SCALE) -> np.ndarray:
    """(T, C) channel values whose legs hold each planted foot still (module docstring,
    "Legs"): the hips', knees' and ankles' rotation channels change, nothing else.

    Args:
        values: (T, C) channel values of ``skeleton`` (degrees, Y up).
        skeleton: the joint tree; each leg must be a chain hip -> knee -> ankle (the knee's
            parent the hip, the ankle's the knee), each with three rotation channels.
        fps: frames per second.
        joint_map: which joints play the semantic roles (auto-detected when None).
        contact_height: contact threshold in leg lengths (:data:`CONTACT_HEIGHT`).
        speed_scale: L/s; contact steps faster than this are held less (:data:`SPEED_SCALE`).
    """
    values = np.array(values, dtype=np.float64)
    idx = resolve_indices(skeleton, joint_map)
    parents, rot_idx, orders, _, _ = layout_key(skeleton)
    for s in "lr":
        hip, knee, ankle = idx[f"{s}_hip"], idx[f"{s}_knee"], idx[f"{s}_foot"]
        if parents[knee] != hip or parents[ankle] != knee:
            raise BayesmotionError(
                f"the legs cannot be moved: {skeleton.names[ankle]!r} -> "
                f"{skeleton.names[knee]!r} -> {skeleton.names[hip]!r} is not a chain of "
                "parents (ankle, knee, hip)")
        for j in (hip, knee, ankle):
            if len(orders[j]) != 3:
                raise BayesmotionError(f"the legs cannot be moved: joint "
                                       f"{skeleton.names[j]!r} has rotation channels "
                                       f"{orders[j]!r}, three are needed")
    Rw, pw = numpy_transforms(skeleton, values)
    p = {k: pw[:, j] for k, j in idx.items()}
    shift = foot_corrections(p, fps, leg_length(p), contact_height=contact_height,
                             speed_scale=speed_scale)
    for f, s in enumerate("lr"):
        rows = np.flatnonzero(np.linalg.norm(shift[:, f], axis=-1) > 0)
        if not rows.size:
            continue
        hip, knee, ankle, toe = (idx[f"{s}_{k}"] for k in ("hip", "knee", "foot", "toe"))
        R_hip, R_knee, _ = two_bone_ik(pw[rows, hip], pw[rows, knee], pw[rows, ankle],
                                       Rw[rows, hip], Rw[rows, knee],
                                       pw[rows, ankle] + shift[rows, f],
                                       bend=pw[rows, toe] - pw[rows, ankle])
        above = Rw[rows, parents[hip]] if parents[hip] >= 0 else np.eye(3)
        local = {hip: np.swapaxes(above, -1, -2) @ R_hip,
                 knee: np.swapaxes(R_hip, -1, -2) @ R_knee,
                 ankle: np.swapaxes(R_knee, -1, -2) @ Rw[rows, ankle]}
        for j, R in local.items():
            cols = list(rot_idx[j][:3])
            values[np.ix_(rows, cols)] = euler_channels(orders[j], R, values[np.ix_(rows, cols)])
    return values


def pin_feet(motion: Motion, joint_map: JointMap | None = None, *,
             contact_height: float = CONTACT_HEIGHT, speed_scale: float = SPEED_SCALE,
             smooth: int = SMOOTH, legs: bool = False) -> Motion:
    """The motion with its root path corrected so that planted feet do not glide (module
    docstring); only the root's X and Z position channels change, and with ``legs`` the
    legs' rotations too.

    Args:
        motion: a motion whose root has Xposition and Zposition channels, Y up.
        joint_map: which joints play the semantic roles (auto-detected when None).
        contact_height: contact threshold in leg lengths (:data:`CONTACT_HEIGHT`).
        speed_scale: L/s; contact steps faster than this count less (:data:`SPEED_SCALE`).
        smooth: passes of the [1, 2, 1] / 4 filter over the displacements (:data:`SMOOTH`).
        legs: then also hold each planted foot with its own leg (:func:`plant_legs`), which
            removes what the root cannot: feet that glide apart or in opposite directions.
    """
    cols = root_translation_columns(motion.skeleton)
    offset = pin_offset(motion.positions(), motion.skeleton, motion.fps, joint_map,
                        contact_height=contact_height, speed_scale=speed_scale, smooth=smooth)
    values = np.array(motion.values, dtype=np.float64)
    values[:, cols] += offset[:, GROUND]
    if legs:
        values = plant_legs(values, motion.skeleton, motion.fps, joint_map,
                            contact_height=contact_height, speed_scale=speed_scale)
    return motion.replace(values=values)
