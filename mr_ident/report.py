"""Diagnosis report: a JSON summary and a self-contained HTML page with embedded figures.

Plotting and serialisation only; the numbers come from :mod:`mr_ident.validate`.
"""

from __future__ import annotations

import base64
import html
import io
import math
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from .plots import bode_figure
from .results import FRF
from .validate import Diagnosis, Evidence


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def report_dict(d: Diagnosis, *, extended_model: str | None, alpha: float) -> dict[str, Any]:
    """The JSON report (see the README's "Model validation" section for every field)."""
    none = next(c.score for c in d.ranking if c.cause == "none")
    causes = [{"cause": c.cause, "parameters": c.parameters,
               "score": _finite(c.score), "delta_bic": _finite(c.score - none),
               "applicable": c.applicable} for c in d.ranking]
    return {
        "cause": d.cause,
        "parameters": d.parameters,
        "causes": causes,
        "applied": [{"cause": c.cause, "parameters": c.parameters} for c in d.applied],
        "criterion": "BIC = 2 sum_k |E(k)|^2/S_noise(k) + p ln(n_bins) of the residual y - y_sim; "
                     "lower is better; a cause is accepted when it lowers the BIC of the model it extends",
        "fit_before": _finite(d.fit_before.y),
        "fit_after": _finite(d.fit_after.y),
        "fit_u_before": _finite(d.fit_before.u),
        "fit_u_after": _finite(d.fit_after.u),
        "frf_sigma_error_before": _finite(d.evidence_validation_before.median_sigma_error),
        "frf_sigma_error_after": _finite(d.evidence_after.median_sigma_error),
        "significant_bands": [list(b) for b in d.evidence_before.bands()],
        "significant_bands_after": [list(b) for b in d.evidence_after.bands()],
        "significant_bins": {"before": int(d.evidence_before.significant.sum()
                                           + d.evidence_before.loop_significant.sum()),
                             "after": int(d.evidence_after.significant.sum()
                                          + d.evidence_after.loop_significant.sum())},
        "test": {"statistic": "|P_hat - P_model| / sigma_hat per bin (max over entries)",
                 "null": "F(2, 2q) for the squared statistic, Bonferroni over bins and entries",
                 "alpha": alpha, "q": d.evidence_before.dof,
                 "threshold_sigma": _finite(d.evidence_before.threshold),
                 "loop_threshold_sigma": _finite(d.evidence_before.loop_threshold)},
        "extended_model": extended_model,
        "estimation": d.estimation,
        "validation": d.validation,
        "unexplained": {
            "significant_bands": [list(b) for b in d.evidence_after.bands()],
            "fit_gap_percent": _finite(100.0 - d.fit_after.y),
        },
    }


def _png(fig: Figure) -> str:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def fig_bode(ev: Evidence, extended: NDArray | None) -> Figure:
    """Nominal (and extended) model against P̂_h ± 2σ, every entry."""
    zero = np.zeros(ev.P_std.shape)
    models = [("nominal model", FRF(ev.frequency, ev.P_model, zero, "model"), {"color": "k", "ls": "--"})]
    if extended is not None:
        models.append(("extended model", FRF(ev.frequency, extended, zero, "model"), {"color": "C3"}))
    return bode_figure(FRF(ev.frequency, ev.P_hat, ev.P_std, "identified"), models=models,
                       title="Plant: identified against the model")


def fig_sigma(before: Evidence, after: Evidence) -> Figure:
    """σ-error per bin: nominal (estimation data) and extended (validation data), with thresholds."""
    rows = 2 if before.loop_frequency.size else 1
    fig = Figure(figsize=(9, 3.2 * rows))
    axes = fig.subplots(rows, 1, squeeze=False)[:, 0]
    ax = axes[0]
    ax.loglog(before.frequency, before.sigma_error, ".", ms=2, color="C3", label="nominal model")
    ax.loglog(after.frequency, after.sigma_error, ".", ms=2, color="C0", label="extended model (validation)")
    ax.axhline(before.threshold, color="k", ls="--", lw=1, label=f"significance threshold ({before.threshold:.1f}σ)")
    ax.set_ylabel("|P̂ − P| / σ̂")
    ax.set_title("plant P_h: error in σ units per bin")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    if rows == 2:
        ax = axes[1]
        ax.loglog(before.loop_frequency, before.loop_sigma_error, ".", ms=2, color="C3", label="nominal model")
        ax.loglog(after.loop_frequency, after.loop_sigma_error, ".", ms=2, color="C0", label="extended model")
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
    for ax, key, label, color in ((axes[0], "y_before", f"nominal (fit {d.fit_before.y:.1f} %)", "C3"),
                                  (axes[1], "y_after", f"extended (fit {d.fit_after.y:.1f} %)", "C0")):
        ax.plot(t, d.traces["y"][sl, 0], color="k", lw=0.8, label="measured y")
        ax.plot(t, d.traces[key][sl, 0], color=color, lw=0.8, ls="--", label=label)
        ax.legend(fontsize=8, loc="upper right")
        ax.grid(True, alpha=0.3)
        ax.set_ylabel("y[0]")
    axes[1].set_xlabel("time [s] (validation data)")
    fig.tight_layout()
    return fig


