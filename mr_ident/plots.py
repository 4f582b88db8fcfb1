# SPDX-License-Identifier: Apache-2.0
"""Figures a person can read (matplotlib, Agg, no global pyplot state).

Compute and plot are separate: every function takes result objects and a path.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from .io.units import magnitude_label
from .numerics.results import FRF, PFG

if TYPE_CHECKING:
    from .numerics.excitation.bla import BLA, BandLevels


def _save(fig: Figure, path: str | Path) -> Path:
    FigureCanvasAgg(fig)
    p = Path(path)
    fig.savefig(p, dpi=110)
    return p


def _db(x: NDArray) -> NDArray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs(x))


#: Buckets of a log frequency axis a curve keeps its extremes in (a figure 8 inches wide has
#: about 900 pixels: more points than this only cost drawing time).
THIN_BUCKETS = 1500


def _thin(f: NDArray, values: Sequence[NDArray], buckets: int = THIN_BUCKETS) -> NDArray:
    """Indices of ``f`` to draw, ascending.

    Per bucket of log frequency the smallest and the largest of each of ``values`` (so the
    envelope and every peak and notch stay; a NaN bin stays too); every index where few.
    """
    K = f.size
    if K <= 4 * buckets:
        return np.arange(K)
    pos = np.flatnonzero(f > 0)
    edges = np.geomspace(f[pos[0]], f[-1], buckets + 1)
    b = np.full(K, -1)
    b[pos] = np.clip(np.searchsorted(edges, f[pos], side="right") - 1, 0, buckets - 1)
    keep = [np.flatnonzero(b < 0), pos[[0, -1]]]
    for v in values:
        w = np.where(np.isfinite(v), v, np.nan)
        order = np.lexsort((w, b))  # by bucket, then value (NaN last)
        _, first = np.unique(b[order], return_index=True)
        _, last = np.unique(b[order][::-1], return_index=True)
        keep += [order[first], order[::-1][last], np.flatnonzero(~np.isfinite(v))]
    return np.unique(np.concatenate(keep))


def _phase(x: NDArray) -> NDArray:
    """The phase in degrees, unwrapped along frequency; NaN bins stay NaN.

    The one convention of the plots, the live view and the Bode message; the first finite
    bin lies in (-180, 180].
    """
    deg = np.full(np.shape(x), np.nan)
    ok = np.isfinite(x)
    if ok.any():
        deg[ok] = np.degrees(np.unwrap(np.angle(x[ok])))
    return deg


def _phase_ticks(ax: Any) -> None:
    """Phase ticks on multiples of 15, 30, 45, 90, 180 ... degrees.

    The finest step with at most eight ticks across the axis (a phase that runs far gets
    180 or 360).
    """
    from matplotlib.ticker import MultipleLocator

    lo, hi = ax.get_ylim()
    step = next(
        (b for b in (15, 30, 45, 90, 180, 360, 720, 1440) if (hi - lo) / b <= 8),
        90 * 2 ** max(0, int(np.ceil(np.log2((hi - lo) / 720)))),
    )
    ax.yaxis.set_major_locator(MultipleLocator(step))


def _log_ticks(ax: Any) -> None:
    """Readable frequency ticks on a log axis.

    On an axis of less than 2.5 decades (where the default labels the decades only: one
    tick across 11-250 Hz), ticks on 1-2-5 or finer steps of each decade, as many as give
    at least four labels, in plain numbers.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    lo, hi = ax.get_xlim()
    if not (lo > 0 and np.log10(hi / lo) < 2.5):
        return
    for subs in ((1.0, 2.0, 5.0), (1.0, 2.0, 3.0, 5.0, 7.0), tuple(range(1, 10))):
        ticks = LogLocator(subs=subs).tick_values(lo, hi)
        if np.count_nonzero((ticks >= lo) & (ticks <= hi)) >= 4:
            break
    ax.xaxis.set_major_locator(LogLocator(subs=subs))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def _nyquist(ax: Any, f: float, *, label: bool) -> None:
    """The low-rate Nyquist frequency: a dotted line, named inside the frame (left of it)."""
    ax.axvline(f, color="0.5", ls=":", lw=1)
    if label:
        ax.text(
            f,
            0.97,
            "low-rate Nyquist ",
            transform=ax.get_xaxis_transform(),
            fontsize=7,
            ha="right",
            va="top",
            color="0.35",
            bbox={"facecolor": "white", "edgecolor": "none", "alpha": 0.7, "pad": 1},
        )


