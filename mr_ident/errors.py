# SPDX-License-Identifier: Apache-2.0
"""Exceptions of mr_ident.

Every exception derives from :class:`MrIdentError` *and* from the matching
builtin, so callers can catch either ``MrIdentError`` or ``ValueError``.
Messages name the parameter, what was expected and what came.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence


class MrIdentError(Exception):
    """Root of every error raised on purpose by mr_ident.

    Examples
    --------
    A caller may catch the package's errors, or the builtin each also is:

    >>> from mr_ident import MrIdentError, time_lift
    >>> try:
    ...     time_lift([1.0, 2.0], 0)
    ... except MrIdentError as err:
    ...     print(type(err).__name__, isinstance(err, ValueError), err)
    ConfigError True ratio must be an integer >= 1, got 0
    """


class DimensionError(MrIdentError, ValueError):
    """An array has the wrong shape, or two arrays disagree in shape."""


class DataError(MrIdentError, ValueError):
    """Measured data is unusable: NaN/inf, too short, inconsistent columns."""


class ModelError(MrIdentError, ValueError):
    """A model file or system description is invalid (including an unstable loop)."""


class ConfigError(MrIdentError, ValueError):
    """An option or parameter is out of range or of the wrong type."""


def said(text: str, fields: Sequence[str], name: Callable[[str], str]) -> str:
    """``text`` with every ``{field}`` of ``fields`` said as ``name(field)``.

    Other braces (a source's ``{name=="j1"}``) are left alone.

    >>> said("give {fs_high} or {model}", ("fs_high", "model"), lambda f: "--" + f)
    'give --fs_high or --model'
    """
    for f in fields:
        text = text.replace("{" + f + "}", name(f))
    return text


class NamesFields(MrIdentError):
    """An error whose message names a request's fields: the base of the two below.

    The message holds ``{field}`` for each of ``fields`` (the request's attribute names);
    ``str()`` says them as they are, and each caller says them in its own words with
    :meth:`told`: the command line its flags (``--excitation-index``), the node its
    parameters. Other braces in the message (a source's ``{name=="j1"}``) are left alone.
    """

    def __init__(self, template: str, *fields: str) -> None:
        self.template, self.fields = template, fields
        super().__init__(self.told(str))

    def told(self, name: Callable[[str], str]) -> str:
        """The message with every field said as ``name(field)``."""
        return said(self.template, self.fields, name)


class FieldError(NamesFields, ConfigError):
    """A request's fields that do not go together or are out of range, named as fields.

    >>> err = FieldError("{excitation_index} goes with {period}", "excitation_index", "period")
    >>> str(err)
    'excitation_index goes with period'
    >>> err.told(lambda f: "--" + f.replace("_", "-"))
    '--excitation-index goes with --period'
    """


class DataFieldError(NamesFields, DataError):
    """Data that cannot be read as the request stands; the remedy names its fields.

    E.g. stamps too few to tell the rate: ``give {fs_high}``.
    """


class RecordingError(MrIdentError, OSError):
    """A recording could not be written to the end (e.g. the disk filled up)."""


def yaml_problem(err: Exception) -> str:
    """A PyYAML error on one line, with the file's line and column (1-based)."""
    mark = getattr(err, "problem_mark", None)
    text = getattr(err, "problem", None) or str(err).splitlines()[0]
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    ctx, cmark = getattr(err, "context", None), getattr(err, "context_mark", None)
    if ctx and cmark is not None:
        text += f" ({ctx} at line {cmark.line + 1}, column {cmark.column + 1})"
    return where + text
