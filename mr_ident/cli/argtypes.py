# SPDX-License-Identifier: Apache-2.0
"""Argument types of the command line: each parses one option's text or names what came."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def int_at_least(low: int) -> Callable[[str], int]:
    """The parser of an integer >= ``low``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {v}")
        return v

    return parse


def auto_or_int(low: int) -> Callable[[str], int | str]:
    """The parser of "auto" or an integer >= ``low``."""

    def parse(text: str) -> int | str:
        if text.strip().lower() == "auto":
            return "auto"
        try:
            v = int(text)
        except ValueError:
            v = low - 1
        if v < low:
            raise argparse.ArgumentTypeError(
                f'expected "auto" or an integer >= {low}, got {text!r}'
            )
        return v

    return parse


#: ``--n``: "auto" or an integer >= 1.
window_n = auto_or_int(1)
#: ``identify --period``: "auto" (from the excitation's labels) or an integer >= 4.
period_or_auto = auto_or_int(4)


def band(text: str) -> tuple[float, float]:
    """``LO,HI`` in Hz."""
    parts = text.split(",")
    try:
        lo, hi = (float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LO,HI in Hz, got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
        raise argparse.ArgumentTypeError(f"expected 0 <= LO < HI, got {text!r}")
    return lo, hi


def frequencies(text: str) -> tuple[float, ...]:
    """Positive frequencies in Hz, separated by commas."""
    out = []
    for part in text.split(","):
        try:
            f = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected frequencies in Hz separated by commas, got {text!r}"
            ) from None
        if not math.isfinite(f) or f <= 0:
            raise argparse.ArgumentTypeError(f"frequencies must be positive, got {part!r}")
        out.append(f)
    return tuple(out)
