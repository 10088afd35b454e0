"""Motion data: skeletons, motions, trials, datasets, BVH I/O, forward kinematics."""

from .bvh import parse_bvh, read_bvh, write_bvh
from .fk import forward_kinematics
from .motion import Motion, MotionDataset, Trial
from .skeleton import Skeleton

__all__ = ["Motion", "MotionDataset", "Skeleton", "Trial", "forward_kinematics", "parse_bvh",
           "read_bvh", "write_bvh"]
