"""bayesmotion: probabilistic synthesis and analysis of emotional human motion.

The core is the hierarchical Gaussian-process dynamical model of Taubert, Christensen, Endres &
Giese (2012), treated as a Bayesian posterior: MAP fit (:class:`HGPDM`), emcee/NUTS over the
kernel hyperparameters and style vectors (:func:`sample_posterior`), generation with predictive
variance (:meth:`FittedHGPDM.generate`), and emotion inference on observed motion
(:func:`infer_emotion`). Importing bayesmotion enables float64 in JAX (see ``_config``).
"""

from . import (
    _config,  # noqa: F401  (float64 before any array is made)
    datasets,
)
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
from .data.bandai import load_bandai
from .data.emotion import EMOTION_PRESETS, EmotionStyle, apply_emotion
from .data.handshakes import load_cmu_handshake, load_handshakes
from .data.mirror import canonical_side, mirror, reframe, rest_frames
from .data.representation import PoseCodec
from .errors import BayesmotionError, BVHError, ModelFileError, SkeletonMismatchError
from .fitted import FittedHGPDM
from .generate import Rollout, Transition
from .infer import EmotionPosterior, infer_emotion, infer_online
from .io import load
from .model import HGPDM
from .params import Priors
from .posterior import Posterior, sample_posterior

__version__ = "0.1.0"

__all__ = [
    "EMOTION_PRESETS", "HGPDM", "BVHError", "BayesmotionError", "EmotionPosterior",
    "EmotionStyle", "FittedHGPDM", "ModelFileError", "Motion", "MotionDataset", "PoseCodec",
    "Posterior", "Priors", "Rollout", "Skeleton", "SkeletonMismatchError", "Transition", "Trial",
    "apply_emotion", "canonical_side", "datasets", "forward_kinematics", "infer_emotion",
    "infer_online", "load", "mirror", "reframe", "rest_frames",
    "load_bandai", "load_cmu_handshake", "load_handshakes", "parse_bvh", "read_bvh",
    "sample_posterior", "write_bvh",
]