def fig_ranking(d: Diagnosis) -> Figure:
    """ΔBIC of every cause against the nominal model (negative: the cause explains the data better)."""
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


def report_html(d: Diagnosis, summary: dict[str, Any], extended_frf: NDArray | None, title: str) -> str:
    """A self-contained HTML page (PNG figures embedded as data URIs)."""
    figs = [("Bode: nominal and extended model against P̂_h ± 2σ (estimation data)",
             fig_bode(d.evidence_before, extended_frf)),
            ("Error in σ units per bin", fig_sigma(d.evidence_before, d.evidence_after)),
            ("Measured against simulated output, validation data", fig_time(d)),
            ("Ranking of the causes", fig_ranking(d))]
    e = html.escape
    def params(p: dict[str, float]) -> str:
        return ", ".join(f"{k} = {v:.6g}" for k, v in p.items())

    def delta(c: dict[str, Any]) -> str:
        return "" if c["delta_bic"] is None else f"{c['delta_bic']:.1f}"

    rows = "".join(
        f"<tr><td>{e(c['cause'])}</td><td>{e(params(c['parameters']))}</td><td>{delta(c)}</td>"
        f"<td>{'' if c['applicable'] else 'not applicable'}</td></tr>"
        for c in summary["causes"])
    applied = ", ".join(f"{a['cause']} ({params(a['parameters'])})" for a in summary["applied"]) or "none"
    bands = ", ".join(f"{lo:.3g}–{hi:.3g} Hz" for lo, hi in summary["significant_bands"]) or "none"
    bands_after = ", ".join(f"{lo:.3g}–{hi:.3g} Hz" for lo, hi in summary["significant_bands_after"]) or "none"

    def pct(x: float | None) -> str:
        return "–" if x is None else f"{x:.1f} %"

    def num(x: float | None) -> str:
        return "–" if x is None else f"{x:.2f}"

    body = [f"<h1>{e(title)}</h1>",
            f"<p><b>Cause:</b> {e(summary['cause'])} {e(params(summary['parameters']))}<br>",
            f"<b>Applied to the extended model:</b> {e(applied)}<br>",
            f"<b>Fit of y</b> (validation): {pct(summary['fit_before'])} → {pct(summary['fit_after'])}; ",
            f"<b>fit of u</b>: {pct(summary['fit_u_before'])} → {pct(summary['fit_u_after'])}<br>",
            f"<b>FRF error</b> (median |P̂−P|/σ̂, validation): {num(summary['frf_sigma_error_before'])} → "
            f"{num(summary['frf_sigma_error_after'])}<br>",
            f"<b>Significant bands</b> (nominal, estimation data): {e(bands)}<br>",
            f"<b>Still significant</b> (extended, validation data): {e(bands_after)}</p>",
            f"<p>Estimation: {e(summary['estimation'])}.<br>Validation: {e(summary['validation'])}.<br>",
            f"Test per bin: {e(summary['test']['statistic'])}, null {e(summary['test']['null'])}, "
            f"α = {summary['test']['alpha']}, q = {summary['test']['q']}.<br>",
            f"Ranking: {e(summary['criterion'])}.</p>",
            "<table border=1 cellpadding=4 style='border-collapse:collapse'>"
            "<tr><th>cause</th><th>fitted parameters</th><th>ΔBIC vs nominal</th><th></th></tr>"
            f"{rows}</table>"]
    for caption, fig in figs:
        body.append(f"<h2>{e(caption)}</h2><img alt='{e(caption)}' src='data:image/png;base64,{_png(fig)}'>")
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'>"
            f"<title>{e(title)}</title><style>body{{font-family:sans-serif;max-width:1000px;margin:auto}}"
            "img{max-width:100%}</style></head><body>" + "".join(body) + "</body></html>")

