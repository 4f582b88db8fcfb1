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
    """The diagnosis, the model it was of, and the record diagnosed (rates settled)."""

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

    ``notify`` hears each notice when it happens (the outcome keeps them all);
    ``progress`` each step of the diagnosis as it begins (:func:`~mr_ident.diagnose`).

    Raises
    ------
    ConfigError
        ``alpha`` outside (0, 1), rates that disagree (``rates`` "agree").
    DataError
        What the readers and :func:`~mr_ident.diagnosis.diagnose` raise.
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
    """
    from ..diagnosis.criterion.holes import diagnosable
    from ..diagnosis.monitoring.monitor import diagnose_window
    from ..diagnosis.report import report_dict

    window, note = diagnosable(window, model)
    report = report_dict(diagnose_window(model, window), extended_model=None, alpha=alpha)
    span = {"window_first": int(window.first), "window_samples": int(window.n_samples)}
    return report | span | ({"window_note": note} if note else {})
