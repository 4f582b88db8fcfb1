# SPDX-License-Identifier: Apache-2.0
"""Which span of a recording is used: the request's ``span``, latest|longest|all.

A hole of u or y (a dropped message, a NaN block) within the bridging limits
(:mod:`mr_ident.live.gaps`) is kept as missing samples: the span goes on over it. A
longer hole, a hole of r, a restarted publisher split the recording into several aligned
spans; an estimate never spans such a gap. The rule, in one place:

``longest`` (the default)
    the span with the most samples (the latest of equally long ones);
``latest``
    the last span (what the live node identifies from at the end of the recording);
``all``
    every sample: the recording must be one span, else an error says where the gaps are.

The reading says which span was used, where the gaps are (:func:`describe`) and why they
could not be bridged (the hole and the limit it broke).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..errors import ConfigError, DataError, DataFieldError

if TYPE_CHECKING:  # numpy-free at import: the parser takes SPANS from here
    from ..numerics.signals import LoopData
    from .align import Aligner

SPANS = ("longest", "latest", "all")
DEFAULT_SPAN = "longest"
#: The request's fields a reading's notes name as ``{field}`` (which span: ``{span}``), for
#: the caller to say in its own words (:class:`~mr_ident.app.requests.Notice`'s ``fields``).
NOTE_FIELDS = ("span",)


def check_span(span: str) -> str:
    """``span`` if it is one of :data:`SPANS`, else a ConfigError naming them."""
    if span not in SPANS:
        raise ConfigError(f"span must be one of {', '.join(SPANS)}, got {span!r}")
    return span


def gaps(spans: Sequence[tuple[int, int]]) -> list[tuple[int, int]]:
    """The index ranges between consecutive spans."""
    return [(a[1], b[0]) for a, b in zip(spans, spans[1:], strict=False) if b[0] > a[1]]


def describe(spans: Sequence[tuple[int, int]], most: int = 4) -> str:
    """The spans and the gaps between them in words (at most ``most`` of each listed)."""

    def ranges(xs: Sequence[tuple[int, int]]) -> str:
        shown = ", ".join(f"[{a}, {b})" for a, b in xs[:most])
        return shown + (f" and {len(xs) - most} more" if len(xs) > most else "")

    if not spans:
        return "no aligned span"
    longest = max(spans, key=lambda s: (s[1] - s[0], s[0]))
    g = gaps(spans)
    text = (
        f"{len(spans)} span(s) between gaps too long to bridge, the longest "
        f"[{longest[0]}, {longest[1]}) of {longest[1] - longest[0]} samples"
    )
    if g:
        text += f"; gaps at {ranges(g)}"
    return text


def choose(al: Aligner, span: str, *, what: str) -> tuple[LoopData, str]:
    """The span ``span`` of the aligned recording in ``al`` (an aligner with history).

    Returns the data and a note for the user ("" when the recording is gap-free).

    Raises
    ------
    DataError
        No aligned sample at all.
    DataFieldError
        ``span == "all"`` and the recording has gaps (naming ``{span}``).

    The note names ``{span}`` too (:data:`NOTE_FIELDS`).
    """
    check_span(span)
    spans = al.spans()
    if not spans:
        which = "r, u, y and the excitation's labels" if al.labels else "r, u and y"
        raise DataError(f"{what}: the recording holds no aligned samples of {which}")
    if len(spans) == 1:
        return al.extract(*spans[0]), ""
    if span == "all":
        raise DataFieldError(
            f"{what}: {{span}} all needs a recording without gaps too long to bridge; it "
            f"holds {describe(spans)}{why(al)} ({{span}} longest or latest uses one span)",
            "span",
        )
    if span == "latest":
        lo, hi = spans[-1]
    else:
        lo, hi = max(spans, key=lambda s: (s[1] - s[0], s[0]))
    note = (
        f"using the {span} span [{lo}, {hi}) of {hi - lo} samples; "
        f"{describe(spans)}{why(al)} ({{span}} latest|longest|all chooses)"
    )
    return al.extract(lo, hi), note


def why(al: Aligner, most: int = 3) -> str:
    """Why the streams split (the holes and the limits they broke), to append; "" if unknown."""
    b = al.bridging()
    breaks = list(al.breaks)
    if not breaks:
        return ""
    shown = "; ".join(breaks[:most]) + (
        f"; and {len(breaks) - most} more" if len(breaks) > most else ""
    )
    from .gaps import R_GAP_BLOCKS  # numpy's: not at import (the parser takes SPANS)

    r_gap = R_GAP_BLOCKS * al.ratio
    limit = (
        f" (bridged: holes of u, y {b.describe()}; of r, at most {r_gap} samples)"
        if b is not None
        else ""
    )
    return f"; split at: {shown}{limit}"
