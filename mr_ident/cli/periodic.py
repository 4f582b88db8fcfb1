"""``identify --period``: the best linear approximation of periodic data; its report.

An NPZ holds r, u, y of shape (M realizations, n), periods counted from each row's start.
A bag is cut by the excitation's labels recorded beside r (``TOPIC/excitation_index`` of
``mr-ident excite --publish TOPIC``, read in the signals' form and aligned with them;
``--period auto`` reads the period off them); without them, with ``--period N``, its record
is one realization counted from its first sample. Both go through
:mod:`mr_ident.live.periodic`, as ``replay`` and the node do.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigError, DataError
from .common import read_loop, reading, source_specs

if TYPE_CHECKING:
    from ..io.periodicfile import Realizations
    from ..live.periodic import Periods
    from ..numerics.excitation.bla import BLA


def identify_periodic(args: argparse.Namespace) -> int:
    """``identify --period``: the BLA of an NPZ of realizations or of a bag."""
    from ..live.periodic import cut_by_count, periodic_bla
    from ..live.recordings import is_bag
    from ..numerics.excitation.bla import distortion_by_band

    if is_bag(args.data):
        cut, fs, F = _bag_periods(args)
    else:
        data, fs, F = _read_npz(args)
        if data.low_rate_y:
            return _npz_slow(args, data, fs, F)
        cut = cut_by_count(data.r, data.u, data.y, args.period, args.transient_periods)
    bla = periodic_bla(cut, F)
    print(f"periods: {cut.describe()}")
    bands = distortion_by_band(cut.r, cut.y, cut.period, fs, ratio=F) if bla.periods > 1 else []
    write_bla_report(args.out, bla, cut.period, fs, F, plot=args.plot, bands=bands)
    return 0


def _npz_slow(args: argparse.Namespace, data: Realizations, fs: float, F: int) -> int:
    """P_h from an NPZ whose y holds the low-rate samples only.

    Through :func:`~mr_ident.numerics.lifted.slow_periodic.slow_output_plant` (a rotated lifted
    design: ``mr-ident excite --lifted --rotate``), written as an identification result.
    """
    import numpy as np

    from ..io.datafile import write_result
    from ..numerics.lifted.slow_periodic import SLOW_PFG_SOURCE, slow_output_plant
    from ..numerics.results import FRF, PFG, Identification

    r, u, y, q = data.r, data.u, data.y, data.y_phase
    N, T = int(args.period), int(args.transient_periods)
    if N % F or r.shape[1] % N or r.shape[1] // N <= T:
        raise DataError(
            f"{args.data}: --period {N} must be a multiple of F = {F} and divide the "
            f"{r.shape[1]} samples per realization into more than the {T} transient period(s)"
        )
    sp = slow_output_plant(r[:, T * N :], u[:, T * N :], y[:, T * N // F :], N, F, phase=q)
    lines, P, sd = sp.lines, sp.response, sp.std
    if lines.size == 0:
        raise DataError(
            f"{args.data}: y holds the low-rate samples only, and no lifted bin has all its "
            f"F = {F} aliases excited over the {r.shape[0]} realization(s): P_h needs a "
            "rotated lifted design (mr-ident excite --lifted --rotate --kind full "
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
    write_result(args.out, ident)
    print(
        f"wrote {args.out} (P_h from y at the low rate on {lines.size} lines, "
        f"{f.min():.4g}-{f.max():.4g} Hz; {r.shape[0]} realizations x "
        f"{r.shape[1] // N - T} periods; median std {np.nanmedian(sd / np.abs(P)):.2g} of |P|; "
        "with the PFG from data, J = diag(P_h) S measured)"
    )
    if args.plot:
        from ..plots import plot_bode

        print(f"wrote {plot_bode(ident.plant, args.plot)}")
    return 0


def _read_npz(args: argparse.Namespace) -> tuple[Realizations, float, int]:
    """The NPZ of realizations, read once, with fs_high and F settled (the flags first)."""
    from ..io.periodicfile import read_realizations

    if args.period == "auto":
        raise ConfigError(
            "--period auto reads the period off the excitation's labels in a bag; "
            f"{args.data} is an NPZ: give --period N"
        )
    if args.excitation_index:
        raise ConfigError(f"--excitation-index names a topic of a bag; {args.data} is an NPZ")
    data = read_realizations(args.data, args.ratio)
    fs = args.fs_high or data.fs_high
    if fs is None:
        raise ConfigError(f"{args.data} has no fs_high: pass --fs-high")
    return data, fs, args.ratio or data.ratio or 1


def _default_labels(specs: dict[str, list[str]] | None) -> str:
    """The labels' topic beside r's: the first r source's topic, or the block topic."""
    from ..io.blocks import STREAMS
    from ..io.labels import index_topic
    from ..io.paths import parse_source

    return index_topic(parse_source(specs["r"][0]).topic if specs else STREAMS[0])


