"""Exceptions raised by bayesmotion.

Every error the package raises on bad input is a :class:`BayesmotionError`, so a program can
catch one type. Messages say what was wrong and what to do about it.
"""


class BayesmotionError(Exception):
    """Base class of all errors raised by bayesmotion on bad input or bad files."""


class BVHError(BayesmotionError):
    """A BVH file could not be parsed; the message names the line and the problem."""


class ModelFileError(BayesmotionError):
    """A model file is corrupted, foreign, or written by an incompatible version."""


class SkeletonMismatchError(BayesmotionError):
    """A motion's skeleton does not match the one a model was trained on."""
