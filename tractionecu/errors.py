"""One exception tree for the project.

Library errors are translated at the boundary into these classes.  Where a
project error resembles a builtin, it also subclasses that builtin so callers
may catch either.
"""

from __future__ import annotations


class TractionEcuError(Exception):
    """Root of every error raised by tractionecu."""


class ConfigError(TractionEcuError, ValueError):
    """A configuration value is missing, of the wrong type or out of range.

    The message always names the offending key.
    """


class RecordingError(TractionEcuError, OSError):
    """A recording cannot be read: missing, empty or unreadable file.

    The message names the file and, where it applies, the line.
    """


class UnknownFrame(TractionEcuError, KeyError):
    """A CAN frame whose PGN is not in the DBC."""


class DecodeError(TractionEcuError, ValueError):
    """A frame or sentence that is known but malformed (wrong DLC, bad checksum...)."""


class EstimatorError(TractionEcuError, ArithmeticError):
    """The estimator cannot continue (e.g. covariance beyond repair)."""
