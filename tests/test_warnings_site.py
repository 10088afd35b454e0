"""Warnings are attributed to the user's line that called the package, however deep inside it
the condition was found (what ``warnings`` prints, and what a user's filters match)."""

import warnings

import numpy as np
import pytest

from bayesmotion.errors import warn
from bayesmotion.inference.posterior import ChainTooShortWarning, burn_thin


def test_chain_warning_points_at_the_callers_line():
    with pytest.warns(ChainTooShortWarning) as caught:
        line = _lineno() + 1
        burn_thin(np.array([100.0]), 10, None, None)
    assert [(w.filename, w.lineno) for w in caught] == [(__file__, line)]


def test_warn_from_outside_the_package_points_at_its_caller():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = _lineno() + 1
        warn("from a test", UserWarning)
    assert [(w.filename, w.lineno, str(w.message)) for w in caught] == [
        (__file__, line, "from a test")]


def _lineno() -> int:
    import inspect

    return inspect.currentframe().f_back.f_lineno
