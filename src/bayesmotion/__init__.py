"""bayesmotion: probabilistic synthesis and analysis of emotional human motion.

The core is the hierarchical Gaussian-process dynamical model of Taubert, Christensen, Endres &
Giese (2012), treated as a Bayesian posterior: MAP fit (:class:`HGPDM`), emcee/NUTS over the
kernel hyperparameters and style vectors (:func:`sample_posterior`), generation with predictive
variance (:meth:`FittedHGPDM.generate`), and emotion inference on observed motion
(:func:`infer_emotion`). Importing bayesmotion enables float64 in JAX (see ``_config``).
"""

from bayesmotion import _config, datasets  # noqa: F401  (_config: float64 before any array)
from bayesmotion._version import __version__
from bayesmotion.codecs.pose import PoseCodec
from bayesmotion.compile_cache import enable_compilation_cache
from bayesmotion.data import (
    Motion,
    MotionDataset,
    Skeleton,
    Trial,
    forward_kinematics,
    parse_bvh,
    read_bvh,
    write_bvh,
)
from bayesmotion.data.emotion import EMOTION_PRESETS, EmotionStyle, apply_emotion
from bayesmotion.data.mirror import canonical_side, mirror, reframe, rest_frames
from bayesmotion.datasets.bandai import load_bandai
from bayesmotion.datasets.handshakes import load_cmu_handshake, load_handshakes
from bayesmotion.emotion.batch import infer_many
from bayesmotion.emotion.evidence import calibrate_evidence
from bayesmotion.emotion.infer import infer_emotion, infer_online
from bayesmotion.emotion.result import EmotionPosterior
from bayesmotion.errors import BayesmotionError, BVHError, ModelFileError, SkeletonMismatchError
from bayesmotion.features.contacts import pin_feet
from bayesmotion.inference.posterior import Posterior
from bayesmotion.inference.sample import sample_posterior
from bayesmotion.model.fitted import FittedHGPDM
from bayesmotion.model.generate import Transition
from bayesmotion.model.io import load
from bayesmotion.model.params import Priors
from bayesmotion.model.rollout import Rollout, load_rollout
from bayesmotion.model.spec import HGPDM

__all__ = [
    "EMOTION_PRESETS", "HGPDM", "__version__", "BVHError", "BayesmotionError", "EmotionPosterior",
    "EmotionStyle", "FittedHGPDM", "ModelFileError", "Motion", "MotionDataset", "PoseCodec",
    "Posterior", "Priors", "Rollout", "Skeleton", "SkeletonMismatchError", "Transition", "Trial",
    "apply_emotion", "calibrate_evidence", "canonical_side", "datasets", "enable_compilation_cache",
    "forward_kinematics",
    "infer_emotion", "infer_many", "infer_online", "load", "load_rollout", "mirror", "pin_feet",
    "reframe", "rest_frames",
    "load_bandai", "load_cmu_handshake", "load_handshakes", "parse_bvh", "read_bvh",
    "sample_posterior", "write_bvh",
]