def _band(ax: Any, f: NDArray, g: NDArray, s: NDArray, color: str) -> None:
    """The ±2σ band of |g| in dB.

    Its legend says how wide it is where it hides behind the line (an estimate 80 dB above
    its σ has a band of 1e-3 dB).
    """
    a = np.abs(g)
    lo, hi = np.maximum(a - 2 * s, a * 1e-3), a + 2 * s
    with np.errstate(invalid="ignore", divide="ignore"):
        width = float(np.nanmax(_db(hi) - _db(lo))) if np.isfinite(s).any() else 0.0
    label = "±2σ" if width >= 1.0 else f"±2σ (at most {width:.2g} dB wide: within the line)"
    ax.fill_between(f, _db(lo), _db(hi), color=color, alpha=0.35, lw=0, label=label, zorder=1)


def pfg_label(source: str) -> str:
    """A PFG's name in the figures: from data (the lifted r→y map), or from P_h and K_l."""
    if source.startswith("data"):
        return "PFG from data (lifted r→y)"
    method = source.split(":", 1)[1] if ":" in source else ""
    return "PFG from P_h and K_l" + (f" ({method})" if method else "")


def bode_figure(
    frf: FRF,
    *,
    models: Sequence[tuple[str, FRF, Mapping[str, Any]]] = (),
    nyquist_low: float | None = None,
    title: str | None = None,
    undetermined: NDArray[np.bool_] | None = None,
    units: tuple[str, str] | None = None,
) -> Figure:
    """Bode magnitude and phase of an estimate with a +-2 sigma band, and reference curves.

    ``models`` holds ``(label, frf, line style)`` triples drawn over the estimate;
    ``undetermined`` (n_freq,) marks the bins the data do not determine (shaded);
    ``units``: (u's, y's) physical units, for the magnitude's axis. The phase is unwrapped.
    """
    ny, nu = frf.n_out, frf.n_in
    fig = Figure(figsize=(5.5 * nu + 1, 6.5 * ny))
    axes = fig.subplots(2 * ny, nu, sharex=True, squeeze=False)
    f = frf.frequency
    for o in range(ny):
        for i in range(nu):
            am, ap = axes[2 * o, i], axes[2 * o + 1, i]
            g, s = frf.response[:, o, i], frf.std[:, o, i]
            ph = _phase(g)  # unwrapped at full resolution, then thinned
            k = _thin(f, [_db(g), s, ph])
            label = f"estimate ({frf.method})"
            am.semilogx(f[k], _db(g[k]), lw=0.8, color="C0", label=label, zorder=3)
            if np.isfinite(s).any():
                _band(am, f[k], g[k], s[k], "C0")
                am.semilogx(f[k], _db(s[k]), lw=0.6, color="C2", label="σ")
            ap.semilogx(f[k], ph[k], lw=0.8, color="C0", zorder=3)
            for label, m, style in models:
                r = m.response[:, o, i]
                mph = _phase(r)
                j = _thin(m.frequency, [_db(r), mph])
                am.semilogx(m.frequency[j], _db(r[j]), lw=1, label=label, **style)
                ap.semilogx(m.frequency[j], mph[j], lw=1, **style)
            for ax in (am, ap):
                if nyquist_low:
                    _nyquist(ax, nyquist_low, label=ax is axes[0, 0])
                for n, (a, b) in enumerate(_runs(f, undetermined)):
                    zero = "not determined (hold zero)" if ax is am and n == 0 else None
                    ax.axvspan(a, b, color="C3", alpha=0.15, lw=0)
                    ax.axvline((a + b) / 2, color="C3", ls="--", lw=0.8, label=zero)
                ax.grid(True, which="both", alpha=0.3)
            am.set_ylabel(magnitude_label(units, o, i, ny, nu))
            ap.set_ylabel("phase [deg] (unwrapped)")
            _phase_ticks(ap)
    axes[0, 0].legend(loc="best", fontsize=8)
    axes[-1, -1].set_xlabel("frequency [Hz]")
    _log_ticks(axes[-1, -1])
    fig.suptitle(title or f"Plant estimate P_h ({frf.method})")
    fig.tight_layout()
    return fig


