"""Naturalness proxies of a motion: foot sliding, joint-limit violations, jerk.

None of these needs a model; they flag the artefacts that synthesis methods typically add to
real motion. Lengths are in leg lengths ``L`` (as in :mod:`bayesmotion.features.movement`),
times in seconds, angles in degrees, so nothing depends on the file's length unit.

=======================  ======  ===========================================================
key                      unit    definition
=======================  ======  ===========================================================
foot_sliding             L/s     mean horizontal speed of the foot's contact point over the
                                 frames in contact (both feet pooled); 0 when no foot touches
contact_fraction         --      fraction of (frame, foot) pairs in contact
jerk                     L/s³    RMS over frames and the 18 semantic joints of ‖d³p/dt³‖
                                 (third finite difference of world positions)
jerk_local               L/s³    the same for body-frame positions (root-relative, facing +Z;
                                 :func:`~bayesmotion.features.body_frame_pose`): the limbs'
                                 jerk without that of the global path
joint_limit_violations   --      fraction of frames where any angle of ``ANGLE_NAMES`` leaves
                                 its allowed range (the reference range, else anatomical)
joint_limit_exceedance   deg     largest distance of an angle outside its range (0 if none)
anatomical_violations    --      fraction of frames breaking ``ANATOMICAL_LIMITS``
violations_by_angle      --      per angle, the fraction of frames out of range
joint_limit_source       --      ``"reference"`` or ``"anatomical"``
foot_sliding_ratio       --      foot_sliding / the reference clips' (with a reference only)
jerk_ratio               --      jerk / the reference clips' (with a reference only)
jerk_local_ratio         --      jerk_local / the reference clips' (with a reference only)
=======================  ======  ===========================================================

**Contacts** are those of :mod:`bayesmotion.features.contacts`: a foot is in contact where its
ankle or toe is within ``contact_height`` (L, default ``CONTACT_HEIGHT`` = 0.03 L, about 2.5 cm)
of that joint's lowest height in the clip, with no speed gate (a speed gate would hide exactly
the sliding measured here). The contact point is whichever of ankle and toe is nearer its own
floor height in that frame (the heel at heel strike, the toe at push-off), and sliding is that
joint's horizontal speed. Real walks score 0.2-0.9 L/s (30 fps), mostly from the frames around
heel strike and toe-off, so compare motions through ``foot_sliding_ratio``.

**Joint angles** (``ANGLE_NAMES``) come from positions, so they do not depend on the skeleton's
Euler conventions and are invariant to translation, rotation and uniform scale:
elbow flexion ``180 - ∠(shoulder, elbow, hand)``; knee flexion signed about the hip line
(``l_hip - r_hip``, the body's left), positive when the shank swings behind the thigh and
negative for hyperextension; shoulder elevation ``∠(elbow - shoulder, root - neck)`` and hip
flexion ``∠(knee - hip, root - neck)`` against the trunk's downward axis; ankle
``∠(knee, foot, toe)``; trunk bend ``180 - ∠(root, spine, neck)``; neck bend
``180 - ∠(spine, neck, head)``.

**Joint limits.** With reference clips an angle is out of range outside the [min, max] it takes
over all reference frames (widened by ``margin`` degrees, default 1e-6 for round-off); without
them, outside the generous anatomical ranges of elbow and knee flexion in ``ANATOMICAL_LIMITS``
(elbow 0-150°; knee -10-160°, allowing a little hyperextension and capture noise), which flag
impossible rather than unusual poses. The reference range is tight: a real clip held out of
its group can leave the range the others span, so read violations relative to real clips
scored the same way.

**Jerk** grows with the frame rate (finite differences amplify capture noise by ``fps³``), so a
motion is only compared with references at its own frame rate: references given as motions are
resampled to it, and a prebuilt :class:`NaturalnessReference` at another rate is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError
from bayesmotion.features.contacts import CONTACT_HEIGHT, sliding_contacts, toe_leads
from bayesmotion.features.joint_map import JointMap, Names
from bayesmotion.features.movement import body_frame_pose, leg_length
from bayesmotion.features.pose import angle, semantic_positions

ANGLE_NAMES = (
    "l_elbow_flexion", "r_elbow_flexion", "l_knee_flexion", "r_knee_flexion",
    "l_shoulder_elevation", "r_shoulder_elevation", "l_hip_flexion", "r_hip_flexion",
    "l_ankle", "r_ankle", "trunk_bend", "neck_bend",
)
ANATOMICAL_LIMITS = {
    "l_elbow_flexion": (0.0, 150.0), "r_elbow_flexion": (0.0, 150.0),
    "l_knee_flexion": (-10.0, 160.0), "r_knee_flexion": (-10.0, 160.0),
}
"""Angle name -> (low, high) degrees allowed without reference clips."""


def _between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between vectors (..., 3) in degrees."""
    return angle(u, np.zeros_like(u), v)


