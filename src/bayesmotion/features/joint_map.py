"""Semantic joint names: which skeleton joint plays the root, the neck, the left knee ...

Affective and movement features are defined on an anatomical stick figure of 18 points, not on
one file format's joints. A :class:`JointMap` names, for one skeleton family, the joint that
stands for each point. Two maps ship with the package:

============  =================  ==============  ===================================================
semantic      ``CMU_MAP``        ``BANDAI_MAP``  note
============  =================  ==============  ===================================================
root          Hips               Hips            pelvis (Bandai's ``joint_Root`` stays on the floor)
spine         Spine              Spine           mid back, about halfway up the trunk
neck          Neck1              Neck            CMU ``Neck`` sits at the clavicles' base
head          Head               Head
l/r_shoulder  Left/RightArm      UpperArm_L/R    glenohumeral joint, not the clavicle
l/r_elbow     Left/RightForeArm  LowerArm_L/R
l/r_hand      Left/RightHand     Hand_L/R        wrist
l/r_hip       Left/RightUpLeg    UpperLeg_L/R
l/r_knee      Left/RightLeg      LowerLeg_L/R
l/r_foot      Left/RightFoot     Foot_L/R        ankle
l/r_toe       Left/RightToeBase  Toes_L/R
============  =================  ==============  ===================================================

Any other skeleton works with a user-made ``JointMap``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

from bayesmotion.data.skeleton import Skeleton
from bayesmotion.errors import BayesmotionError

Names = Skeleton | Sequence[str]  # a skeleton, or its (J,) joint names

SEMANTIC_JOINTS = (
    "root", "spine", "neck", "head",
    "l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_hand", "r_hand",
    "l_hip", "r_hip", "l_knee", "r_knee", "l_foot", "r_foot", "l_toe", "r_toe",
)


@dataclass(frozen=True)
class JointMap:
    """Skeleton joint name for each of the 18 semantic joints (see the module table)."""

    root: str
    spine: str
    neck: str
    head: str
    l_shoulder: str
    r_shoulder: str
    l_elbow: str
    r_elbow: str
    l_hand: str
    r_hand: str
    l_hip: str
    r_hip: str
    l_knee: str
    r_knee: str
    l_foot: str
    r_foot: str
    l_toe: str
    r_toe: str

    def missing(self, names: Sequence[str]) -> list[str]:
        """Joint names this map needs that ``names`` lacks."""
        have = set(names)
        return [getattr(self, f.name) for f in fields(self) if getattr(self, f.name) not in have]

    def indices(self, names: Sequence[str]) -> dict[str, int]:
        """Semantic name -> index into ``names``; raises naming the absent joints."""
        names = tuple(names)
        absent = self.missing(names)
        if absent:
            raise BayesmotionError(f"skeleton lacks the joints {absent} named by this JointMap")
        return {f.name: names.index(getattr(self, f.name)) for f in fields(self)}


def _sided(**kw: str) -> dict[str, str]:
    """Expand ``shoulder=("LeftArm", "RightArm")`` into ``l_shoulder``/``r_shoulder``."""
    out = {}
    for k, v in kw.items():
        if isinstance(v, tuple):
            out[f"l_{k}"], out[f"r_{k}"] = v
        else:
            out[k] = v
    return out


CMU_MAP = JointMap(**_sided(
    root="Hips", spine="Spine", neck="Neck1", head="Head",
    shoulder=("LeftArm", "RightArm"), elbow=("LeftForeArm", "RightForeArm"),
    hand=("LeftHand", "RightHand"), hip=("LeftUpLeg", "RightUpLeg"),
    knee=("LeftLeg", "RightLeg"), foot=("LeftFoot", "RightFoot"),
    toe=("LeftToeBase", "RightToeBase")))

BANDAI_MAP = JointMap(**_sided(
    root="Hips", spine="Spine", neck="Neck", head="Head",
    shoulder=("UpperArm_L", "UpperArm_R"), elbow=("LowerArm_L", "LowerArm_R"),
    hand=("Hand_L", "Hand_R"), hip=("UpperLeg_L", "UpperLeg_R"),
    knee=("LowerLeg_L", "LowerLeg_R"), foot=("Foot_L", "Foot_R"), toe=("Toes_L", "Toes_R")))

SHIPPED_MAPS = {"cmu": CMU_MAP, "bandai": BANDAI_MAP}


def _names(skeleton_or_names: Names) -> tuple[str, ...]:
    if isinstance(skeleton_or_names, Skeleton):
        return skeleton_or_names.names
    return tuple(skeleton_or_names)


def joint_map_for(skeleton_or_names: Names) -> JointMap:
    """The first shipped map whose joints all exist in the skeleton.

    Raises:
        BayesmotionError: naming, for every shipped map, the joints the skeleton lacks.
    """
    names = _names(skeleton_or_names)
    report = []
    for key, jm in SHIPPED_MAPS.items():
        absent = jm.missing(names)
        if not absent:
            return jm
        report.append(f"{key}: missing {absent}")
    raise BayesmotionError(
        "no shipped JointMap fits this skeleton (" + "; ".join(report)
        + "); pass joint_map=JointMap(root=..., ...) naming its joints")


def resolve_indices(skeleton_or_names: Names,
                    joint_map: JointMap | None = None) -> dict[str, int]:
    """Semantic name -> joint index, auto-detecting the map when ``joint_map`` is None."""
    names = _names(skeleton_or_names)
    return (joint_map or joint_map_for(names)).indices(names)
