"""The 18 scale-independent pose affective features of Bhattacharya et al. (2021).

"Generating emotive gaits for virtual agents using affect-based autoregression" (IEEE ISMAR),
Fig. 2: 11 joint angles, 4 distance ratios and 3 area ratios per frame. The
paper's figure lists the kinds of feature; the exact triples below follow the authors' public
implementation (``MocapDataset.get_affective_features`` in UttaranB127/GeneratingEmotiveGaits,
CMU skeleton), re-expressed through a :class:`~bayesmotion.features.JointMap`. Where that code
uses CMU's ``HandIndex1`` (finger tip) we use the wrist (``l/r_hand``). "Feet" means the toes.

Angles are in degrees, in [0, 180]; ``∠(a, b, c)`` is the angle at ``b`` between ``a - b`` and
``c - b``. ``|ab|`` is a distance and ``△(a, b, c)`` a triangle's area.

==  ==========================  =========================================================
#   name                        definition
==  ==========================  =========================================================
1   angle_spine_shoulders       ∠(r_shoulder, spine, l_shoulder)  shoulders at the back
2   angle_spine_hands           ∠(r_hand, spine, l_hand)          arms spread
3   angle_l_elbow               ∠(l_shoulder, l_elbow, l_hand)
4   angle_r_elbow               ∠(r_shoulder, r_elbow, r_hand)
5   angle_neck_head_l_shoulder  ∠(head, neck, l_shoulder)         head tilt / shrug
6   angle_neck_head_r_shoulder  ∠(head, neck, r_shoulder)
7   angle_root_head_l_knee      ∠(head, root, l_knee)             trunk flexion (left)
8   angle_root_head_r_knee      ∠(head, root, r_knee)             trunk flexion (right)
9   angle_root_feet             ∠(r_toe, root, l_toe)             legs spread
10  angle_l_knee                ∠(l_hip, l_knee, l_foot)
11  angle_r_knee                ∠(r_hip, r_knee, r_foot)
12  ratio_l_hand_neck_root      |l_hand neck| / |l_hand root|     hand raised (left)
13  ratio_r_hand_neck_root      |r_hand neck| / |r_hand root|
14  ratio_hands_torso           |l_hand r_hand| / |neck root|
15  ratio_feet_torso            |l_toe r_toe| / |neck root|       stride width/length
16  area_shoulders_spine_root   △(l_sh, spine, r_sh) / △(l_sh, root, r_sh)
17  area_hands_spine_root       △(l_hand, spine, r_hand) / △(l_hand, root, r_hand)
18  area_hands_neck_feet_root   △(l_hand, neck, r_hand) / △(l_toe, root, r_toe)
==  ==========================  =========================================================

A ratio whose denominator is exactly zero (coincident joints, a flat triangle) is NaN.
"""

from __future__ import annotations

import numpy as np

from bayesmotion.data.motion import Motion
from bayesmotion.features.joint_map import JointMap, Names, resolve_indices

_ANGLES = (
    ("angle_spine_shoulders", "r_shoulder", "spine", "l_shoulder"),
    ("angle_spine_hands", "r_hand", "spine", "l_hand"),
    ("angle_l_elbow", "l_shoulder", "l_elbow", "l_hand"),
    ("angle_r_elbow", "r_shoulder", "r_elbow", "r_hand"),
    ("angle_neck_head_l_shoulder", "head", "neck", "l_shoulder"),
    ("angle_neck_head_r_shoulder", "head", "neck", "r_shoulder"),
    ("angle_root_head_l_knee", "head", "root", "l_knee"),
    ("angle_root_head_r_knee", "head", "root", "r_knee"),
    ("angle_root_feet", "r_toe", "root", "l_toe"),
    ("angle_l_knee", "l_hip", "l_knee", "l_foot"),
    ("angle_r_knee", "r_hip", "r_knee", "r_foot"),
)
_DISTANCES = (  # name, numerator pair, denominator pair
    ("ratio_l_hand_neck_root", ("l_hand", "neck"), ("l_hand", "root")),
    ("ratio_r_hand_neck_root", ("r_hand", "neck"), ("r_hand", "root")),
    ("ratio_hands_torso", ("l_hand", "r_hand"), ("neck", "root")),
    ("ratio_feet_torso", ("l_toe", "r_toe"), ("neck", "root")),
)
_AREAS = (  # name, numerator triangle, denominator triangle
    ("area_shoulders_spine_root", ("l_shoulder", "spine", "r_shoulder"),
     ("l_shoulder", "root", "r_shoulder")),
    ("area_hands_spine_root", ("l_hand", "spine", "r_hand"), ("l_hand", "root", "r_hand")),
    ("area_hands_neck_feet_root", ("l_hand", "neck", "r_hand"), ("l_toe", "root", "r_toe")),
)
POSE_FEATURE_NAMES = tuple(f[0] for f in _ANGLES + _DISTANCES + _AREAS)


def angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Angle at ``b`` in degrees; a, b, c: (..., 3) -> (...). 0 when an arm has zero length."""
    u, v = a - b, c - b
    # atan2(|u×v|, u·v) is accurate near 0 and 180 degrees, where arccos is not.
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1),
                                 np.einsum("...i,...i->...", u, v)))


def distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3), (..., 3) -> (...) Euclidean distance."""
    return np.linalg.norm(a - b, axis=-1)


def triangle_area(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(..., 3) x3 -> (...) area ½|(b - a) × (c - a)|."""
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=-1)


def ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den, NaN where den == 0 (without a floating-point warning)."""
    out = np.full(np.broadcast_shapes(num.shape, den.shape), np.nan)
    return np.divide(num, den, out=out, where=den != 0)


def semantic_positions(positions: np.ndarray, skeleton_or_names: Names,
                       joint_map: JointMap | None = None) -> dict[str, np.ndarray]:
    """Semantic name -> (..., 3) positions, from ``positions: (..., J, 3)``."""
    idx = resolve_indices(skeleton_or_names, joint_map)
    P = np.asarray(positions, dtype=np.float64)
    return {k: P[..., j, :] for k, j in idx.items()}


def pose_features(positions: np.ndarray, skeleton_or_names: Names,
                  joint_map: JointMap | None = None) -> np.ndarray:
    """The 18 affective pose features (module table) of every frame.

    Args:
        positions: (T, J, 3) world joint positions (any leading shape works: (..., J, 3)).
        skeleton_or_names: the skeleton, or its (J,) joint names.
        joint_map: which joints play the semantic roles; auto-detected when None.

    Returns:
        (T, 18) features, ordered as ``POSE_FEATURE_NAMES``; invariant to translation, rotation
        and uniform scaling of ``positions``.
    """
    p = semantic_positions(positions, skeleton_or_names, joint_map)
    cols = [angle(p[a], p[b], p[c]) for _, a, b, c in _ANGLES]
    cols += [ratio(distance(*(p[k] for k in n)), distance(*(p[k] for k in d)))
             for _, n, d in _DISTANCES]
    cols += [ratio(triangle_area(*(p[k] for k in n)), triangle_area(*(p[k] for k in d)))
             for _, n, d in _AREAS]
    return np.stack(cols, axis=-1)


def affective_features(motion: Motion, joint_map: JointMap | None = None) -> np.ndarray:
    """(T, 18) :func:`pose_features` of a motion's forward-kinematics positions."""
    return pose_features(motion.positions(), motion.skeleton, joint_map)