def _runs(f: NDArray, mask: NDArray[np.bool_] | None) -> list[tuple[float, float]]:
    """The frequency spans of the runs of True in ``mask`` (none when None)."""
    if mask is None or not mask.any():
        return []
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(f[a]), float(f[b])) for a, b in zip(starts, stops, strict=True)]


def plot_bode(
    frf: FRF,
    path: str | Path,
    *,
    model: FRF | None = None,
    nyquist_low: float | None = None,
    title: str | None = None,
    undetermined: NDArray[np.bool_] | None = None,
    units: tuple[str, str] | None = None,
) -> Path:
    """:func:`bode_figure` with the model (dashed black) when given, saved to ``path``."""
    models = [("model", model, {"color": "k", "ls": "--"})] if model is not None else []
    fig = bode_figure(
        frf,
        models=models,
        nyquist_low=nyquist_low,
        title=title,
        undetermined=undetermined,
        units=units,
    )
    return _save(fig, path)


def plot_pfg(
    pfg: PFG,
    path: str | Path,
    *,
    model: PFG | None = None,
    title: str | None = None,
    also: Sequence[PFG] = (),
    nyquist_low: float | None = None,
) -> Path:
    """PFG of the multirate loop with a +-2 sigma band, ``also`` the same, and the model's.

    In dB, as in the live view.
    """
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for j, p in enumerate((pfg, *also)):
        k = _thin(p.frequency, [_db(p.gain), p.std])
        f, g, s = p.frequency[k], p.gain[k], p.std[k]
        ax.semilogx(f, _db(g), lw=0.8, color=f"C{j}", label=pfg_label(p.source), zorder=3)
        if np.isfinite(s).any():
            _band(ax, f, g, s, f"C{j}")
    if model is not None:
        k = _thin(model.frequency, [_db(model.gain)])
        ax.semilogx(model.frequency[k], _db(model.gain[k]), "k--", lw=1, label="model")
    if nyquist_low:
        _nyquist(ax, nyquist_low, label=True)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("PFG r→y [dB]")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    _log_ticks(ax)
    ax.set_title(title or "Performance frequency gain")
    fig.tight_layout()
    return _save(fig, path)


def plot_errors(
    frequency: NDArray,
    errors: Mapping[str, NDArray],
    path: str | Path,
    *,
    ylabel: str,
    title: str,
    nyquist_low: float | None = None,
) -> Path:
    """One error curve per method (log-log), as in the paper's figures."""
    return _per_method(
        frequency,
        {name: np.maximum(e, 1e-300) for name, e in errors.items()},
        path,
        ylabel=ylabel,
        title=title,
        nyquist_low=nyquist_low,
        height=4.2,
        loglog=True,
    )


def plot_windows(
    frequency: NDArray,
    windows: Mapping[str, NDArray],
    path: str | Path,
    *,
    title: str,
    nyquist_low: float | None = None,
) -> Path:
    """The LPM window half-width n used per frequency, one step curve per method."""
    return _per_method(
        frequency,
        windows,
        path,
        ylabel="window half-width n",
        title=title,
        nyquist_low=nyquist_low,
        height=3.2,
        loglog=False,
    )


