# SPDX-License-Identifier: Apache-2.0
"""The diagnosis as a self-contained HTML page with embedded figures (an adapter).

Plotting only: the numbers come from :mod:`mr_ident.diagnosis`, the summary it shows
from :func:`mr_ident.diagnosis.report.report_dict`.
"""

from __future__ import annotations

import base64
import html
import io
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from .diagnosis.criterion.evidence import Evidence
from .diagnosis.diagnose import Diagnosis
from .numerics.results import FRF
from .plots import bode_figure


def _png(fig: Figure) -> str:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def fig_bode(
    ev: Evidence, extended: NDArray | None, units: tuple[str, str] | None = None
) -> Figure:
    """Nominal (and extended) model against P̂_h ± 2σ, every entry (``units``: u's, y's)."""
    zero = np.zeros(ev.P_std.shape)
    models = [
        ("nominal model", FRF(ev.frequency, ev.P_model, zero, "model"), {"color": "k", "ls": "--"})
    ]
    if extended is not None:
        models.append(
            ("extended model", FRF(ev.frequency, extended, zero, "model"), {"color": "C3"})
        )
    return bode_figure(
        FRF(ev.frequency, ev.P_hat, ev.P_std, "identified"),
        models=models,
        title="Plant: identified against the model",
        units=units,
    )


def fig_controller(d: Diagnosis) -> Figure:
    """The controller identified from the data ± 2σ against the model's and the fitted one."""
    c = d.controller_frf
    assert c is not None
    models = [("model's controller", c.model, {"color": "k", "ls": "--"})]
    if c.fit is not None:
        models.append(("fitted controller", c.fit, {"color": "C3"}))
    return bode_figure(c.identified, models=models, title="Controller at its rate")


def fig_sigma(before: Evidence, after: Evidence) -> Figure:
    """σ-error per bin: nominal (estimation data), extended (validation data), thresholds."""
    rows = 2 if before.loop_frequency.size else 1
    fig = Figure(figsize=(9, 3.2 * rows))
    axes = fig.subplots(rows, 1, squeeze=False)[:, 0]
    ax = axes[0]
    for ev, color, label in (
        (before, "C3", "nominal model"),
        (after, "C0", "extended model (validation)"),
    ):
        t = ev.tested
        ax.loglog(ev.frequency[t], ev.sigma_error[t], ".", ms=2, color=color, label=label)
    untested = [(e.frequency[~e.tested], e.sigma_error[~e.tested]) for e in (before, after)]
    if any(f.size for f, _ in untested):  # biased where the window reaches DC: not tested
        for i, (f, z) in enumerate(untested):
            grey = "not tested (the fit's window reaches DC)" if i == 0 else None
            ax.loglog(f, z, ".", ms=3, color="0.6", label=grey)
    ax.axhline(
        before.threshold,
        color="k",
        ls="--",
        lw=1,
        label=f"significance threshold ({before.threshold:.1f}σ)",
    )
    ax.set_ylabel("|P̂ − P| / σ̂")
    ax.set_title("plant P_h: error in σ units per bin")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    if rows == 2:
        ax = axes[1]
        ax.loglog(
            before.loop_frequency,
            before.loop_sigma_error,
            ".",
            ms=2,
            color="C3",
            label="nominal model",
        )
        ax.loglog(
            after.loop_frequency,
            after.loop_sigma_error,
            ".",
            ms=2,
            color="C0",
            label="extended model",
        )
        ax.axhline(before.loop_threshold, color="k", ls="--", lw=1, label="threshold")
        ax.set_ylabel("max |J̃,S̃ error| / σ̂")
        ax.set_title("lifted closed-loop maps J̃ (r→y), S̃ (r→u): error in σ units per low-rate bin")
        ax.legend(fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].set_xlabel("frequency [Hz]")
    fig.tight_layout()
    return fig


