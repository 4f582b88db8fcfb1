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

    Attributes
    ----------
    identification : Identification
        P_h with its std, the PFG from data and (with a model's controller) from P_h.
    fs_high : float
    ratio : int
        The settled rates.
    first, n_samples : int
        The record identified: its first sample index, its length.
    method : str
    model : Model or None
        The model given (loaded), for the plots' reference.
    notices : tuple of Notice
        What the reading and the identification noticed.
    structure : str
        What the data showed of the loop (the hold, F, where r enters), in words.
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

    Read the recording (:mod:`.reading`), settle the rates and the loop's structure with what
    the data show, take a low-rate y as such, check the model against the data, identify
    (:func:`~mr_ident.numerics.identify.identify` [1]_ [2]_); with ``req.period`` the best
    linear approximation of periodic data instead (:func:`.periodic.periodic_recording`).

    Parameters
    ----------
    req : IdentifyRequest
        The recording, how to read it, the rates, the method and its options.
    notify : callable, optional
        Hears each :class:`~.requests.Notice` when it happens (the outcome keeps them all).
    progress : callable, optional
        Told each step (reading, identifying) as it begins.

    Returns
    -------
    Identified
        P_h and the PFG (the model's controller given), the rates and the record used.
    PeriodicBLA or SlowPlant
        With ``req.period``: the BLA, or P_h of an NPZ whose y holds the low-rate samples.

    Raises
    ------
    FieldError
        A :class:`~mr_ident.errors.ConfigError` naming the request's fields: options that
        do not go together (``excitation_index`` without ``period``, ``y_rate`` "high" for a
        low-rate y, sources for a data file), rates nothing gives, or that the flags, the
        file, the model and the data disagree on (F, where r enters).
    DataFieldError
        A :class:`~mr_ident.errors.DataError` whose remedy names the request's fields: a
        bag's rates the stamps cannot tell, bare topics given as sources, ``span`` "all" on
        a recording with gaps.
    DataError
        A recording that is missing or unreadable, a model of other dimensions than the
        data, too little data, too many missing samples (as
        :func:`~mr_ident.numerics.identify.identify`).
    ConfigError
        Options out of range (``method``, ``n``, ``degree``, ``local``).
    ModelError
        ``req.model`` a file that is not a valid model.
    DimensionError
        Signals whose shapes do not go together.

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.
    .. [2] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012: ch. 7 (the LPM), sec. 3.6 and 4.3 (the BLA of
       periodic data).

    Examples
    --------
    A first-order plant under a proportional controller at half its rate, 40 s of white
    reference in an NPZ that gives its rates; the data show the hold of u - r (F = 2, r
    at the plant input):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from mr_ident import simulate
    >>> from mr_ident.app.identify import identify_recording
    >>> from mr_ident.app.requests import IdentifyRequest, Reading
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [10.0], "den": [1.0, 10.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> sim = simulate(model, duration=40.0, rng=np.random.default_rng(0))
    >>> path = Path(tempfile.mkdtemp()) / "loop.npz"
    >>> np.savez(path, r=sim.r, u=sim.u, y=sim.y, fs_high=100.0, ratio=2)
    >>> got = identify_recording(IdentifyRequest(Reading(path), model=model))
    >>> got.ratio, got.n_samples, got.identification.plant.response.shape
    (2, 4000, (2000, 1, 1))
    >>> got.structure
    'u - r changes every 2 samples (at sample 0 of each block): F = 2, r enters at the plant input'
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
    from ..numerics.structure import NOTE_FIELDS

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
        heard(Notice("warning", note, fields=NOTE_FIELDS))
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