def _per_method(
    frequency: NDArray,
    curves: Mapping[str, NDArray],
    path: str | Path,
    *,
    ylabel: str,
    title: str,
    nyquist_low: float | None,
    height: float,
    loglog: bool,
) -> Path:
    """One curve per method against frequency (log-log, or steps on a log frequency axis)."""
    fig = Figure(figsize=(7.5, height))
    ax = fig.subplots()
    for j, (name, c) in enumerate(curves.items()):
        if loglog:
            k = _thin(frequency, [np.log(np.maximum(c, 1e-300))])
            ax.loglog(frequency[k], c[k], lw=0.7, color=f"C{j}", label=name)
        else:
            ax.semilogx(frequency, c, lw=0.8, color=f"C{j}", label=name, drawstyle="steps-mid")
    if nyquist_low:
        _nyquist(ax, nyquist_low, label=True)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    _log_ticks(ax)
    fig.tight_layout()
    return _save(fig, path)


def bla_figure(
    frequency: NDArray,
    bla: BLA,
    *,
    bands: Sequence[BandLevels] = (),
    model: FRF | None = None,
    title: str | None = None,
    units: tuple[str, str] | None = None,
) -> Figure:
    """The best linear approximation with its noise and nonlinear parts, per line.

    Magnitude (dB) of the BLA with its ±2σ band and, per excited line, the total std and
    its parts from the noise and from the stochastic nonlinear distortion (σ² = σ_n² +
    σ_NL²), as in Pintelon and Schoukens (2012, fig. 3-6); the phase; the odd and even
    distortion at the unexcited lines in dB above the noise (the BLA's overall levels over
    the magnitude, and per band when ``bands`` are given). ``model``: a reference drawn dashed.
    """
    f, g = np.asarray(frequency, float), bla.response
    rows = 3 if bands else 2
    fig = Figure(figsize=(7.5, 2.9 * rows + 0.6))
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    am, ap = axes[0], axes[1]
    am.semilogx(f, _db(g), lw=1.0, color="C0", label="BLA", zorder=3)
    if np.isfinite(bla.std).any():
        _band(am, f, g, bla.std, "C0")
    odd, even = float(bla.odd_db[0]), float(bla.even_db[0])
    parts = (
        (bla.std, "C7", "σ total"),
        (bla.noise_std, "C2", "σ noise"),
        (bla.nl_std, "C3", "σ nonlinear"),
    )
    for s, c, label in parts:
        if np.isfinite(s).any():
            am.semilogx(f, _db(s), ls="none", marker=".", ms=3, color=c, label=label)
    ap.semilogx(f, _phase(g), lw=1.0, color="C0")
    if model is not None:
        am.semilogx(model.frequency, _db(model.response[:, 0, 0]), "k--", lw=1, label="model")
        ap.semilogx(model.frequency, _phase(model.response[:, 0, 0]), "k--", lw=1)
    am.set_ylabel(magnitude_label(units, 0, 0, 1, 1).replace("P_h", "G"))
    am.set_title(
        f"distortion at the unexcited lines: odd {odd:.1f} dB, even {even:.1f} dB above the noise",
        fontsize=8,
    )
    ap.set_ylabel("phase [deg] (unwrapped)")
    _phase_ticks(ap)
    am.legend(fontsize=7, loc="best")
    if bands:
        ad = axes[2]
        edges = [b.band[0] for b in bands] + [bands[-1].band[1]]
        for key, c, label in (
            ("excited_db", "C0", "excited lines"),
            ("odd_db", "C3", "unexcited odd lines"),
            ("even_db", "C1", "unexcited even lines"),
        ):
            v = [getattr(b, key) for b in bands]
            ad.stairs(v, edges, color=c, lw=1.2, label=label, baseline=None)
        ad.axhline(0.0, color="0.5", lw=0.8, ls=":")
        ad.set_ylabel("dB above noise")
        ad.legend(fontsize=7, loc="best")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].set_xlabel("frequency [Hz]")
    _log_ticks(axes[-1])
    fig.suptitle(
        title
        or f"Best linear approximation ({bla.realizations} realization(s) x {bla.periods} periods)"
    )
    fig.tight_layout()
    return fig


def plot_bla(
    frequency: NDArray,
    bla: BLA,
    path: str | Path,
    *,
    bands: Sequence[BandLevels] = (),
    model: FRF | None = None,
    title: str | None = None,
) -> Path:
    """:func:`bla_figure` saved to ``path``."""
    return _save(bla_figure(frequency, bla, bands=bands, model=model, title=title), path)