def _knee_flexion(hip, knee, foot, lateral) -> np.ndarray:
    """Signed angle from thigh to shank about the body's left axis (flexion > 0), degrees."""
    t, s = knee - hip, foot - knee
    a = lateral / np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-300)
    # rotation about +left takes a downward thigh to a shank pointing backward: t × s ∥ +left
    sin = np.einsum("...i,...i->...", np.cross(t, s), a)
    return np.degrees(np.arctan2(sin, np.einsum("...i,...i->...", t, s)))


def joint_angles(p: dict[str, np.ndarray]) -> np.ndarray:
    """(T, 12) angles of ``ANGLE_NAMES`` (module docstring) from semantic positions ``p``."""
    down = p["root"] - p["neck"]
    lateral = p["l_hip"] - p["r_hip"]
    cols = {}
    for s in "lr":
        cols[f"{s}_elbow_flexion"] = 180.0 - angle(p[f"{s}_shoulder"], p[f"{s}_elbow"],
                                                   p[f"{s}_hand"])
        cols[f"{s}_knee_flexion"] = _knee_flexion(p[f"{s}_hip"], p[f"{s}_knee"],
                                                  p[f"{s}_foot"], lateral)
        cols[f"{s}_shoulder_elevation"] = _between(p[f"{s}_elbow"] - p[f"{s}_shoulder"], down)
        cols[f"{s}_hip_flexion"] = _between(p[f"{s}_knee"] - p[f"{s}_hip"], down)
        cols[f"{s}_ankle"] = angle(p[f"{s}_knee"], p[f"{s}_foot"], p[f"{s}_toe"])
    cols["trunk_bend"] = 180.0 - angle(p["root"], p["spine"], p["neck"])
    cols["neck_bend"] = 180.0 - angle(p["spine"], p["neck"], p["head"])
    return np.stack([cols[n] for n in ANGLE_NAMES], axis=-1)


