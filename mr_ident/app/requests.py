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

    ``sources``: ``{"r": [...], "u": [...], "y": [...]}`` with empty lists for those not
    given. ConfigError naming the missing ones.
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

    The options are those of ``mr-ident identify`` (and of its flags' names in the
    messages): ``fs_high``/``ratio`` None: from the file, the model or the stamps;
    ``y_rate`` "low"/"high"/None; ``period`` an int N, "auto" or None;
    ``excitation_index`` the labels' topic of a bag; ``workers`` identification threads
    (None: every CPU this process may use); ``injection`` where r entered
    (``plant_input``/``setpoint``; None: as the data show it).
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

    ``validate``: a second recording (read as the first) to validate on; ``more``: further
    recordings of other excitation realizations, compared with the two as realizations
    (nonlinear distortion across records); ``names``: how the report names the first two
    (default: their paths). ``rates``: "file" takes a data file's own
    rates where it gives them, else the model's (``diagnose``); "agree": ``fs_high``,
    ``ratio``, the file and the model must agree (``batch``). ``injection``: where r
    entered (None: as the data show it).
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

    ``params``: the node's parameters file (None: the node's defaults); ``y_rate`` and
    ``excitation_index`` replace its values where given; ``fs_high``/``ratio`` with
    sources: default from ``params``, else read off the stamps. ``stop``: the window
    ending at or before this sample index.
    """

    reading: Reading
    params: Path | None = None
    fs_high: float | None = None
    ratio: int | None = None
    stop: int | None = None
    y_rate: str | None = None
    excitation_index: str | None = None


def load(model: Model | Path | None) -> Model | None:
    """The model itself: loaded from its YAML where a path is given."""
    if model is None or not isinstance(model, (str, Path)):
        return model
    from ..io.modelfile import load_model

    return load_model(model)
