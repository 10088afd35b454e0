"""Baselines the hierarchical GPDM is compared with.

* :mod:`~bayesmotion.baselines.classifier` -- emotion classifiers on clip features.
* :mod:`~bayesmotion.baselines.strength` -- relative emotion strength (Ho et al. RankSVM).
* :mod:`~bayesmotion.baselines.unuma` -- Fourier principles (Unuma et al. 1995).
* :mod:`~bayesmotion.baselines.rose` -- verbs and adverbs (Rose et al. 1998).
* :mod:`~bayesmotion.baselines.amaya` -- emotion from motion (Amaya et al. 1996).
"""

from bayesmotion.baselines.amaya import apply_amaya, fit_amaya
from bayesmotion.baselines.classifier import (
    GroupCentred,
    LogisticRegression,
    NearestNeighbour,
    accuracy,
    leave_one_out_predictions,
    mean_pose_features,
    trial_features,
)
from bayesmotion.baselines.rose import RBFInterpolant, Verb, emotion_coordinates, fit_rbf, fit_verb
from bayesmotion.baselines.strength import (
    StrengthClassifier,
    StrengthModel,
    fit_strength,
    fit_strength_features,
    keyframe_features,
    ranking_accuracy,
    simplify_curve,
)
from bayesmotion.baselines.unuma import (
    EmotionComponent,
    FourierModel,
    blend,
    detect_period,
    emotion_component,
    fourier_eval,
    fourier_fit,
    superpose,
)

__all__ = [
    "EmotionComponent", "FourierModel", "GroupCentred", "LogisticRegression", "NearestNeighbour",
    "RBFInterpolant", "StrengthClassifier", "StrengthModel", "Verb", "accuracy", "apply_amaya",
    "blend", "detect_period", "emotion_component", "emotion_coordinates", "fit_amaya", "fit_rbf",
    "fit_strength", "fit_strength_features", "fit_verb", "fourier_eval", "fourier_fit",
    "keyframe_features", "leave_one_out_predictions", "mean_pose_features", "ranking_accuracy",
    "simplify_curve", "superpose", "trial_features",
]