def _bag_periods(args: argparse.Namespace) -> tuple[Periods, float, int]:
    from ..io.modelfile import load_model
    from ..live.periodic import cut_by_labels, record_by_count
    from ..live.recordings import find_topic

    specs = source_specs(args)
    model = load_model(args.model) if args.model else None
    fs = args.fs_high or (model.fs_high if model else None)
    F = args.ratio or (model.ratio if model else None)
    want = args.excitation_index or _default_labels(specs)
    opts = reading(args)
    topic, names = find_topic(args.data, want, exact=specs is not None, msg_path=opts["msg_path"])
    period = None if args.period == "auto" else int(args.period)
    if topic is None:
        if period is None:
            raise DataError(
                f"{args.data}: no topic {want} with the excitation's labels (the bag holds "
                f"{', '.join(names) or 'none'}); --period auto reads the period off them: "
                "give --excitation-index TOPIC, or --period N to count periods from the "
                "record's first sample"
            )
        data = read_loop(args.data, specs, fs, F, **opts)
        print(
            f"note: no topic {want} with the excitation's labels: whole periods of {period} "
            f"samples counted from the record's first sample (index {data.first})",
            file=sys.stderr,
        )
        cut = record_by_count(data, period, args.transient_periods)
    else:
        data = read_loop(args.data, specs, fs, F, labels=topic, **opts)
        cut = cut_by_labels(data, period, args.transient_periods)
    fs_got, F_got = data.rates()
    return cut, fs_got, F_got


def write_bla_report(
    out: Path,
    bla: BLA,
    period: int,
    fs: float,
    ratio: int,
    *,
    plot: Path | None = None,
    bands: list | None = None,
) -> None:
    """Write the BLA result ``out``; say what it holds; the band table and the plot."""
    import numpy as np

    from ..io.periodicfile import write_bla
    from ..live.periodic import nl_to_noise

    write_bla(out, bla, fs_high=fs, ratio=ratio, period=period)
    if bla.realizations > 1 and bla.periods > 1:
        parts = f"nonlinear/noise std {nl_to_noise(bla):.2g} (median over the lines)"
    else:
        parts = "one realization or period: no nonlinear/noise split (the lines still tell)"
    print(
        f"wrote {out} (BLA on {bla.lines.size} lines, {bla.realizations} realization(s) "
        f"x {bla.periods} period(s); {parts}; odd {bla.odd_db[0]:.1f} dB, even "
        f"{bla.even_db[0]:.1f} dB above the noise)"
    )
    if bla.pfg is not None and np.isfinite(bla.pfg).any():
        ok = np.isfinite(bla.pfg)
        k = int(np.nanargmax(bla.pfg))
        print(
            f"PFG from data at {int(ok.sum())} of {ok.size} lines (each alone in its lifted "
            f"bin): peak {20 * np.log10(bla.pfg[k]):.1f} dB at {bla.lines[k] * fs / period:.4g} Hz"
        )
    if bands:  # the distortion at the unexcited lines, per band
        print("band (Hz)        excited  odd lines  even lines   (dB above the noise)")
        for b in bands:
            print(
                f"{b.band[0]:7.3g}-{b.band[1]:<7.3g}  {b.excited_db:7.1f}  {b.odd_db:9.1f}  "
                f"{b.even_db:10.1f}"
            )
    if plot:
        from ..plots import plot_bla

        print(f"wrote {plot_bla(bla.lines * fs / period, bla, plot, bands=bands or ())}")
