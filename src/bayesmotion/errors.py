"""Exceptions raised by bayesmotion.

Every error the package raises on bad input is a :class:`BayesmotionError`, so a program can
catch one type. Messages say what was wrong and what to do about it. Warnings are issued
with :func:`warn`, which attributes them to the user's line that called the package.
"""

import os
import sys
import warnings


class BayesmotionError(Exception):
    """Base class of all errors raised by bayesmotion on bad input or bad files."""


class BVHError(BayesmotionError):
    """A BVH file could not be parsed; the message names the line and the problem."""


class ModelFileError(BayesmotionError):
    """A model file is corrupted, foreign, or written by an incompatible version."""


class SkeletonMismatchError(BayesmotionError):
    """A motion's skeleton does not match the one a model was trained on."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn(message: str, category: type[Warning] = UserWarning) -> None:
    """Issue a warning attributed to the first caller outside bayesmotion: the line of the
    user's code that called the package (what ``warnings`` prints and filters by), however deep
    inside the package the condition was found."""
    frame, level = sys._getframe(1), 2
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level - 1 if frame is None else level)