def fig_time(d: Diagnosis, seconds: float = 0.5) -> Figure:
    """Measured y against the nominal and the extended simulation on the validation data."""
    t0 = int(d.traces["start"])
    fs = float(d.traces["fs_high"])
    n = max(16, min(int(seconds * fs), d.traces["y"].shape[0] - t0))
    sl = slice(t0, t0 + n)
    t = np.arange(t0, t0 + n) / fs
    fig = Figure(figsize=(9, 4.5))
    axes = fig.subplots(2, 1, sharex=True)
    for ax, key, label, color in (
        (axes[0], "y_before", f"nominal (fit {d.fit_before.y:.1f} %)", "C3"),
        (axes[1], "y_after", f"extended (fit {d.fit_after.y:.1f} %)", "C0"),
    ):
        ax.plot(t, d.traces["y"][sl, 0], color="k", lw=0.8, label="measured y")
        ax.plot(t, d.traces[key][sl, 0], color=color, lw=0.8, ls="--", label=label)
        ax.legend(fontsize=8, loc="upper right")
        ax.grid(True, alpha=0.3)
        ax.set_ylabel("y[0]")
    axes[1].set_xlabel("time [s] (validation data)")
    fig.tight_layout()
    return fig


def fig_ranking(d: Diagnosis) -> Figure:
    """ΔBIC of every cause against the nominal model (negative: the cause explains more)."""
    none = next(c.score for c in d.ranking if c.cause == "none")
    items = [(c.cause, c.score - none) for c in d.ranking if c.applicable]
    fig = Figure(figsize=(8, 0.45 * len(items) + 1.2))
    ax = fig.subplots()
    names = [c for c, _ in items][::-1]
    vals = np.array([v for _, v in items][::-1])
    shown = -np.sign(vals) * np.log10(1 + np.abs(vals))
    ax.barh(names, shown, color=["C0" if v < 0 else "0.6" for v in vals])
    ax.axvline(0, color="k", lw=0.8)
    ax.set_xlabel("−sign(ΔBIC)·log10(1 + |ΔBIC|)   (right of 0: better than the nominal model)")
    fig.tight_layout()
    return fig


def _decision_html(decision: dict[str, Any] | None) -> str:
    """The validation's decision: each candidate, its status, its test and its fits."""
    if decision is None or not decision["candidates"]:
        return ""
    e = html.escape

    def num(x: float | None, fmt: str = ".2f") -> str:
        return "–" if x is None else format(x, fmt)

    rows = "".join(
        f"<tr><td>{e(k['cause'])}</td><td>{e(k['status'])}</td><td>{num(k['z'])}</td>"
        f"<td>{num(k['fit_without'], '.1f')} % → {num(k['fit_with'], '.1f')} %</td>"
        f"<td>{e(k['description'])}</td></tr>"
        for k in decision["candidates"]
    )
    return (
        f"<h2>Validation decides</h2><p><b>{e(decision['text'])}</b><br>"
        f"Test: {e(decision['statistic'])}; α = {decision['alpha']:g}. Every candidate "
        f"together: fit of y {num(decision['fit_candidates'], '.1f')} % on the validation "
        "data.</p><table border=1 cellpadding=4 style='border-collapse:collapse'><tr>"
        "<th>candidate (estimation data)</th><th>validation</th><th>z</th>"
        "<th>fit of y without → with it</th><th>description</th></tr>"
        f"{rows}</table>"
    )


