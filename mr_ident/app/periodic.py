# SPDX-License-Identifier: Apache-2.0
"""``identify --period``: the best linear approximation of periodic data.

An NPZ holds r, u, y of shape (M realizations, n), periods counted from each row's start.
A bag is cut by the excitation's labels recorded beside r (``TOPIC/excitation_index`` of
``mr-ident excite --publish TOPIC``, read in the signals' form and aligned with them;
``--period auto`` reads the period off them); without them, with ``--period N``, its record
is one realization counted from its first sample. Both go through
:mod:`mr_ident.live.periodic`, as ``replay`` and the node do. An NPZ whose y holds the
low-rate samples only gives P_h on a rotated lifted design (:class:`SlowPlant`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ..errors import DataError, DataFieldError, FieldError
from .reading import read_loop
from .requests import Heard, IdentifyRequest, Notice, Specs, load

if TYPE_CHECKING:
    from ..io.periodicfile import Realizations
    from ..live.periodic import Periods
    from ..numerics.excitation.bla import BLA, BandLevels
    from ..numerics.results import Identification


@dataclass(frozen=True)
class PeriodicBLA:
    """The BLA of periodic data: the cut (``periods``), the rates, the distortion per band.

    Attributes
    ----------
    bla : BLA
        P_h at the excited lines with its noise and total std (and the PFG from data where
        the design measured it).
    periods : Periods
        The realizations x whole periods used.
    fs_high : float
    ratio : int
    bands : tuple of BandLevels
        The noise and nonlinear distortion per band (several periods only).
    notices : tuple of Notice
    """

    bla: BLA
    periods: Periods
    fs_high: float
    ratio: int
    bands: tuple[BandLevels, ...] = ()
    notices: tuple[Notice, ...] = ()


@dataclass(frozen=True)
class SlowPlant:
    """P_h (and the PFG from data) of an NPZ whose y holds the low-rate samples only.

    Attributes
    ----------
    identification : Identification
        P_h at the lines the rotated lifted design determines, with its std.
    realizations, periods : int
        The whole periods used (after the transient), per realization.
    notices : tuple of Notice
    """

    identification: Identification
    realizations: int
    periods: int
    notices: tuple[Notice, ...] = ()


def periodic_recording(req: IdentifyRequest, heard: Heard) -> PeriodicBLA | SlowPlant:
    """The BLA of an NPZ of realizations or of a bag (``req.period`` given).

    An NPZ's rows are the realizations, its periods counted from each row's start; a bag is
    cut by the excitation's labels (``req.excitation_index``, default the topic beside r's),
    else counted from its first sample with ``req.period`` N. Both through
    :func:`~mr_ident.live.periodic.periodic_bla` [1]_, with the nonlinear distortion per band
    where there are several periods.

    Parameters
    ----------
    req : IdentifyRequest
        The recording and its options; ``req.period`` an int N or "auto" (a bag's labels).
    heard : Heard
        Hears the notices (and keeps them for the outcome).

    Returns
    -------
    PeriodicBLA
        The BLA with its noise and nonlinear std, the cut, the rates, the bands.
    SlowPlant
        P_h from an NPZ whose y holds the low-rate samples only.

    Raises
    ------
    FieldError
        ``period`` "auto" or ``excitation_index`` for an NPZ, an NPZ without ``fs_high``.
    DataFieldError
        u or y miss samples in the periods kept; no labels in a bag with ``period`` "auto";
        a ``period`` that does not cut a low-rate y's realizations into whole periods.
    DataError
        A recording that is missing or unreadable, fewer samples than one period, labels
        that do not fit the period, a low-rate y without a rotated lifted design.
    ConfigError
        A period that does not divide an NPZ's realizations.

    References
    ----------
    .. [1] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012, sec. 3.6 and 4.3.
    """
    from ..live.periodic import cut_by_count, periodic_bla
    from ..live.recordings import is_bag
    from ..numerics.excitation.bla import distortion_by_band

    if is_bag(req.reading.path):
        cut, fs, F = _bag_periods(req, heard)
    else:
        data, fs, F = _read_npz(req)
        if data.low_rate_y:
            return _npz_slow(req, data, fs, F, heard)
        assert isinstance(req.period, int)  # "auto" refused by _read_npz
        cut = cut_by_count(data.r, data.u, data.y, req.period, req.transient_periods)
    bla = periodic_bla(cut, F)
    if bla.pfg is not None and _setpoint(cut):
        bla = replace(bla, pfg=None, pfg_std=None)
        heard(Notice("note", "r is the controller's setpoint: no PFG from data (the BLA is P_h)"))
    bands = distortion_by_band(cut.r, cut.y, cut.period, fs, ratio=F) if bla.periods > 1 else []
    return PeriodicBLA(bla, cut, fs, F, tuple(bands), tuple(heard.notices))


def _setpoint(cut: Periods) -> bool:
    """Whether the periods' first realization shows r at the setpoint (u held, u - r not).

    The BLA ``Y/U`` is P_h wherever r enters; the PFG from data is the paper's lifted map
    from r at the plant input, not defined for a setpoint.
    """
    from ..numerics.structure import SETPOINT, read_structure

    first = (x[0][:, None] for x in (cut.r, cut.u, cut.y))
    return read_structure(*first).injection == SETPOINT


def _npz_slow(
    req: IdentifyRequest, data: Realizations, fs: float, F: int, heard: Heard
) -> SlowPlant:
    """P_h from an NPZ whose y holds the low-rate samples only.

    Through :func:`~mr_ident.numerics.lifted.slow_periodic.slow_output_plant` (a rotated lifted
    design: ``mr-ident excite --lifted --rotate``), as an identification result.
    """
    from ..numerics.lifted.slow_periodic import SLOW_PFG_SOURCE, slow_output_plant
    from ..numerics.results import FRF, PFG, Identification

    r, u, y, q = data.r, data.u, data.y, data.y_phase
    N, T = int(str(req.period)), int(req.transient_periods)
    if N % F or r.shape[1] % N or r.shape[1] // N <= T:
        raise DataFieldError(
            f"{req.reading.path}: {{period}} {N} must be a multiple of F = {F} and divide the "
            f"{r.shape[1]} samples per realization into more than the {T} transient period(s)",
            "period",
        )
    sp = slow_output_plant(r[:, T * N :], u[:, T * N :], y[:, T * N // F :], N, F, phase=q)
    lines, P, sd = sp.lines, sp.response, sp.std
    if lines.size == 0:
        raise DataError(
            f"{req.reading.path}: y holds the low-rate samples only, and no lifted bin has "
            f"all its F = {F} aliases excited over the {r.shape[0]} realization(s): P_h needs "
            "a rotated lifted design (mr-ident excite --lifted --rotate --kind full "
            f"--ratio {F} --realizations {F})"
        )
    f = lines * fs / N
    ident = Identification(
        FRF(f, P[:, None, None], sd[:, None, None], "periodic:slow y"),
        None,
        None,
        None,
        fs,
        F,
        pfg_data=PFG(f, sp.pfg, sp.pfg_std, SLOW_PFG_SOURCE),
    )
    return SlowPlant(ident, int(r.shape[0]), int(r.shape[1] // N - T), tuple(heard.notices))


def _read_npz(req: IdentifyRequest) -> tuple[Realizations, float, int]:
    """The NPZ of realizations, read once, with fs_high and F settled (the flags first)."""
    from ..io.periodicfile import read_realizations

    path = req.reading.path
    if req.period == "auto":
        raise FieldError(
            "{period} auto reads the period off the excitation's labels in a bag; "
            f"{path} is an NPZ: give {{period}} N",
            "period",
        )
    if req.excitation_index:
        raise FieldError(
            f"{{excitation_index}} names a topic of a bag; {path} is an NPZ", "excitation_index"
        )
    data = read_realizations(path, req.ratio)
    fs = req.fs_high or data.fs_high
    if fs is None:
        raise FieldError(f"{path} has no fs_high: give {{fs_high}}", "fs_high")
    return data, fs, req.ratio or data.ratio or 1


def _default_labels(specs: Specs | None) -> str:
    """The labels' topic beside r's: the first r source's topic, or the block topic."""
    from ..io.blocks import STREAMS
    from ..io.labels import index_topic
    from ..io.paths import parse_source

    return index_topic(parse_source(specs["r"][0]).topic if specs else STREAMS[0])


def _bag_periods(req: IdentifyRequest, heard: Heard) -> tuple[Periods, float, int]:
    from ..live.periodic import cut_by_labels, record_by_count
    from ..live.recordings import find_topic

    reading = req.reading
    specs = reading.specs()
    model = load(req.model)
    fs = req.fs_high or (model.fs_high if model else None)
    F = req.ratio or (model.ratio if model else None)
    want = req.excitation_index or _default_labels(specs)
    topic, names = find_topic(
        reading.path, want, exact=specs is not None, msg_path=reading.msg_path
    )
    period = None if req.period == "auto" else int(str(req.period))
    if topic is None:
        if period is None:
            raise DataFieldError(
                f"{reading.path}: no topic {want} with the excitation's labels (the bag holds "
                f"{', '.join(names) or 'none'}); {{period}} auto reads the period off them: "
                "give {excitation_index} TOPIC, or {period} N to count periods from the "
                "record's first sample",
                "period",
                "excitation_index",
            )
        data = read_loop(reading, specs, fs, F, heard)
        heard(
            Notice(
                "note",
                f"no topic {want} with the excitation's labels: whole periods of {period} "
                f"samples counted from the record's first sample (index {data.first})",
            )
        )
        cut = record_by_count(data, period, req.transient_periods)
    else:
        data = read_loop(reading, specs, fs, F, heard, labels=topic)
        cut = cut_by_labels(data, period, req.transient_periods)
    fs_got, F_got = data.rates()
    return cut, fs_got, F_got
