"""bayesmotion: probabilistic synthesis and analysis of emotional human motion.

The core is the hierarchical Gaussian-process dynamical model of Taubert, Christensen, Endres &
Giese (2012), treated as a Bayesian posterior. Importing bayesmotion enables float64 in JAX
(see :mod:`bayesmotion._config`).
"""

from . import _config  # noqa: F401  (enables float64 before any array is made)
from .data import (
    Motion,
    MotionDataset,
    Skeleton,
    Trial,
    forward_kinematics,
    parse_bvh,
    read_bvh,
    write_bvh,
)
from .errors import BayesmotionError, BVHError, ModelFileError, SkeletonMismatchError

__version__ = "0.1.0"

__all__ = [
    "BVHError",
    "BayesmotionError",
    "ModelFileError",
    "Motion",
    "MotionDataset",
    "Skeleton",
    "SkeletonMismatchError",
    "Trial",
    "forward_kinematics",
    "parse_bvh",
    "read_bvh",
    "write_bvh",
]
