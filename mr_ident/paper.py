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
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .numerics.identify import METHODS, identify
from .numerics.lifted.pfg import pfg_of_model
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
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if noise_std is not None:
        model = replace(model, noise_std=noise_std)
    sim = simulate(model, duration=duration, rng=np.random.default_rng(seed))
    N = sim.n_samples
    F = model.ratio
    model_frf = model.plant_result(N)
    model_pfg = pfg_of_model(model, N)
    freq, P_true, g_true = model_frf.frequency, model_frf.response, model_pfg.gain
    err_P: dict[str, np.ndarray] = {}
    err_pfg: dict[str, np.ndarray] = {}
    seconds: dict[str, float] = {}
    results = {}
    windows: dict[str, np.ndarray] = {}
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
            ratio=F,
            method=method,
            n=w,
            degree=degree,
            **model.identify_arguments(N),
        )
        seconds[row] = time.perf_counter() - t0
        results[row] = res
        err_P[row] = np.abs(res.plant.response - P_true).max(axis=(1, 2))
        assert res.pfg is not None
        err_pfg[row] = np.abs(res.pfg.gain - g_true)
        if w == "auto" and res.n_used is not None:
            windows[method] = np.asarray(res.n_used)
    nyq = model.fs_low / 2
    default_rows = [r for r in err_P if not r.endswith(f" n={n}")]
    files = {
        "plant_error": plot_errors(
            freq,
            {r: err_P[r] for r in default_rows},
            out / "paper_plant_error.png",
            ylabel="|P_h - P̂_h|",
            title=f"Plant error, {duration:g} s, noise std {model.noise_std:g}, n auto",
            nyquist_low=nyq,
        ),
        "pfg_error": plot_errors(
            freq,
            {r: err_pfg[r] for r in default_rows},
            out / "paper_pfg_error.png",
            ylabel="|PFG - PFĜ|",
            title="PFG error",
            nyquist_low=nyq,
        ),
    }
    files["windows"] = plot_windows(
        freq,
        windows,
        out / "paper_window_n.png",
        title=f"Window chosen (n auto), noise std {model.noise_std:g}",
        nyquist_low=nyq,
    )
    best = results["freq-lifted auto"]
    files["bode"] = plot_bode(
        best.plant,
        out / "paper_bode_freq_lifted.png",
        model=model_frf,
        nyquist_low=nyq,
        units=units,
    )
    assert best.pfg is not None
    files["pfg"] = plot_pfg(
        best.pfg, out / "paper_pfg_freq_lifted.png", model=model_pfg, nyquist_low=nyq
    )
    rel = {m: float(np.median(err_P[m] / np.abs(P_true).max(axis=(1, 2)))) for m in err_P}
    lines = [
        f"# Paper example: N = {N} samples ({duration:g} s at {model.fs_high:g} Hz), F = {F}, "
        f"noise std {model.noise_std:g}, n = {n} or auto, R = {degree}, seed {seed}",
        "",
        "Median relative plant error |P_h - P̂_h| / |P_h| per band:",
        "",
    ]
    bl = bands(model.fs_high, F)
    head = (
        "| method | "
        + " | ".join(f"({a:g}, {b:g}] Hz" for a, b in bl)
        + " | all | PFG rel. | time [s] |"
    )
    lines += [head, "|" + " --- |" * (len(bl) + 4)]
    for m in err_P:
        r = err_P[m] / np.abs(P_true).max(axis=(1, 2))
        cells = [f"{np.median(r[(freq > a) & (freq <= b)]):.2e}" for a, b in bl]
        pr = np.median(err_pfg[m] / g_true)
        lines.append(
            f"| {m} | " + " | ".join(cells) + f" | {rel[m]:.2e} | {pr:.2e} | {seconds[m]:.2f} |"
        )
    lines += [
        "",
        "Window chosen with n auto: median n per band (share of bins at each candidate):",
        "",
        "| method | " + " | ".join(f"({a:g}, {b:g}] Hz" for a, b in bl) + " |",
        "|" + " --- |" * (len(bl) + 1),
    ]
    for m, nw in windows.items():
        cells = []
        for a, b in bl:
            part = nw[(freq > a) & (freq <= b)]
            vals, counts = np.unique(part, return_counts=True)
            share = ", ".join(
                f"{v}: {c / part.size:.0%}" for v, c in zip(vals, counts, strict=True)
            )
            cells.append(f"{np.median(part):g} ({share})")
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    table = "\n".join(lines) + "\n"
    tpath = out / "paper_errors.md"
    tpath.write_text(table)
    files["table"] = tpath
    return PaperRun(
        files=files, table=table, median_rel_error=rel, seconds=seconds, windows=windows
    )
