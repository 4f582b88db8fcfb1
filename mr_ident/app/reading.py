# SPDX-License-Identifier: Apache-2.0
"""A request's recording as loop data: read once, the rates settled, what was noticed said.

Over :func:`~mr_ident.live.recordings.load_recording` (files and bags alike); its notes come
back as warnings (:class:`~.requests.Notice`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import DataError
from .requests import Notice, Notify, Reading, Specs

if TYPE_CHECKING:
    from ..numerics.signals import LoopData
    from ..numerics.structure import Settled
    from ..numerics.systems.model import Model


def read_loop(
    reading: Reading,
    specs: Specs | None,
    fs_high: float | None,
    ratio: int | None,
    notify: Notify,
    *,
    labels: str = "",
    path: Path | None = None,
    complete: bool = False,
) -> LoopData:
    """r, u, y of ``reading`` (``path`` instead of its own: a second recording read alike).

    Parameters
    ----------
    reading : Reading
        The recording and how to read it.
    specs : dict or None
        The checked sources (:meth:`Reading.specs`; None: a data file, or a bag's block
        contract).
    fs_high, ratio : float or None, int or None
        The rates a bag needs (a data file keeps its own).
    notify : callable
        Hears what the reading noticed, as warnings (fields named as ``{span}``).
    labels : str, optional
        The topic of an excitation's labels in a bag ("": none).
    path : Path, optional
        Another recording to read as ``reading`` says.
    complete : bool, default False
        A bag's holes split it (none bridged as missing samples).

    Returns
    -------
    LoopData
        The rates as the file gives them (None where it gives none).

    Raises
    ------
    FieldError
        Sources or labels for a data file, a bag's rates not given.
    DataFieldError
        Rates the stamps cannot tell, bare topics given as sources, ``span`` "all" on a
        recording with gaps.
    DataError
        A recording that is missing, unreadable, or holds no aligned samples.
    ConfigError
        ``span`` not one of longest, latest, all.
    """
    from ..live.recordings import load_recording
    from ..live.spans import DEFAULT_SPAN, NOTE_FIELDS

    loaded = load_recording(
        path or reading.path,
        specs=specs,
        topics=reading.topics,
        fs_high=fs_high,
        ratio=ratio,
        span=reading.span or DEFAULT_SPAN,
        msg_path=reading.msg_path,
        labels=labels,
        complete=complete,
    )
    for note in loaded.notes:
        notify(Notice("warning", note, fields=NOTE_FIELDS))
    return loaded.data


def read_for_diagnosis(
    reading: Reading,
    model: Model,
    period: int | None,
    specs: Specs | None,
    notify: Notify,
    *,
    path: Path | None = None,
) -> LoopData:
    """Data for diagnose from a file or a bag; rates from the file where given, else the model.

    Parameters
    ----------
    reading : Reading
        The recording and how to read it.
    model : Model
        Gives the rates a bag is read at, and a data file's where it gives none.
    period : int or None
        Periodic data's period (its holes split a bag: the periods need every sample).
    specs : dict or None
        The checked sources (None: a data file, or a bag's block contract).
    notify : callable
        Hears what the reading noticed.
    path : Path, optional
        Another recording to read as ``reading`` says.

    Returns
    -------
    LoopData
        With the rates and ``period`` set.

    Raises
    ------
    DataError
        N not a multiple of F; as :func:`read_loop`.
    FieldError, DataFieldError, ConfigError
        As :func:`read_loop`.
    """
    from ..live.recordings import is_bag

    where = path or reading.path
    data = read_loop(
        reading, specs, model.fs_high, model.ratio, notify, path=where, complete=period is not None
    )  # holes bridged as missing samples (periodic data: split at them)
    if is_bag(where):  # a bag's rates are the model's
        fs, F = model.fs_high, model.ratio
    else:
        fs = data.fs_high if data.fs_high is not None else model.fs_high
        F = data.ratio if data.ratio is not None else model.ratio
    if data.n_samples % F:
        raise DataError(f"{where}: N = {data.n_samples} samples is not a multiple of ratio F={F}")
    return replace(data, fs_high=float(fs), ratio=int(F), period=period)


def read_settled(
    reading: Reading,
    specs: Specs | None,
    fs_high: float | None,
    ratio: int | None,
    model: Model | None,
    notify: Notify,
    *,
    complete: bool = False,
    injection: str | None = None,
) -> tuple[LoopData, float, Settled]:
    """r, u, y, fs_high and the loop's structure: the data's, agreed by every given.

    A bag is read at the request's rates, else the model's; then
    :func:`~mr_ident.live.recordings.settle_rates` checks that the request, the file, the
    model and the stamps agree with what the data show (F, where r enters, a setpoint's
    phase). Where r's holes leave too many of its samples undetermined, the recording is
    read again without bridging and its longest span used (with a warning).

    Parameters
    ----------
    reading : Reading
        The recording and how to read it.
    specs : dict or None
        The checked sources (None: a data file, or a bag's block contract).
    fs_high, ratio : float or None, int or None
        The request's rates (None: the file's, the model's or the stamps').
    model : Model or None
        The model given, whose rates, injection point and phase must agree too.
    notify : callable
        Hears what the reading noticed.
    complete : bool, default False
        A bag's holes split it (none bridged).
    injection : {"plant_input", "setpoint"} or None
        Where the request says r entered (None: as the data show it).

    Returns
    -------
    data : LoopData
        As read (its rates the file's).
    fs_high : float
        The settled high rate.
    settled : Settled
        F, where r enters, the phase, what the data show; what the structure leaves to a
        default is in ``Settled.notes``, for the caller to say once its result stands.

    Raises
    ------
    FieldError
        Rates nothing gives, or that the request, the file, the model and the data disagree
        on (F, where r enters); as :func:`read_loop`.
    DataFieldError, DataError, ConfigError
        As :func:`read_loop`.
    """
    from ..live.recordings import settle_rates

    data = read_loop(
        reading,
        specs,
        fs_high or (model.fs_high if model else None),
        ratio or (model.ratio if model else None),
        notify,
        complete=complete,
    )
    fs, settled = settle_rates(
        data, fs_high=fs_high, ratio=ratio, model=model, injection=injection
    )
    why = "" if complete else _r_undetermined(data, settled, model)
    if why:
        notify(Notice("warning", f"{reading.path}: {why}; the longest span without holes is used"))
        return read_settled(
            reading, specs, fs_high, ratio, model, notify, complete=True, injection=injection
        )
    return data, fs, settled


def _r_undetermined(data: LoopData, settled: Settled, model: Model | None) -> str:
    """Why r's bridged holes leave more unknown samples than a fit takes, or ""."""
    import numpy as np

    from ..numerics.missing_r import recover_r

    if not np.isnan(data.r).any():
        return ""
    phase = settled.phase if settled.phase is not None else (model.sample_phase if model else 0)
    try:
        recover_r(
            data.r, data.u, data.y, ratio=settled.ratio, injection=settled.injection, phase=phase
        )
    except DataError as e:
        return str(e).split(":")[0]  # the count and the share
    return ""
