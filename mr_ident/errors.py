"""Exceptions of mr_ident.

Every exception derives from :class:`MrIdentError` *and* from the matching
builtin, so callers can catch either ``MrIdentError`` or ``ValueError``.
Messages name the parameter, what was expected and what came.
"""

from __future__ import annotations


class MrIdentError(Exception):
    """Root of every error raised on purpose by mr_ident."""


class DimensionError(MrIdentError, ValueError):
    """An array has the wrong shape, or two arrays disagree in shape."""


class DataError(MrIdentError, ValueError):
    """Measured data is unusable: NaN/inf, too short, inconsistent columns."""


class ModelError(MrIdentError, ValueError):
    """A model file or system description is invalid (including an unstable loop)."""


class ConfigError(MrIdentError, ValueError):
    """An option or parameter is out of range or of the wrong type."""
