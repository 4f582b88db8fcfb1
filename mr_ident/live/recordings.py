# SPDX-License-Identifier: Apache-2.0
"""A recording of any kind as loop data.

A CSV or NPZ file, or a bag (rosbag2 directory or ``.mcap``) read through sources or the
block contract.

The one place where the programs (``identify``, ``diagnose``, ``batch``) turn a path into
:class:`~mr_ident.numerics.signals.LoopData` and settle the rates. What the user should
know about the reading (a truncated file, samples left out before a gap) comes back as
notes, for the caller to print or to put in a table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, DataError, FieldError
from ..numerics.signals import LoopData
from .spans import DEFAULT_SPAN, check_span

if TYPE_CHECKING:
    from ..numerics.structure import Settled
    from ..numerics.systems.model import Model

#: Suffixes of the files read as loop data (bags are directories or these suffixes).
DATA_SUFFIXES = (".csv", ".npz")
BAG_SUFFIXES = (".mcap", ".db3", ".zstd")


@dataclass(frozen=True)
class Loaded:
    """A recording's loop data and what the reading noticed (empty if nothing)."""

    data: LoopData
    notes: tuple[str, ...] = ()


def is_bag(path: Path) -> bool:
    """A rosbag2 directory or a bag file (``.mcap``, ``.db3``, ``.mcap.zstd``)."""
    return path.is_dir() or path.suffix.lower() in BAG_SUFFIXES


def settle_rates(
    data: LoopData,
    *,
    fs_high: float | None,
    ratio: int | None,
    model: Model | None,
    injection: str | None = None,
) -> tuple[float, Settled]:
    """fs_high, and F and where r enters as the data show them, which the givens must agree with.

    fs_high from the request, the data file and the model; F and the injection point
    read from the data (:func:`~mr_ident.numerics.structure.read_structure`) and checked
    against the request's, the data file's and the model's
    (:func:`~mr_ident.numerics.structure.settle_structure`). FieldError naming the sources
    (the request's fields as ``{fs_high}``, ``{ratio}``, ``{injection}``) when none gives a
    rate or two disagree.
    """
    from ..numerics.structure import read_structure, settle_structure

    fs_sources = [
        (n, v)
        for n, v in (
            ("{fs_high}", fs_high),
            ("the data file", data.fs_high),
            ("the model", model.fs_high if model else None),
        )
        if v is not None
    ]
    if not fs_sources:
        raise FieldError(
            "fs_high unknown: pass {fs_high} or {model}, or use an NPZ/CSV that gives it",
            "fs_high",
            "model",
        )
    fs = fs_sources[0][1]
    for name, v in fs_sources[1:]:
        if abs(v - fs) > 1e-6 * fs:
            raise FieldError(
                f"fs_high disagrees: {fs_sources[0][0]} says {fs:g} Hz, {name} says {v:g} Hz",
                "fs_high",
            )

    def given(*pairs: tuple[str, Any]) -> list[tuple[str, Any]]:
        return [(n, v) for n, v in pairs if v is not None]

    try:
        settled = settle_structure(
            read_structure(data.r, data.u, data.y),
            ratios=given(
                ("{ratio}", ratio),
                ("the data file", data.ratio),
                ("the model", model.ratio if model else None),
            ),
            injections=given(
                ("{injection}", injection), ("the model", model.injection if model else None)
            ),
            phases=given(("the model", model.sample_phase if model else None)),
        )
    except FieldError:
        raise
    except ConfigError as err:  # the given named as the request's fields
        raise FieldError(str(err), "ratio", "injection") from err
    return float(fs), settled


def load_recording(
    path: str | Path,
    *,
    specs: Mapping[str, Sequence[str]] | None = None,
    topics: Sequence[str] | None = None,
    fs_high: float | None = None,
    ratio: int | None = None,
    span: str = DEFAULT_SPAN,
    msg_path: Sequence[str | Path] = (),
    labels: str = "",
    complete: bool = False,
) -> Loaded:
    """r, u, y of a recording.

    Parameters
    ----------
    path : a CSV/NPZ data file, a rosbag2 directory or an ``.mcap`` file
    specs : the r, u, y sources (``{"r": [...], "u": [...], "y": [...]}``) for a bag of
        per-sample or foreign messages; None: a bag follows the block contract
    topics : the block-contract topics of a bag (None: matched by name)
    fs_high, ratio : the rates a bag needs (a data file may give its own, kept as given:
        the caller settles them with :func:`settle_rates`)
    span : which gap-free span of a bag with gaps (:mod:`mr_ident.live.spans`)
    msg_path : directories of ``.msg`` files for types a bag does not define
    labels : the topic of an excitation's labels in a bag, read in the signals' form and
        aligned with them (the data's ``labels``; "": none)
    complete : a bag's holes of u and y are not bridged (every hole splits it into spans,
        ``span`` chooses): for a reader that needs every sample (the periodic average)

    Errors and notes name the request's fields as ``{field}`` (``{ratio}``, ``{r}``,
    ``{span}``: :class:`~mr_ident.errors.NamesFields`, :data:`~.spans.NOTE_FIELDS`), for the
    caller to say in its own words.
    """
    check_span(span)
    p = Path(path)
    if not p.exists():
        raise DataError(
            f"{str(p)!r} does not exist (a data file .csv or .npz, a rosbag2 directory, or a "
            ".mcap, .db3 or .mcap.zstd bag)"
        )
    if not is_bag(p):
        if labels:
            raise FieldError(
                f"excitation labels are read from a bag; {str(p)!r} is a data file (an NPZ "
                "of r, u, y of shape (M realizations, n) is cut by {period} N)",
                "period",
            )
        if specs is not None:
            raise FieldError(
                f"{{r}}/{{u}}/{{y}} name sources in a bag; {str(p)!r} is a data file (give it "
                "without them)",
                "r",
                "u",
                "y",
            )
        from ..io.datafile import read_data

        return Loaded(read_data(p))
    notes: list[str] = []
    from .gaps import NO_BRIDGING as no

    if specs is None:
        from .replay import recorded_signals

        if ratio is None:
            raise FieldError("ratio F unknown: pass {ratio} or {model}", "ratio", "model")
        if fs_high is None:
            raise FieldError("fs_high unknown: pass {fs_high} or {model}", "fs_high", "model")
        data, info = recorded_signals(
            p, ratio, topics=topics, span=span, labels=labels, bridge=no if complete else None
        )
        data = replace(data, fs_high=fs_high, ratio=ratio)
    else:
        from .replay import bag_signals

        data, info = bag_signals(
            p,
            specs,
            fs_high=fs_high,
            ratio=ratio,
            span=span,
            msg_path=msg_path,
            labels=labels,
            bridge=no if complete else None,
        )
    if info.truncated:
        notes.append(f"{p} is truncated ({info.reason}); using the {data.n_samples} samples read")
    if info.broken:
        notes.append(f"{p}: {info.broken}")
    return Loaded(data, tuple(notes))


def find_topic(
    path: str | Path,
    topic: str,
    *,
    exact: bool,
    msg_path: Sequence[str | Path] = (),
) -> tuple[str | None, list[str]]:
    """The bag's topic that is ``topic`` (or None), and every topic of the bag (sorted).

    ``exact``: names equal (sources); else matched as the block contract's topics
    (:func:`~mr_ident.io.recording.matches_topic`).
    """
    from ..io.bags import Bag
    from ..io.recording import matches_topic

    names = sorted(Bag.open(path, msg_path=msg_path).scanned_topics())
    return next((t for t in names if matches_topic(t, topic, exact)), None), names
