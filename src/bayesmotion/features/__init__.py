"""Affective and movement features of motions (Bhattacharya et al. pose features, gait)."""

from bayesmotion.features.joint_map import (
    BANDAI_MAP,
    CMU_MAP,
    SEMANTIC_JOINTS,
    JointMap,
    joint_map_for,
)
from bayesmotion.features.movement import (
    body_frame_pose,
    movement_features,
    movement_features_from_positions,
)
from bayesmotion.features.pose import POSE_FEATURE_NAMES, affective_features, pose_features
from bayesmotion.features.summary import (
    CLIP_FEATURE_NAMES,
    clip_features,
    clip_features_from_positions,
)

__all__ = [
    "BANDAI_MAP", "CLIP_FEATURE_NAMES", "CMU_MAP", "POSE_FEATURE_NAMES", "SEMANTIC_JOINTS",
    "JointMap", "affective_features", "body_frame_pose", "clip_features",
    "clip_features_from_positions", "joint_map_for", "movement_features",
    "movement_features_from_positions", "pose_features",
]
