# SPDX-License-Identifier: Apache-2.0
"""What the application is asked: frozen requests, and the notices that come back.

Plain data, importable without numpy (the command line builds them at once). A model is
given as the loaded :class:`~mr_ident.numerics.systems.model.Model` (``batch`` loads it
once) or as its YAML path, read only where the request needs it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from ..errors import FieldError, said

if TYPE_CHECKING:
    from ..numerics.systems.model import Model

Specs = dict[str, list[str]]


@dataclass(frozen=True)
class Notice:
    """Something the user should know, said once.

    ``kind`` is the word it is shown with (``warning: ...``, ``note: ...``); ``about``
    "reading": about how the recording was read (the command line's stderr), "result":
    part of the result's own account (its stdout). ``fields``: the request's fields the
    text names as ``{field}`` (:class:`~mr_ident.errors.FieldError`'s convention), said by
    each caller in its own words (:meth:`told`).
    """

    kind: Literal["warning", "note"]
    text: str
    about: Literal["reading", "result"] = "reading"
    fields: tuple[str, ...] = ()

    def told(self, name: Callable[[str], str] = str) -> str:
        """The text with every field said as ``name(field)`` (default: as it is)."""
        return said(self.text, self.fields, name)

    def line(self, name: Callable[[str], str] = str) -> str:
        """The notice as one line: ``<kind>: <text>``, the fields said as ``name(field)``."""
        return f"{self.kind}: {self.told(name)}"


Notify = Callable[[Notice], None]


def ignore(_: Notice) -> None:
    """The default ``notify``: the notices are only collected in the outcome."""


class Heard:
    """A ``notify`` that keeps what it passes on (the outcome's ``notices``)."""

    def __init__(self, notify: Notify) -> None:
        self.notify = notify
        self.notices: list[Notice] = []

    def __call__(self, notice: Notice) -> None:
        """Keep ``notice`` and pass it on."""
        self.notices.append(notice)
        self.notify(notice)


def source_specs(sources: Mapping[str, Sequence[str]] | None) -> Specs | None:
    """The r, u, y sources as given, or None when none was (all three needed otherwise).

    Parameters
    ----------
    sources : mapping or None
        ``{"r": [...], "u": [...], "y": [...]}`` with empty lists for those not given.

    Returns
    -------
    dict or None
        Each signal's list of source specs; None when no source is given.

    Raises
    ------
    FieldError
        Some given, not all: naming the missing ones as fields.

    Examples
    --------
    >>> from mr_ident.app.requests import source_specs
    >>> source_specs({"r": [], "u": [], "y": []}) is None
    True
    >>> try:
    ...     source_specs({"r": ["/a.x"], "u": [], "y": []})
    ... except ValueError as err:
    ...     print(err)
    ...     print(err.told(lambda f: "--" + f))
    give all of r, u, y with a bag; missing u, y
    give all of --r, --u, --y with a bag; missing --u, --y
    """
    specs = {sig: list((sources or {}).get(sig, ()) or ()) for sig in ("r", "u", "y")}
    if not any(specs.values()):
        return None
    missing = [f"{{{sig}}}" for sig, v in specs.items() if not v]
    if missing:
        raise FieldError(
            f"give all of {{r}}, {{u}}, {{y}} with a bag; missing {', '.join(missing)}",
            "r",
            "u",
            "y",
        )
    return specs


@dataclass(frozen=True)
class Reading:
    """A recording and how to read it.

    Attributes
    ----------
    path : Path
        A CSV/NPZ data file or a bag (rosbag2 directory, ``.mcap``, ``.db3``).
    sources : mapping or None
        The ``r``, ``u``, ``y`` source specs as given (lists; empty: not given); checked
        (:func:`source_specs`) only where a bag is read through them.
    topics : sequence of str or None
        The block-contract topics of a bag (None: matched by name).
    span : str or None
        Which span of a bag split by gaps too long to bridge (None: the reader's default).
    msg_path : tuple of Path
        Directories of ``.msg`` files for types a bag does not define.
    """

    path: Path
    sources: Mapping[str, Sequence[str]] | None = None
    topics: Sequence[str] | None = None
    span: str | None = None
    msg_path: tuple[Path, ...] = ()

    def specs(self) -> Specs | None:
        """The checked sources (:func:`source_specs`)."""
        return source_specs(self.sources)


@dataclass(frozen=True)
class IdentifyRequest:
    """P_h and the PFG from a recording, or with ``period`` the BLA of periodic data.

    The options are those of ``mr-ident identify``; messages name them as fields
    (``{fs_high}``), which the command line says as its flags.

    Attributes
    ----------
    reading : Reading
        The recording and how to read it.
    model : Model, path or None
        The model: its controller gives the PFG, its rates and injection point are checked.
    fs_high, ratio : float or None, int or None
        None: from the file, the model or the stamps.
    method, n, degree, local
        As :func:`~mr_ident.numerics.identify.identify`.
    y_rate : {"low", "high"} or None
        Whether y was measured at the low rate (None: as the file shows it).
    period : int, "auto" or None
        Periodic data's period in samples ("auto": a bag's labels say it); None: not
        periodic.
    transient_periods : int
        Whole periods dropped at the start of each realization.
    excitation_index : str or None
        The topic of the excitation's labels in a bag.
    workers : int or None
        Identification threads (None: every CPU this process may use).
    injection : {"plant_input", "setpoint"} or None
        Where r entered (None: as the data show it).
    """

    reading: Reading
    model: Model | Path | None = None
    fs_high: float | None = None
    ratio: int | None = None
    method: str = "freq-lifted"
    n: int | str | None = "auto"
    degree: int = 2
    local: str = "polynomial"
    y_rate: str | None = None
    period: int | str | None = None
    transient_periods: int = 1
    excitation_index: str | None = None
    workers: int | None = None
    injection: str | None = None


@dataclass(frozen=True)
class DiagnoseRequest:
    """Where and why ``model`` disagrees with a recording (``mr-ident diagnose``).

    Attributes
    ----------
    reading : Reading
        The recording and how to read it.
    model : Model or path
        The nominal model.
    validate : Path or None
        A second recording (read as the first) to validate on.
    period : int or None
        Periodic data's period in samples.
    n, degree, alpha, max_causes
        As :func:`~mr_ident.diagnosis.diagnose`.
    fs_high, ratio : float or None, int or None
        The rates given (with ``rates`` "agree").
    rates : {"file", "agree"}
        "file" takes a data file's own rates where it gives them, else the model's
        (``diagnose``); "agree": ``fs_high``, ``ratio``, the file and the model must agree
        (``batch``).
    names : (str, str) or None
        How the report names the first two recordings (default: their paths).
    more : tuple of Path
        Further recordings of other excitation realizations, compared with the two as
        realizations (nonlinear distortion across records).
    injection : {"plant_input", "setpoint"} or None
        Where r entered (None: as the data show it).
    """

    reading: Reading
    model: Model | Path
    validate: Path | None = None
    period: int | None = None
    n: int | str | None = None
    degree: int = 2
    alpha: float = 0.01
    max_causes: int = 3
    fs_high: float | None = None
    ratio: int | None = None
    rates: Literal["file", "agree"] = "file"
    names: tuple[str, str] | None = None
    more: tuple[Path, ...] = ()
    injection: str | None = None


@dataclass(frozen=True)
class ReplayRequest:
    """A recording through the node's own steps (``mr-ident replay``).

    Attributes
    ----------
    reading : Reading
        The recording and how to read it.
    params : Path or None
        The node's parameters file (None: the node's defaults).
    fs_high, ratio : float or None, int or None
        With sources: default from ``params``, else read off the stamps.
    stop : int or None
        The window ending at or before this sample index (None: the end).
    y_rate, excitation_index : str or None
        Replace the parameters' values where given.
    """

    reading: Reading
    params: Path | None = None
    fs_high: float | None = None
    ratio: int | None = None
    stop: int | None = None
    y_rate: str | None = None
    excitation_index: str | None = None


def load(model: Model | Path | None) -> Model | None:
    """The model itself: loaded from its YAML where a path is given.

    Parameters
    ----------
    model : Model, path or None

    Returns
    -------
    Model or None

    Raises
    ------
    ModelError
        The file cannot be read, is not YAML, or is not a valid model.
    """
    if model is None or not isinstance(model, (str, Path)):
        return model
    from ..io.modelfile import load_model

    return load_model(model)
