"""Movement features: how the body travels, turns and steps.

Lengths are in leg lengths ``L`` (hip-knee plus knee-ankle, averaged over both legs and all
frames), times in seconds, angles in radians, so nothing depends on the file's length unit.
The vertical is +Y; "positive turn" is counter-clockwise about +Y (the right-hand rule), i.e.
towards the character's left. Derivatives are central differences (``np.gradient``).

==============  =====  =====  =========================================================
key             shape  unit   definition
==============  =====  =====  =========================================================
root_height     (T,)   L      root height minus its mean over the clip
speed           (T,)   L/s    horizontal root speed
speed_lowpass   (T,)   L/s    speed after a centred moving average over ``window`` s
heading         (T,)   rad    facing direction, unwrapped; 0 faces +Z, π/2 faces +X
turn_rate       (T,)   rad/s  d heading / dt; facing from the hip and shoulder lines
curvature       (T,)   1/L    signed curvature of the moving-averaged root path; 0 where
                              that path is slower than ``min_speed`` (no defined direction)
contacts        (T,2)  bool   left, right foot on the ground: ankle or toe within
                              ``contact_height`` of its lowest height in the clip and
                              slower than ``contact_speed``; runs shorter than 0.1 s dropped
phase           (T,)   rad    stepping phase in [0, 2π): +π per footstep (contact onset of
                              either foot), linear in time between; NaN outside the steps
step_frequency  ()     Hz     footsteps per second between the first and the last step
==============  =====  =====  =========================================================
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from bayesmotion.data.motion import Motion
from bayesmotion.features.joint_map import JointMap, Names
from bayesmotion.features.pose import distance, semantic_positions


def leg_length(p: dict[str, np.ndarray]) -> float:
    """Mean of hip-knee + knee-ankle over both legs and all frames; ``p`` from
    :func:`~bayesmotion.features.pose.semantic_positions`."""
    legs = [distance(p[f"{s}_hip"], p[f"{s}_knee"]) + distance(p[f"{s}_knee"], p[f"{s}_foot"])
            for s in "lr"]
    return float(np.mean(legs))


def heading(p: dict[str, np.ndarray]) -> np.ndarray:
    """(T,) facing angle about +Y (radians, unwrapped), 0 facing +Z.

    The across-body direction is the sum of the unit right-to-left hip and shoulder vectors in
    the ground plane; forward = across × up, i.e. ``(-a_z, a_x)`` in (x, z).
    """
    across = np.zeros(p["root"].shape[:-1] + (2,))
    for part in ("hip", "shoulder"):
        d = (p[f"l_{part}"] - p[f"r_{part}"])[..., [0, 2]]
        across += d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-300)
    return np.unwrap(np.arctan2(-across[..., 1], across[..., 0]))


def body_frame_pose(positions: np.ndarray, names: Names,
                    joint_map: JointMap | None = None) -> np.ndarray:
    """(T, 18, 3) semantic joints relative to the root, turned to face +Z, in leg lengths.

    Invariant to translation, uniform scale and rotation about the vertical.
    """
    p = semantic_positions(positions, names, joint_map)
    th = heading(p)
    c, s = np.cos(th), np.sin(th)
    rel = np.stack([v - p["root"] for v in p.values()], axis=-2)  # (T, 18, 3)
    x, y, z = rel[..., 0], rel[..., 1], rel[..., 2]
    # rotate by -heading about +Y: x' = x cos θ - z sin θ, z' = x sin θ + z cos θ
    out = np.stack([x * c[:, None] - z * s[:, None], y, x * s[:, None] + z * c[:, None]], -1)
    return out / leg_length(p)


def _smooth(x: np.ndarray, size: int) -> np.ndarray:
    return ndimage.uniform_filter1d(x, size=size, axis=0, mode="nearest")


def _derivative(x: np.ndarray, fps: float) -> np.ndarray:
    return np.gradient(x, axis=0) * fps if x.shape[0] > 1 else np.zeros_like(x)


def _clean(mask: np.ndarray, k: int) -> np.ndarray:
    """Fill gaps and drop runs shorter than ``k`` frames (closing then opening, edge-padded)."""
    if k <= 1:
        return mask
    st = np.ones(k, dtype=bool)
    padded = np.pad(mask, k, mode="edge")
    padded = ndimage.binary_opening(ndimage.binary_closing(padded, st), st)
    return padded[k:-k]


def foot_contacts(p: dict[str, np.ndarray], fps: float, L: float, contact_height: float = 0.1,
                  contact_speed: float = 0.6) -> np.ndarray:
    """(T, 2) bool left/right contacts (module table); thresholds in L and L/s."""
    out = []
    for s in "lr":
        on = np.zeros(p["root"].shape[0], dtype=bool)
        for joint in (f"{s}_foot", f"{s}_toe"):
            h = p[joint][:, 1] - p[joint][:, 1].min()
            v = np.linalg.norm(_derivative(p[joint], fps), axis=-1)
            on |= (h < contact_height * L) & (v < contact_speed * L)
        out.append(_clean(on, max(1, round(0.1 * fps))))
    return np.stack(out, axis=-1)


def stepping(contacts: np.ndarray, fps: float) -> tuple[np.ndarray, float]:
    """Stepping phase (T,) and footstep frequency (Hz) from (T, 2) contacts."""
    T = contacts.shape[0]
    onset = contacts[1:] & ~contacts[:-1]
    steps = np.unique(np.nonzero(onset)[0] + 1)
    phase = np.full(T, np.nan)
    if steps.size < 2:
        return phase, 0.0
    t = np.arange(steps[0], steps[-1] + 1)
    phase[t] = np.mod(np.interp(t, steps, np.pi * np.arange(steps.size)), 2 * np.pi)
    return phase, float((steps.size - 1) * fps / (steps[-1] - steps[0]))


def movement_features(motion: Motion, joint_map: JointMap | None = None,
                      **options) -> dict[str, np.ndarray]:
    """Movement features (module table) of a motion's forward-kinematics positions.

    ``options`` are those of :func:`movement_features_from_positions`.
    """
    return movement_features_from_positions(motion.positions(), motion.skeleton, motion.fps,
                                            joint_map, **options)


def movement_features_from_positions(
        positions: np.ndarray, names: Names, fps: float, joint_map: JointMap | None = None, *,
        window: float = 1.0, min_speed: float = 0.25, contact_height: float = 0.1,
        contact_speed: float = 0.6) -> dict[str, np.ndarray]:
    """Movement features (module table).

    Args:
        positions: (T, J, 3) world joint positions, Y up.
        names: the skeleton or its (J,) joint names; must fit ``joint_map`` (auto when None).
        fps: frames per second.
        window: moving-average length in seconds for ``speed_lowpass`` and ``curvature``.
        min_speed: L/s below which the root path's curvature is set to 0.
        contact_height: foot-contact height threshold in L.
        contact_speed: foot-contact speed threshold in L/s.

    Returns:
        dict with the keys of the module table.
    """
    p = semantic_positions(positions, names, joint_map)
    L = leg_length(p)
    size = 2 * max(0, round(window * fps / 2)) + 1  # odd, so the average is centred
    root = p["root"] / L
    v = _derivative(root[:, [0, 2]], fps)
    vs = _derivative(_smooth(root[:, [0, 2]], size), fps)
    a = _derivative(vs, fps)
    sp = np.linalg.norm(vs, axis=-1)
    # κ = (v × a)·Y / |v|³ with (x, z) components: v_z a_x - v_x a_z
    cross = vs[:, 1] * a[:, 0] - vs[:, 0] * a[:, 1]
    curv = np.divide(cross, sp**3, out=np.zeros_like(sp), where=sp > min_speed)
    th = heading(p)
    contacts = foot_contacts(p, fps, L, contact_height, contact_speed)
    phase, freq = stepping(contacts, fps)
    speed = np.linalg.norm(v, axis=-1)
    return {
        "root_height": root[:, 1] - root[:, 1].mean(),
        "speed": speed,
        "speed_lowpass": _smooth(speed, size),
        "heading": th,
        "turn_rate": _derivative(th, fps),
        "curvature": curv,
        "contacts": contacts,
        "phase": phase,
        "step_frequency": np.asarray(freq),
    }
