"""One fixed-length feature vector per clip, for classifiers.

The 18 pose features are summarised by their median and interquartile range over the clip, not
by mean and standard deviation: the area ratios divide by triangles that flatten for a moment
(e.g. ``area_hands_spine_root`` when the hands pass the root's height), reaching values above 200
on Bandai's ``walk-left_normal`` for a frame or two, which would swamp a mean or a std.
Movement features add nine numbers (see ``CLIP_FEATURE_NAMES``).
"""

from __future__ import annotations

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.errors import BayesmotionError
from bayesmotion.features.joint_map import JointMap, Names
from bayesmotion.features.movement import movement_features_from_positions
from bayesmotion.features.pose import POSE_FEATURE_NAMES, pose_features

MOVEMENT_SUMMARY_NAMES = (
    "std_root_height",      # L
    "mean_speed",           # L/s
    "std_speed",            # L/s
    "std_speed_lowpass",    # L/s, slow changes of pace
    "mean_abs_turn_rate",   # rad/s
    "mean_abs_curvature",   # 1/L
    "contact_fraction",     # mean over both feet
    "double_support",       # fraction of frames with both feet down
    "step_frequency",       # Hz
)
CLIP_FEATURE_NAMES = (tuple(f"median_{n}" for n in POSE_FEATURE_NAMES)
                      + tuple(f"iqr_{n}" for n in POSE_FEATURE_NAMES) + MOVEMENT_SUMMARY_NAMES)


def _pose_summary(F: np.ndarray, name: str) -> np.ndarray:
    F = F[np.all(np.isfinite(F), axis=1)]  # frames with a degenerate ratio are left out
    if F.shape[0] == 0:
        raise BayesmotionError(f"motion {name!r}: every frame has a degenerate pose feature "
                               "(coincident joints); check the JointMap")
    q25, q50, q75 = np.percentile(F, [25, 50, 75], axis=0)
    return np.concatenate([q50, q75 - q25])


def _movement_summary(m: dict[str, np.ndarray]) -> np.ndarray:
    c = m["contacts"]
    return np.array([
        m["root_height"].std(), m["speed"].mean(), m["speed"].std(), m["speed_lowpass"].std(),
        np.abs(m["turn_rate"]).mean(), np.abs(m["curvature"]).mean(), c.mean(),
        np.all(c, axis=1).mean(), float(m["step_frequency"]),
    ])


def clip_features(motion: Motion, joint_map: JointMap | None = None) -> np.ndarray:
    """(45,) summary of a clip, ordered as ``CLIP_FEATURE_NAMES``.

    Invariant to translation, uniform scale and rotation about the vertical of the motion.
    """
    return clip_features_from_positions(motion.positions(), motion.skeleton, motion.fps,
                                        joint_map, name=motion.name)


def clip_features_from_positions(positions: np.ndarray, names: Names, fps: float,
                                 joint_map: JointMap | None = None, name: str = "") -> np.ndarray:
    """(45,) :func:`clip_features` of (T, J, 3) positions of the skeleton/joint ``names``."""
    pose = _pose_summary(pose_features(positions, names, joint_map), name)
    move = movement_features_from_positions(positions, names, fps, joint_map)
    return np.concatenate([pose, _movement_summary(move)])
