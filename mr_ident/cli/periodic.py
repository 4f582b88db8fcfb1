# SPDX-License-Identifier: Apache-2.0
"""``identify --period`` and ``replay`` of periodic data: the BLA's report, written and told.

The computing is the application's (:mod:`mr_ident.app.periodic`); here the result files
are written and what they hold is printed.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..app.periodic import PeriodicBLA, SlowPlant
    from ..numerics.excitation.bla import BLA


def report_periodic(out: Path, outcome: PeriodicBLA, plot: Path | None) -> None:
    """The BLA of ``identify --period``: the cut told, the result written, its report."""
    print(f"periods: {outcome.periods.describe()}")
    write_bla_report(
        out,
        outcome.bla,
        outcome.periods.period,
        outcome.fs_high,
        outcome.ratio,
        plot=plot,
        bands=list(outcome.bands),
    )


def report_slow(out: Path, outcome: SlowPlant, plot: Path | None) -> None:
    """P_h from an NPZ whose y holds the low-rate samples only: written, told, plotted."""
    import numpy as np

    from ..io.datafile import write_result

    ident = outcome.identification
    f, P, sd = ident.plant.frequency, ident.plant.response[:, 0, 0], ident.plant.std[:, 0, 0]
    write_result(out, ident)
    print(
        f"wrote {out} (P_h from y at the low rate on {f.size} lines, "
        f"{f.min():.4g}-{f.max():.4g} Hz; {outcome.realizations} realizations x "
        f"{outcome.periods} periods; median std {np.nanmedian(sd / np.abs(P)):.2g} of |P|; "
        "with the PFG from data, J = diag(P_h) S measured)"
    )
    if plot:
        from ..plots import plot_bode

        print(f"wrote {plot_bode(ident.plant, plot)}")


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