def sliding_speeds(p: dict[str, np.ndarray], fps: float, L: float,
                   contact_height: float = CONTACT_HEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal contact-point speed (T, 2) in L/s and the (T, 2) contacts (left, right)."""
    contacts = sliding_contacts(p, fps, L, contact_height)
    out = []
    for s in "lr":
        v = {j: np.linalg.norm(np.gradient(p[j][:, [0, 2]], axis=0), axis=-1) * fps / L
             if len(p[j]) > 1 else np.zeros(len(p[j])) for j in (f"{s}_foot", f"{s}_toe")}
        out.append(np.where(toe_leads(p, s), v[f"{s}_toe"], v[f"{s}_foot"]))
    return np.stack(out, axis=-1), contacts


def jerk_squares(P: np.ndarray, fps: float) -> np.ndarray:
    """(T-3, K) squared jerk norms ‖Δ³p‖² · fps⁶ of (T, K, 3) positions P."""
    if P.shape[0] < 4:
        raise BayesmotionError(f"jerk needs at least 4 frames, got {P.shape[0]}")
    return np.sum((np.diff(P, n=3, axis=0) * fps**3) ** 2, axis=-1)


def _clip_terms(positions: np.ndarray, names: Names, fps: float, joint_map: JointMap | None,
                contact_height: float) -> dict[str, np.ndarray]:
    """Per-frame ingredients of every proxy: angles, contact speeds, squared jerks."""
    p = semantic_positions(positions, names, joint_map)
    L = leg_length(p)
    v, c = sliding_speeds(p, fps, L, contact_height)
    return {
        "angles": joint_angles(p),
        "sliding": v[c],
        "contacts": c,
        "jerk2": jerk_squares(np.stack(list(p.values()), axis=1) / L, fps),
        "jerk2_local": jerk_squares(body_frame_pose(positions, names, joint_map), fps),
    }


@dataclass(frozen=True, eq=False)
class NaturalnessReference:
    """What naturalness compares a motion with, pooled over real reference clips.

    Attributes:
        fps: frame rate the statistics were taken at.
        low, high: (12,) per-angle min and max over all reference frames (``ANGLE_NAMES``).
        foot_sliding: mean contact-point speed over all reference contact frames, L/s.
        jerk, jerk_local: RMS jerk (world, body frame) over all reference frames and joints,
            L/s³.
        n_clips: number of reference clips.
    """

    fps: float
    low: np.ndarray
    high: np.ndarray
    foot_sliding: float
    jerk: float
    jerk_local: float
    n_clips: int

    @classmethod
    def from_positions(cls, clips: Sequence[np.ndarray], names: Names, fps: float,
                       joint_map: JointMap | None = None,
                       contact_height: float = CONTACT_HEIGHT) -> NaturalnessReference:
        """Pool the statistics of (T_i, J, 3) position arrays of one skeleton at ``fps``."""
        if not clips:
            raise BayesmotionError("NaturalnessReference needs at least one reference clip")
        terms = [_clip_terms(X, names, fps, joint_map, contact_height) for X in clips]
        pooled = {k: np.concatenate([t[k].ravel() for t in terms])
                  for k in ("sliding", "jerk2", "jerk2_local")}
        A = np.concatenate([t["angles"] for t in terms])
        slide = float(pooled["sliding"].mean()) if pooled["sliding"].size else 0.0
        return cls(float(fps), A.min(0), A.max(0), slide, float(np.sqrt(pooled["jerk2"].mean())),
                   float(np.sqrt(pooled["jerk2_local"].mean())), len(clips))

    @classmethod
    def from_motions(cls, motions: Sequence[Motion], fps: float | None = None,
                     joint_map: JointMap | None = None,
                     contact_height: float = CONTACT_HEIGHT) -> NaturalnessReference:
        """Statistics of reference motions, resampled to ``fps`` (default: the first's rate)."""
        if not motions:
            raise BayesmotionError("NaturalnessReference needs at least one reference motion")
        fps = motions[0].fps if fps is None else float(fps)
        ms = [m if m.fps == fps else m.resample(fps) for m in motions]
        return cls.from_positions([m.positions() for m in ms], ms[0].skeleton, fps, joint_map,
                                  contact_height)


def _violations(A: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, float]:
    """Per (frame, angle) out-of-range flags and the largest exceedance in degrees."""
    over = np.maximum(A - high, 0.0) + np.maximum(low - A, 0.0)
    return over > 0, float(over.max()) if over.size else 0.0


def _anatomical_bounds() -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([ANATOMICAL_LIMITS.get(n, (-np.inf, np.inf))[0] for n in ANGLE_NAMES])
    hi = np.array([ANATOMICAL_LIMITS.get(n, (-np.inf, np.inf))[1] for n in ANGLE_NAMES])
    return lo, hi


def naturalness_from_positions(positions: np.ndarray, names: Names, fps: float,
                               reference: NaturalnessReference | None = None,
                               joint_map: JointMap | None = None, *,
                               contact_height: float = CONTACT_HEIGHT,
                               margin: float = 1e-6) -> dict:
    """Naturalness proxies (module table) of (T, J, 3) world positions, Y up.

    Args:
        positions: (T, J, 3), T >= 4. names: the skeleton or its (J,) joint names.
        fps: frames per second.
        reference: pooled real-clip statistics at the same ``fps``, or None.
        joint_map: which joints play the semantic roles (auto-detected when None).
        contact_height: contact threshold in L.
        margin: degrees by which the reference angle range is widened (the default absorbs
            round-off on angles that never vary in the reference).
    """
    if reference is not None and abs(reference.fps - fps) > 1e-9:
        raise BayesmotionError(f"reference statistics were taken at {reference.fps} fps, the "
                               f"motion runs at {fps} fps; rebuild the reference at {fps} fps "
                               "(jerk depends on the frame rate)")
    t = _clip_terms(positions, names, fps, joint_map, contact_height)
    A = t["angles"]
    anat, anat_exceed = _violations(A, *_anatomical_bounds())
    if reference is None:
        out_of_range, exceed, source = anat, anat_exceed, "anatomical"
    else:
        out_of_range, exceed = _violations(A, reference.low - margin, reference.high + margin)
        source = "reference"
    out = {
        "foot_sliding": float(t["sliding"].mean()) if t["sliding"].size else 0.0,
        "contact_fraction": float(t["contacts"].mean()),
        "jerk": float(np.sqrt(t["jerk2"].mean())),
        "jerk_local": float(np.sqrt(t["jerk2_local"].mean())),
        "joint_limit_violations": float(out_of_range.any(axis=1).mean()),
        "joint_limit_exceedance": exceed,
        "anatomical_violations": float(anat.any(axis=1).mean()),
        "violations_by_angle": dict(zip(ANGLE_NAMES, out_of_range.mean(0).tolist(),
                                        strict=True)),
        "joint_limit_source": source,
    }
    if reference is not None:
        out["foot_sliding_ratio"] = out["foot_sliding"] / max(reference.foot_sliding, 1e-300)
        out["jerk_ratio"] = out["jerk"] / max(reference.jerk, 1e-300)
        out["jerk_local_ratio"] = out["jerk_local"] / max(reference.jerk_local, 1e-300)
    return out


def naturalness(motion: Motion,
                reference_motions: Sequence[Motion] | NaturalnessReference | None = None,
                joint_map: JointMap | None = None, **options) -> dict:
    """Naturalness proxies (module table) of a motion.

    Args:
        motion: the motion to score (at least 4 frames).
        reference_motions: real clips of the same skeleton family (resampled to the motion's
            frame rate), a prebuilt :class:`NaturalnessReference` at that rate, or None
            (anatomical joint limits only, no ratios).
        joint_map: which joints play the semantic roles (auto-detected when None).
        **options: ``contact_height`` (L) and ``margin`` (degrees), see
            :func:`naturalness_from_positions`.
    """
    ref = reference_motions
    if ref is not None and not isinstance(ref, NaturalnessReference):
        ref = NaturalnessReference.from_motions(
            list(ref), motion.fps, joint_map, options.get("contact_height", CONTACT_HEIGHT))
    return naturalness_from_positions(motion.positions(), motion.skeleton, motion.fps, ref,
                                      joint_map, **options)