def report_html(
    d: Diagnosis,
    summary: dict[str, Any],
    extended_frf: NDArray | None,
    title: str,
    units: tuple[str, str] | None = None,
) -> str:
    """A self-contained HTML page (PNG figures embedded as data URIs).

    ``units``: the model file's (u's, y's), for the Bode plot's magnitude.
    """
    figs = [
        (
            "Bode: nominal and extended model against P̂_h ± 2σ (estimation data)",
            fig_bode(d.evidence_before, extended_frf, units),
        ),
        ("Error in σ units per bin", fig_sigma(d.evidence_before, d.evidence_after)),
        ("Measured against simulated output, validation data", fig_time(d)),
        ("Ranking of the causes", fig_ranking(d)),
    ]
    if d.controller_frf is not None and d.controller_frf.available:
        figs.append(
            ("Controller: identified from the data ± 2σ, model and fit", fig_controller(d))
        )
    e = html.escape

    def params(p: dict[str, float]) -> str:
        return ", ".join(f"{k} = {v:.6g}" for k, v in p.items())

    def delta(c: dict[str, Any]) -> str:
        return "" if c["delta_bic"] is None else f"{c['delta_bic']:.1f}"

    rows = "".join(
        f"<tr><td>{e(c['cause'])}</td><td>{e(params(c['parameters']))}</td><td>{delta(c)}</td>"
        f"<td>{'' if c['applicable'] else 'not applicable'}</td></tr>"
        for c in summary["causes"]
    )

    def with_std(a: dict[str, Any]) -> str:
        std = a.get("std", {})
        return ", ".join(
            f"{k} = {v:.6g}" + (f" ± {std[k]:.2g}" if std.get(k) else "")
            for k, v in a["parameters"].items()
        )

    def with_equivalents(a: dict[str, Any]) -> str:
        alts = "; ".join(
            f"{q['cause']} ({with_std(q)}, BIC {q['delta_bic']:+.1f})"
            for q in a.get("equivalents", [])
        )
        return f"{a['cause']} ({with_std(a)})" + (f" — or, as well: {alts}" if alts else "")

    applied = ", ".join(with_equivalents(a) for a in summary["applied"]) or "none"
    decision = summary.get("validation_decision")
    if decision is not None and decision["candidates"] and not decision["extension_validated"]:
        applied = "none: no extension validated"
    bands = ", ".join(f"{lo:.3g}–{hi:.3g} Hz" for lo, hi in summary["significant_bands"]) or "none"
    bands_after = (
        ", ".join(f"{lo:.3g}–{hi:.3g} Hz" for lo, hi in summary["significant_bands_after"])
        or "none"
    )

    def pct(x: float | None) -> str:
        return "–" if x is None else f"{x:.1f} %"

    def num(x: float | None) -> str:
        return "–" if x is None else f"{x:.2f}"

    body = [
        f"<h1>{e(title)}</h1>",
        f"<p><b>Cause:</b> {e(summary['cause'])} {e(params(summary['parameters']))}<br>",
        f"<b>Applied to the extended model:</b> {e(applied)}<br>",
        "".join(f"<b>Found:</b> {e(x)}<br>" for x in summary.get("findings", [])),
        f"<b>Fit of y</b> (validation): {pct(summary['fit_before'])} → "
        f"{pct(summary['fit_after'])}; ",
        f"<b>fit of u</b>: {pct(summary['fit_u_before'])} → {pct(summary['fit_u_after'])}<br>",
        "<b>FRF error</b> (median |P̂−P|/σ̂, validation): "
        f"{num(summary['frf_sigma_error_before'])} → "
        f"{num(summary['frf_sigma_error_after'])}<br>",
        f"<b>Significant bands</b> (nominal, estimation data): {e(bands)}<br>",
        f"<b>Still significant</b> (extended, validation data): {e(bands_after)}</p>",
        f"<p>Estimation: {e(summary['estimation'])}.<br>Validation: "
        f"{e(summary['validation'])}.<br>",
        f"Test per bin: {e(summary['test']['statistic'])}, null {e(summary['test']['null'])}, "
        f"α = {summary['test']['alpha']}, q = {summary['test']['q']}.<br>",
        f"Ranking: {e(summary['criterion'])}.</p>",
        "<table border=1 cellpadding=4 style='border-collapse:collapse'>"
        "<tr><th>cause</th><th>fitted parameters</th><th>ΔBIC vs nominal</th><th></th></tr>"
        f"{rows}</table>",
        _decision_html(decision),
    ]
    for caption, fig in figs:
        body.append(
            f"<h2>{e(caption)}</h2><img alt='{e(caption)}' "
            f"src='data:image/png;base64,{_png(fig)}'>"
        )
    return (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>{e(title)}</title><style>body{{font-family:sans-serif;max-width:1000px;margin:auto}}"
        "img{max-width:100%}</style></head><body>" + "".join(body) + "</body></html>"
    )
