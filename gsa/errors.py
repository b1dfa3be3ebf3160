"""Errors and warnings of the GSA engine.

The engine never imports the application package (``sam``); a CLI layer turns a
:class:`GSAError` into its own user-error type. Every message names the thing that
is wrong (parameter, file, field) and the offending value.
"""

from __future__ import annotations


class GSAError(ValueError):
    """Something the caller gave us (problem, design, data, folder) is unusable.

    The message is one self-contained explanation meant for the end user.
    """


class GSAWarning(UserWarning):
    """Base class of the engine's warnings (filter them all at once)."""


class SamplingWarning(GSAWarning):
    """The design will work but loses a property of the Sobol' sequence."""


class ZeroVarianceWarning(GSAWarning):
    """Some outputs do not vary at all: their indices are undefined (NaN)."""


class NonFiniteWarning(GSAWarning):
    """Model runs with NaN/inf were explicitly dropped from an analysis."""
