"""Motion data: skeletons, motions, trials, datasets, BVH I/O, forward and inverse kinematics."""

from bayesmotion.data.bvh import parse_bvh, read_bvh, write_bvh
from bayesmotion.data.fk import forward_kinematics
from bayesmotion.data.motion import Motion, MotionDataset, Trial
from bayesmotion.data.skeleton import Skeleton

__all__ = ["Motion", "MotionDataset", "Skeleton", "Trial", "forward_kinematics", "parse_bvh",
           "read_bvh", "write_bvh"]
