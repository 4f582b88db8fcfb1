# SPDX-License-Identifier: Apache-2.0
"""``diagnose``: where and why a model disagrees with a recording.

:func:`diagnose_recording` is the one path of ``mr-ident diagnose`` and of every
``mr-ident batch --task diagnose`` job; :func:`window_report` that of the node's
``~/diagnose`` service (a window it holds in memory). The diagnosis is imported inside
the calls: ``identify`` never loads it (start-up, ``test_cli``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ..errors import ConfigError, FieldError
from .reading import read_for_diagnosis, read_settled
from .requests import DiagnoseRequest, Heard, Notice, Notify, ignore, load

if TYPE_CHECKING:
    from ..diagnosis.diagnose import Diagnosis
    from ..numerics.signals import LoopData
    from ..numerics.systems.model import Model
    from .requests import Reading, Specs


@dataclass(frozen=True)
class Diagnosed:
    """The diagnosis, the model it was of, and the record diagnosed (rates settled).

    Attributes
    ----------
    diagnosis : Diagnosis
        :func:`~mr_ident.diagnosis.diagnose`'s result.
    model : Model
        The model diagnosed, with the injection point the data show.
    data : LoopData
        The record diagnosed: its rates settled, its holes within the fits' limits.
    notices : tuple of Notice
        What the reading noticed.
    """

    diagnosis: Diagnosis
    model: Model
    data: LoopData
    notices: tuple[Notice, ...] = ()


def diagnose_recording(
    req: DiagnoseRequest,
    notify: Notify = ignore,
    progress: Callable[[str], None] | None = None,
) -> Diagnosed:
    """The diagnosis a request asks for (the report files are the caller's to write).

    Read the recording (and ``req.validate``, ``req.more``) as ``req.rates`` says, keep the
    holes the fits carry (beyond them: the longest stretch without one), state where r
    enters as the data show it, and diagnose (:func:`~mr_ident.diagnosis.diagnose`: the
    evidence, the causes in turn, the validation on held-out data).

    Parameters
    ----------
    req : DiagnoseRequest
        The recording, the model, the validation and further records, the options.
    notify : callable, optional
        Hears each :class:`~.requests.Notice` when it happens (the outcome keeps them all).
    progress : callable, optional
        Told each step of the diagnosis as it begins.

    Returns
    -------
    Diagnosed
        The diagnosis, the model it was of (its injection point the data's) and the record.

    Raises
    ------
    FieldError
        A :class:`~mr_ident.errors.ConfigError` naming the request's fields: ``alpha``
        outside (0, 1), sources for a data file, rates the flags, the file and the model
        disagree on (``rates`` "agree").
    DataFieldError
        A :class:`~mr_ident.errors.DataError` whose remedy names the request's fields (as
        :func:`~.identify.identify_recording`).
    ConfigError
        ``more`` without ``validate``; options out of range.
    DataError
        A recording that is missing or unreadable, N not a multiple of F, model and data
        that disagree on rates or channels, too little data.
    ModelError
        ``req.model`` a file that is not a valid model.

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.
    .. [2] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012, ch. 7.

    Examples
    --------
    The plant's gain is 30 % higher than the model says, 20 s in an NPZ:

    >>> import dataclasses, tempfile
    >>> from pathlib import Path
    >>> import numpy as np
    >>> from mr_ident import simulate
    >>> from mr_ident.app.diagnose import diagnose_recording
    >>> from mr_ident.app.requests import DiagnoseRequest, Reading
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [10.0], "den": [1.0, 10.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> true = dataclasses.replace(model, plant_gain=1.3, noise_std=0.01)
    >>> sim = simulate(true, duration=20.0, rng=np.random.default_rng(0))
    >>> path = Path(tempfile.mkdtemp()) / "loop.npz"
    >>> np.savez(path, r=sim.r, u=sim.u, y=sim.y)
    >>> got = diagnose_recording(DiagnoseRequest(Reading(path), model))
    >>> got.diagnosis.cause, round(got.diagnosis.parameters["gain"], 2), got.data.rates()
    ('gain_error', 1.3, (100.0, 2))
    """
    from ..diagnosis import diagnose
    from ..diagnosis.criterion.records import with_injection

    if not 0.0 < req.alpha < 1.0:
        raise FieldError(f"{{alpha}} must be in (0, 1), got {req.alpha}", "alpha")
    heard = Heard(notify)
    model = load(req.model)
    assert model is not None
    specs = req.reading.specs()
    data = _read(req, req.reading, model, specs, heard)
    model = with_injection(model, data, req.injection)
    val = None
    if req.validate is not None:
        val = _read(req, replace(req.reading, path=req.validate), model, specs, heard)
    if req.more and val is None:
        raise ConfigError("further records (more) need a validation record (validate) first")
    more = [_read(req, replace(req.reading, path=p), model, specs, heard) for p in req.more]
    d = diagnose(
        model,
        data,
        val,
        n=req.n,
        degree=req.degree,
        alpha=req.alpha,
        max_causes=req.max_causes,
        names=req.names or (str(req.reading.path), str(req.validate)),
        more=more,
        progress=progress,
    )
    return Diagnosed(d, model, data, tuple(heard.notices))


def _read(
    req: DiagnoseRequest, reading: Reading, model: Model, specs: Specs | None, notify: Notify
) -> LoopData:
    """One recording of the request, its rates settled as ``req.rates`` says.

    Its missing samples (NaN in u or y) within the limits stay (a note counts them); past
    them the longest stretch without one (a warning says which and why).
    """
    import numpy as np

    from ..diagnosis.criterion.holes import diagnosable

    if req.rates == "file":
        data = read_for_diagnosis(reading, model, req.period, specs, notify)
    else:
        raw, fs, settled = read_settled(
            reading, specs, req.fs_high, req.ratio, model, notify, complete=req.period is not None
        )
        data = replace(raw, fs_high=fs, ratio=settled.ratio, period=req.period)
    data, note = diagnosable(data, model, req.n, req.degree)  # holes beyond the limits: cut
    if note:
        notify(Notice("warning", f"{reading.path}: {note}"))
    n_y, n_u = int(np.isnan(data.y).sum()), int(np.isnan(data.u).sum())
    if n_y or n_u:
        notify(
            Notice(
                "note",
                f"{reading.path}: {n_y} samples of y and {n_u} of u missing (NaN) of "
                f"{data.n_samples}: diagnosed whole, each an unknown of the fits",
            )
        )
    return data


def window_report(model: Model, window: LoopData, alpha: float = 0.01) -> dict[str, object]:
    """The diagnosis of a live window as the JSON report of ``mr-ident diagnose --json``.

    ``window.first`` is the window's absolute sample index (the model's sampling phase is
    taken relative to it); the window's absolute span is added (``window_first``,
    ``window_samples``). A window with missing samples (NaN in u or y, holes the node
    bridged) is diagnosed whole, its holes unknowns of every fit, within the limits
    identification derives (beyond them: its longest stretch without one, whole periods,
    and ``window_note`` says so; :func:`~mr_ident.diagnosis.criterion.holes.diagnosable`).

    Parameters
    ----------
    model : Model
        The nominal model.
    window : LoopData
        The node's window (rates set, ``first`` its absolute index).
    alpha : float, default 0.01
        The per-bin test's family-wise false-alarm level, as reported.

    Returns
    -------
    dict
        The report (:func:`~mr_ident.diagnosis.report.report_dict`) with ``window_first``,
        ``window_samples`` and, where holes cut it, ``window_note``.

    Raises
    ------
    DataError
        Model and window disagree on rates or channels, or the window is too short.
    """
    from ..diagnosis.criterion.holes import diagnosable
    from ..diagnosis.monitoring.monitor import diagnose_window
    from ..diagnosis.report import report_dict

    window, note = diagnosable(window, model)
    report = report_dict(diagnose_window(model, window), extended_model=None, alpha=alpha)
    span = {"window_first": int(window.first), "window_samples": int(window.n_samples)}
    return report | span | ({"window_note": note} if note else {})
