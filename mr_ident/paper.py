# SPDX-License-Identifier: Apache-2.0
"""The paper's example end to end (van Haren, Blanken, Oomen, CDC 2022).

Simulate the multirate loop of ``config/paper_example.yaml``, identify P_h with
every method, each with the paper's fixed window (n = 8) and with the automatic one
(``n = "auto"``, the default), and compare with the exactly evaluated model:
``|P_h - P_hat|`` and the PFG error, one curve per method (automatic window), a table of
median errors per band (both windows) and the window chosen across the band.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .numerics.identify import METHODS, identify
from .numerics.lifted.pfg import pfg_of_model
from .numerics.results import FRF, PFG, Identification
from .numerics.signals import LoopData
from .numerics.systems.model import Model
from .numerics.systems.simulate import simulate
from .plots import plot_bode, plot_errors, plot_pfg, plot_windows


@dataclass(frozen=True)
class PaperRun:
    """What :func:`run_paper` produced."""

    files: dict[str, Path]
    table: str
    median_rel_error: dict[str, float]
    seconds: dict[str, float]
    windows: dict[str, np.ndarray]


def bands(fs_high: float, ratio: int) -> list[tuple[float, float]]:
    """The F low-rate Nyquist bands covering (0, fs_high/2]."""
    edges = np.linspace(0.0, fs_high / 2, ratio + 1) if ratio > 1 else np.array([0.0, fs_high / 2])
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def run_paper(
    model: Model,
    out_dir: str | Path,
    *,
    duration: float = 600.0,
    seed: int = 0,
    noise_std: float | None = None,
    n: int = 8,
    degree: int = 2,
    units: tuple[str, str] | None = None,
) -> PaperRun:
    """Run the example and write figures and a table into ``out_dir``.

    ``units``: the model file's (u's, y's), for the Bode plot's magnitude.

    Every method with the window ``n`` (rows ``method n=8``) and with ``n = "auto"``
    (rows ``method auto``; the ETFE has no window: one row); ``median_rel_error`` and
    ``seconds`` are keyed by those row names, ``windows`` (n per bin, automatic) by method.
    The steps: simulate, identify with every method and window, draw the figures, write
    the table.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if noise_std is not None:
        model = replace(model, noise_std=noise_std)
    sim = simulate(model, duration=duration, rng=np.random.default_rng(seed))
    truth = _Truth(model.plant_result(sim.n_samples), pfg_of_model(model, sim.n_samples))
    rows = _identify_rows(model, sim, truth, n, degree)
    files = _figures(model, truth, rows, out, duration, units)
    lines = [
        f"# Paper example: N = {sim.n_samples} samples ({duration:g} s at {model.fs_high:g} "
        f"Hz), F = {model.ratio}, noise std {model.noise_std:g}, n = {n} or auto, "
        f"R = {degree}, seed {seed}",
        "",
    ]
    table = "\n".join(lines + _table(model, truth, rows)) + "\n"
    tpath = out / "paper_errors.md"
    tpath.write_text(table)
    files["table"] = tpath
    return PaperRun(
        files=files,
        table=table,
        median_rel_error=rows.median_rel(truth),
        seconds=rows.seconds,
        windows=rows.windows,
    )


@dataclass(frozen=True)
class _Truth:
    """The exactly evaluated model: P_h and the PFG on the record's bins."""

    frf: FRF
    pfg: PFG


@dataclass(frozen=True)
class _Rows:
    """Every row of the comparison (a method with a window), in order, by row name."""

    results: dict[str, Identification] = field(default_factory=dict)
    err_P: dict[str, np.ndarray] = field(default_factory=dict)  # max |P_h - P̂_h| per bin
    err_pfg: dict[str, np.ndarray] = field(default_factory=dict)  # |PFG - PFĜ| per bin
    seconds: dict[str, float] = field(default_factory=dict)
    windows: dict[str, np.ndarray] = field(default_factory=dict)  # n per bin, by method

    def relative(self, row: str, truth: _Truth) -> np.ndarray:
        """The row's plant error per bin relative to the largest entry of P_h there."""
        rel: np.ndarray = self.err_P[row] / np.abs(truth.frf.response).max(axis=(1, 2))
        return rel

    def median_rel(self, truth: _Truth) -> dict[str, float]:
        """The median relative plant error of every row."""
        return {m: float(np.median(self.relative(m, truth))) for m in self.err_P}


