# SPDX-License-Identifier: Apache-2.0
"""The verdict in one line: what the data show, in the order a control engineer asks.

The headline names, first,

1. **nonlinear distortion** (``"nonlinear_distortion"``) where a test found it
   (:mod:`~..criterion.nonlinearity`) and no linear extension closes the gap: nothing
   validated, or what validated still leaves part of y unexplained beyond the noise
   (:mod:`~..criterion.unexplained`). The validated linear causes (or the nominal model
   where none is) are then the best linear approximation (BLA) of the loop, named as
   such, not as the cause;
2. else the **causes applied** (the first names the cause, the rest follow), or the plant
   correction where no listed cause validated and it did (``"plant_correction"``);
3. else, where the model leaves part of y unexplained beyond the noise, **how much**
   (``"unexplained"``): the model is wrong in a way no listed cause and no correction
   describes;
4. else ``"none"``: the model explains the data to the noise.

Whatever the first clause, a part of y left beyond the noise is said, with how much: a
verdict never reads "none" with a fit below what the noise allows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..causes.cause import CauseFit
from ..criterion.nonlinearity import Nonlinearity
from ..criterion.unexplained import Unexplained


@dataclass(frozen=True)
class Headline:
    """The verdict: its cause's name, figures and sentence.

    Attributes
    ----------
    cause : str
        The first applied cause's name, ``"nonlinear_distortion"``, ``"plant_correction"``,
        ``"unexplained"`` or ``"none"``.
    parameters : dict
        The first applied cause's parameters; for the others the figures of the finding
        (``level_db``, ``unexplained_percent``).
    text : str
        The verdict in words.
    """

    cause: str
    parameters: dict[str, float] = field(default_factory=dict)
    text: str = ""


def headline(
    applied: list[CauseFit],
    corrected: bool,
    nonlinearity: Nonlinearity | None,
    left: Unexplained | None,
) -> Headline:
    """The verdict (module docstring) from what the diagnosis found and validated."""
    gap = left is not None and left.significant
    tail = f"; {left.text()}" if gap and left is not None else ""
    names = [a.description or a.cause for a in applied] + (
        ["a correction of the plant"] if corrected else []
    )
    if nonlinearity is not None and (gap or not names):
        params = {"level_db": nonlinearity.level_db}
        if left is not None:
            params["unexplained_percent"] = left.share
        bla = "the nominal model" if not names else "the model with " + "; ".join(names)
        return Headline(
            "nonlinear_distortion",
            params,
            f"{nonlinearity.text()}; the best linear approximation (BLA) of the loop is {bla}"
            + tail,
        )
    if names:
        cause = applied[0].cause if applied else "plant_correction"
        params = dict(applied[0].parameters) if applied else {}
        return Headline(cause, params, "; ".join(names) + tail)
    if gap and left is not None:
        return Headline(
            "unexplained",
            {"unexplained_percent": left.share},
            "no listed cause and no correction explains the data: " + left.text(),
        )
    return Headline("none", {}, "the model explains the data to the noise")
