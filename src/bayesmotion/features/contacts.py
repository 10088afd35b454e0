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
clean-up (2002) without their inverse kinematics on the legs, so a foot whose own leg slides
relative to the body (both feet planted, moving apart) keeps that part of its sliding.

On the real Bandai walks and runs at 10 fps (which glide little) the clean-up changes the
jerk by less than 3 % and lowers the measured sliding to 0.70-0.95 of its value; after a
uniform glide of 0.3 L/s is added to those clips, it brings their sliding back to 0.74-0.96 of
the clips' own (``tests/test_contacts.py`` checks both). On generated clips:
``benchmarks/results/foot_contacts.json``.
"""

from __future__ import annotations

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError
from bayesmotion.features.joint_map import JointMap
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


def pin_feet(motion: Motion, joint_map: JointMap | None = None, *,
             contact_height: float = CONTACT_HEIGHT, speed_scale: float = SPEED_SCALE,
             smooth: int = SMOOTH) -> Motion:
    """The motion with its root path corrected so that planted feet do not glide (module
    docstring); only the root's X and Z position channels change.

    Args:
        motion: a motion whose root has Xposition and Zposition channels, Y up.
        joint_map: which joints play the semantic roles (auto-detected when None).
        contact_height: contact threshold in leg lengths (:data:`CONTACT_HEIGHT`).
        speed_scale: L/s; contact steps faster than this count less (:data:`SPEED_SCALE`).
        smooth: passes of the [1, 2, 1] / 4 filter over the displacements (:data:`SMOOTH`).
    """
    cols = root_translation_columns(motion.skeleton)
    offset = pin_offset(motion.positions(), motion.skeleton, motion.fps, joint_map,
                        contact_height=contact_height, speed_scale=speed_scale, smooth=smooth)
    values = np.array(motion.values, dtype=np.float64)
    values[:, cols] += offset[:, GROUND]
    return motion.replace(values=values)
