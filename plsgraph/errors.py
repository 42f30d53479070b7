"""Typed errors. Every message says what is wrong and what the user can do about it."""

from __future__ import annotations


class PlsgraphError(Exception):
    """Base class of every error plsgraph raises on purpose."""


class InputError(PlsgraphError, ValueError):
    """The caller passed data of the wrong shape, type or content (NaN, unsorted, mismatched)."""


class DegenerateMotionError(PlsgraphError):
    """The motion does not excite what the computation needs (too little, collinear, all zero)."""


class InsufficientDataError(PlsgraphError):
    """Too few samples, detections or messages for the requested computation."""


class RecordingError(PlsgraphError):
    """A recording cannot be read: corrupt, truncated, missing topic or unknown schema."""


class ConvergenceError(PlsgraphError):
    """An optimisation did not converge; its result must not be trusted."""


class ClockAlignmentError(InputError):
    """The camera's and the odometry's clocks cannot be aligned without doubt (the command exits 2)."""