def _identify_rows(model: Model, sim: LoopData, truth: _Truth, n: int, degree: int) -> _Rows:
    """Every method with the window ``n`` and with ``"auto"`` (the ETFE once), timed."""
    N, rows = sim.n_samples, _Rows()
    runs = [(m, w) for m in METHODS for w in ((n, "auto") if METHODS[m].uses_lpm else (n,))]
    for method, w in runs:
        row = f"{method} n={w}" if w != "auto" else f"{method} auto"
        if not METHODS[method].uses_lpm:
            row = method
        t0 = time.perf_counter()
        res = identify(
            sim.r,
            sim.u,
            sim.y,
            fs_high=model.fs_high,
            ratio=model.ratio,
            method=method,
            n=w,
            degree=degree,
            **model.identify_arguments(N),
        )
        rows.seconds[row] = time.perf_counter() - t0
        rows.results[row] = res
        rows.err_P[row] = np.abs(res.plant.response - truth.frf.response).max(axis=(1, 2))
        assert res.pfg is not None
        rows.err_pfg[row] = np.abs(res.pfg.gain - truth.pfg.gain)
        if w == "auto" and res.n_used is not None:
            rows.windows[method] = np.asarray(res.n_used)
    return rows


def _figures(
    model: Model,
    truth: _Truth,
    rows: _Rows,
    out: Path,
    duration: float,
    units: tuple[str, str] | None = None,
) -> dict[str, Path]:
    """The automatic window's errors, the windows chosen, freq-lifted's Bode and PFG."""
    freq, nyq = truth.frf.frequency, model.fs_low / 2
    default_rows = [r for r in rows.err_P if " n=" not in r]  # n auto (and the ETFE)
    files = {
        "plant_error": plot_errors(
            freq,
            {r: rows.err_P[r] for r in default_rows},
            out / "paper_plant_error.png",
            ylabel="|P_h - P̂_h|",
            title=f"Plant error, {duration:g} s, noise std {model.noise_std:g}, n auto",
            nyquist_low=nyq,
        ),
        "pfg_error": plot_errors(
            freq,
            {r: rows.err_pfg[r] for r in default_rows},
            out / "paper_pfg_error.png",
            ylabel="|PFG - PFĜ|",
            title="PFG error",
            nyquist_low=nyq,
        ),
    }
    files["windows"] = plot_windows(
        freq,
        rows.windows,
        out / "paper_window_n.png",
        title=f"Window chosen (n auto), noise std {model.noise_std:g}",
        nyquist_low=nyq,
    )
    best = rows.results["freq-lifted auto"]
    files["bode"] = plot_bode(
        best.plant,
        out / "paper_bode_freq_lifted.png",
        model=truth.frf,
        nyquist_low=nyq,
        units=units,
    )
    assert best.pfg is not None
    files["pfg"] = plot_pfg(
        best.pfg, out / "paper_pfg_freq_lifted.png", model=truth.pfg, nyquist_low=nyq
    )
    return files


def _table(model: Model, truth: _Truth, rows: _Rows) -> list[str]:
    """The table's lines: the median errors per band of every row, the windows chosen."""
    freq, bl = truth.frf.frequency, bands(model.fs_high, model.ratio)
    rel = rows.median_rel(truth)
    lines = ["Median relative plant error |P_h - P̂_h| / |P_h| per band:", ""]
    head = (
        "| method | "
        + " | ".join(f"({a:g}, {b:g}] Hz" for a, b in bl)
        + " | all | PFG rel. | time [s] |"
    )
    lines += [head, "|" + " --- |" * (len(bl) + 4)]
    for m in rows.err_P:
        r = rows.relative(m, truth)
        cells = [f"{np.median(r[(freq > a) & (freq <= b)]):.2e}" for a, b in bl]
        pr = np.median(rows.err_pfg[m] / truth.pfg.gain)
        lines.append(
            f"| {m} | "
            + " | ".join(cells)
            + f" | {rel[m]:.2e} | {pr:.2e} | {rows.seconds[m]:.2f} |"
        )
    lines += [
        "",
        "Window chosen with n auto: median n per band (share of bins at each candidate):",
        "",
        "| method | " + " | ".join(f"({a:g}, {b:g}] Hz" for a, b in bl) + " |",
        "|" + " --- |" * (len(bl) + 1),
    ]
    for m, nw in rows.windows.items():
        cells = []
        for a, b in bl:
            part = nw[(freq > a) & (freq <= b)]
            vals, counts = np.unique(part, return_counts=True)
            share = ", ".join(
                f"{v}: {c / part.size:.0%}" for v, c in zip(vals, counts, strict=True)
            )
            cells.append(f"{np.median(part):g} ({share})")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines
