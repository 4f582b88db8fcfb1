# SPDX-License-Identifier: Apache-2.0
"""``identify``: P_h and the PFG from a recording, or the BLA of periodic data.

:func:`identify_recording` is the one path of ``mr-ident identify`` and of every
``mr-ident batch --task identify`` job: read (:mod:`.reading`), settle the rates, take a
low-rate y as such, check the model against the data, identify. With a ``period`` it hands
over to :mod:`.periodic` (the best linear approximation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..errors import DataError, FieldError
from .reading import read_settled
from .requests import Heard, IdentifyRequest, Notice, Notify, ignore, load

if TYPE_CHECKING:
    from ..numerics.results import Identification
    from ..numerics.systems.model import Model
    from .periodic import PeriodicBLA, SlowPlant


@dataclass(frozen=True)
class Identified:
    """P_h and the PFG of a recording, and what was read.

    ``first``, ``n_samples``: the record identified (its first sample index, its length);
    ``model``: the model given (loaded), for the plots' reference; ``structure``: what the
    data showed of the loop (the hold, F, where r enters), in words.
    """

    identification: Identification
    fs_high: float
    ratio: int
    first: int
    n_samples: int
    method: str
    model: Model | None
    notices: tuple[Notice, ...] = ()
    structure: str = ""


def identify_recording(
    req: IdentifyRequest,
    notify: Notify = ignore,
    progress: Callable[[str], None] | None = None,
) -> Identified | PeriodicBLA | SlowPlant:
    """The identification a request asks for (the result file is the caller's to write).

    ``notify`` hears each notice when it happens (the outcome keeps them all);
    ``progress`` each step (reading, identifying) as it begins.

    Raises
    ------
    ConfigError
        Options that do not go together, rates nothing gives or that disagree.
    DataError
        A model of other dimensions than the data; what the readers and
        :func:`~mr_ident.numerics.identify.identify` raise.
    """
    heard = Heard(notify)
    step = progress or (lambda _: None)
    step(f"reading {req.reading.path}")
    if req.period is not None:
        from .periodic import periodic_recording

        return periodic_recording(req, heard)
    if req.excitation_index:
        raise FieldError(
            "{excitation_index} goes with {period} (the BLA of periodic data)",
            "excitation_index",
            "period",
        )
    from ..numerics.identify import identify
    from ..numerics.signals import LoopData

    model = load(req.model)
    specs = req.reading.specs()
    data, fs, settled = read_settled(
        req.reading, specs, req.fs_high, req.ratio, model, heard, injection=req.injection
    )
    F, N = settled.ratio, data.n_samples
    y_phase = 0
    if req.y_rate == "low" and data.y_step == 1:  # a bag's low-rate y, held on the grid
        from ..live.estimate import low_rate_output

        y_low, y_phase = low_rate_output(data.first, data.y, F)
        data = LoopData(data.r, data.u, y_low, data.fs_high, data.ratio, data.first)
        heard(
            Notice(
                "note",
                f"y at the low rate: its samples at sample {y_phase} of each period (F = {F})",
                "result",
            )
        )
    elif req.y_rate == "high" and data.y_step != 1:
        raise FieldError(f"{{y_rate}} high, but y has N/F = {data.y.shape[0]} samples", "y_rate")
    elif data.y_step != 1:
        y_phase = data.y_phase
        heard(
            Notice(
                "note",
                f"y has {data.y.shape[0]} samples, r and u {N}: y is taken as the output at "
                f"the low rate (y_h at samples {y_phase}, {y_phase} + F, ...; F = {F})",
                "result",
            )
        )
    loop: dict[str, Any] = {}
    if model is not None:
        if model.n_y != data.y.shape[1] or model.n_u != data.u.shape[1]:
            raise DataError(
                f"model is {model.n_y}x{model.n_u} (n_y x n_u) but the data has "
                f"{data.y.shape[1]} output and {data.u.shape[1]} input channel(s)"
            )
        loop = model.identify_arguments(N)
    if settled.injection == "setpoint":
        q = settled.phase if settled.phase is not None else loop.get("phase", 0)
        loop = loop | {"phase": q}
    step(f"identifying P_h from {N} samples ({req.method})")
    ident = identify(
        data.r,
        data.u,
        data.y,
        fs_high=fs,
        ratio=F,
        method=req.method,
        n=req.n,
        degree=req.degree,
        local=req.local,
        keep_lifted=False,
        workers=req.workers,
        y_phase=y_phase,
        injection=settled.injection,
        **loop,
    )  # the result holds P_h and the PFG
    for note in settled.notes:
        heard(Notice("warning", note))
    if ident.undetermined is not None:
        heard(
            Notice(
                "note",
                f"{settled.found.describe()}; {int(ident.undetermined.sum())} bins near the "
                f"hold's zeros (multiples of {fs / F:g} Hz) are not determined",
                "result",
            )
        )
    return Identified(
        ident,
        fs,
        F,
        data.first,
        N,
        ident.plant.method,
        model,
        tuple(heard.notices),
        settled.found.describe(),
    )
