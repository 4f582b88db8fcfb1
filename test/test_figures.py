# SPDX-License-Identifier: Apache-2.0
"""Figures a control engineer reads at once (mr_ident.plots): units, the band, labels in the
frame, one phase convention, readable ticks; numbers written to files as given."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from matplotlib.backends.backend_agg import FigureCanvasAgg

from mr_ident import plots
from mr_ident.errors import ModelError
from mr_ident.io.modelfile import load_model, model_to_dict
from mr_ident.io.units import load_units, magnitude_label
from mr_ident.numerics.results import FRF

ROOT = Path(__file__).resolve().parents[1]


def _frf(f0=0.1, f1=120.0, n=400):
    f = np.geomspace(f0, f1, n)
    s = 2j * np.pi * f
    g = 1.0 / (s * (s + 30.0)) * np.exp(-s * 0.01)
    return FRF(f, g[:, None, None], 1e-6 * np.abs(g)[:, None, None], "freq-lifted")


def test_the_magnitude_is_in_the_model_files_units_or_says_y_per_u(tmp_path):
    assert load_units(ROOT / "config" / "tutorial_robot.yaml") == ("N", "m")
    assert magnitude_label(("N m", "rad"), 0, 0, 1, 1) == "|P_h| [dB re 1 rad/(N m)]"
    assert magnitude_label(("A", "rad/s"), 0, 0, 1, 1) == "|P_h| [dB re 1 rad/s/A]"
    assert magnitude_label(None, 1, 0, 2, 1) == "|P_h y1←u0| [dB re 1 y/u]"
    fig = plots.bode_figure(_frf(), units=("N m", "rad"))
    assert fig.axes[0].get_ylabel() == "|P_h| [dB re 1 rad/(N m)]"
    bad = tmp_path / "m.yaml"
    d = yaml.safe_load((ROOT / "config" / "paper_example.yaml").read_text())
    bad.write_text(yaml.safe_dump(d | {"units": {"u": "N m"}}))
    with pytest.raises(ModelError, match=r"m.yaml: units must be a mapping with keys u and y"):
        load_model(bad)


def test_a_written_model_gives_fs_high_as_a_person_would():
    model = load_model(ROOT / "config" / "paper_example.yaml")
    d = model_to_dict(replace(model, fs_high=239.99999999999997))
    assert yaml.safe_dump(d, sort_keys=False).startswith("fs_high: 240\n")


def test_the_phase_is_unwrapped_and_nan_bins_stay_nan():
    g = np.exp(-1j * np.linspace(0, 6 * np.pi, 200))
    g[50] = np.nan
    deg = plots._phase(g)
    assert np.isnan(deg[50]) and deg[-1] == pytest.approx(-1080.0)
    assert np.all(np.diff(deg[np.isfinite(deg)]) < 0)


def _labels(ax):
    FigureCanvasAgg(ax.figure)
    ax.figure.canvas.draw()
    lo, hi = ax.get_xlim()
    return [
        t.get_text()
        for t, v in zip(ax.get_xticklabels(), ax.get_xticks(), strict=True)
        if lo <= v <= hi and t.get_text()
    ]


def test_a_short_log_axis_has_several_labelled_ticks():
    fig = plots.bode_figure(_frf(11.0, 250.0))
    labels = _labels(fig.axes[-1])
    assert len(labels) >= 4 and "20" in labels and "100" in labels


def test_an_axis_of_less_than_a_decade_has_four_labels_and_the_phase_ticks_fit_its_span():
    fig = plots.bode_figure(_frf(55.0, 230.0))
    assert len(_labels(fig.axes[-1])) >= 4
    ticks = [t for t in fig.axes[1].get_yticks() if np.ptp(fig.axes[1].get_ylim()) > 0]
    lo, hi = fig.axes[1].get_ylim()
    assert 3 <= sum(lo <= t <= hi for t in ticks) <= 9


def test_the_low_rate_nyquist_label_lies_inside_the_frame():
    fig = plots.bode_figure(_frf(), nyquist_low=40.0)
    FigureCanvasAgg(fig)
    fig.canvas.draw()
    ax = fig.axes[0]
    (text,) = [t for t in ax.texts if "Nyquist" in t.get_text()]
    box, frame = text.get_window_extent(), ax.get_window_extent()
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 <= box.y1 <= frame.y1


def test_the_band_says_how_wide_it_is_where_the_line_hides_it():
    fig = plots.bode_figure(_frf())
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert any(lab.startswith("±2σ (at most ") and "within the line" in lab for lab in labels)
    wide = _frf()
    wide = FRF(wide.frequency, wide.response, 0.3 * np.abs(wide.response), wide.method)
    assert "±2σ" in plots.bode_figure(wide).axes[0].get_legend_handles_labels()[1]


def test_the_pfgs_are_named_in_words():
    assert plots.pfg_label("data:lifted r->y") == "PFG from data (lifted r→y)"
    assert plots.pfg_label("plant:freq-lifted") == "PFG from P_h and K_l (freq-lifted)"


def test_a_long_record_is_drawn_thinned_with_every_peak_and_notch_kept():
    f = np.linspace(0.01, 120.0, 144_000)
    g = np.ones(f.size, complex)
    g[100_000] = 50.0  # one bin's peak
    g[120_000] = 1e-3  # one bin's notch
    k = plots._thin(f, [plots._db(g)])
    assert k.size < 8_000 and {100_000, 120_000} <= set(k.tolist())
    assert np.all(np.diff(k) > 0) and k[0] == 0 and k[-1] == f.size - 1
    short = np.linspace(1.0, 10.0, 500)
    np.testing.assert_array_equal(plots._thin(short, [short]), np.arange(500))
