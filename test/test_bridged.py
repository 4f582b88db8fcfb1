# SPDX-License-Identifier: Apache-2.0
"""Holes of u and y bridged as missing samples: the aligner keeps its window over them (up
to the limits derived from the fit's degrees of freedom, ``mr_ident.live.gaps``), a hole of
r or a longer one splits; offline, a bag with dropped /joint_states messages is identified
whole, and diagnosed whole (``test_diagnose_holes``: how).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from bagmaker import joint_state_bag, stamps
from test_bags import PAPER, R, U, Y

from mr_ident.cli import main
from mr_ident.io.blocks import Block
from mr_ident.io.modelfile import load_model
from mr_ident.live.align import Aligner
from mr_ident.live.gaps import Bridging
from mr_ident.live.recordings import load_recording
from mr_ident.numerics.identify import identify
from mr_ident.numerics.lifted.options import missing_limits
from mr_ident.numerics.systems.simulate import simulate

SPECS = {"r": [R], "u": [U], "y": [Y]}


def _aligner(gap=20, share=0.05, capacity=3000, min_samples=600, **kw):
    b = Bridging(gap, share, min_samples, capacity)
    return Aligner(capacity, 3, bridge=lambda n_in, n_out: b, **kw)


def _feed(al, x, skip=(), size=10):
    """Blocks of ``size`` samples of r, u, y; block starts in skip[stream] left out."""
    for s in range(3):
        for k in range(0, x[s].shape[0], size):
            if k not in dict(skip).get(s, ()):
                al.push(s, Block(k, x[s][k : k + size]))
    al.expire(float("inf"), 0.0)


def _streams(N=3000):
    rng = np.random.default_rng(0)
    return [rng.standard_normal((N, 1)) for _ in range(3)]


def test_a_dropped_block_of_u_or_y_is_missing_samples_in_one_window():
    x = _streams()
    al = _aligner()
    _feed(al, x, skip=[(1, {500, 1700}), (2, {900})])
    w = al.window()
    assert (w.first, w.end, al.restarts) == (0, 3000, 0)
    assert np.isnan(w.u[500:510]).all() and np.isnan(w.u[1700:1710]).all()
    assert np.isnan(w.y[900:910]).all() and np.isnan(w.u).sum() == 20
    np.testing.assert_array_equal(w.r, x[0])
    st = al.stats["input"]
    assert (st.gaps, st.gap_samples, st.bridged, st.bridged_samples) == (2, 20, 2, 20)
    assert al.missing(0, 3000) == 30


def test_a_hole_of_r_a_long_hole_and_too_many_holes_split_and_say_why():
    x = _streams()
    al = _aligner()
    _feed(al, x, skip=[(0, {1000})])  # 10 samples of r: more than a block of F = 3
    assert al.restarts == 1 and al.window().first >= 1010
    assert "longer than 3 samples: r is recovered within a block" in al.breaks[0]
    al = _aligner(gap=15)
    _feed(al, x, skip=[(2, {1000, 1010})])  # 20 consecutive samples
    assert al.restarts == 1 and "longer than 15 samples" in al.breaks[0]
    al = _aligner(share=0.02)  # 600-sample windows at least: 12 samples
    _feed(al, x, skip=[(1, {100, 300})])
    assert al.restarts == 1 and "20 of the window's 600 samples would be missing" in al.breaks[0]
    assert al.window().first >= 310


def test_a_nan_block_and_a_block_arriving_late_into_a_hole_keep_the_window():
    x = _streams()
    al = _aligner()
    for s in range(3):
        for k in range(0, 3000, 10):
            if s == 2 and k == 600:
                assert al.hole(2, 600, 10) is None  # NaN block, at the stream's end
            elif s == 2 and k == 800:
                continue
            else:
                al.push(s, Block(k, x[s][k : k + 10]))
        al.expire(float("inf"), 0.0)
    al.push(2, Block(800, x[2][800:810]))  # came after the hole was declared: stays a hole
    w = al.window()
    assert (w.first, w.end, al.restarts) == (0, 3000, 0)
    assert np.isnan(w.y).sum() == 20 and al.stats["output"].duplicates == 1


def test_the_limits_come_from_the_fits_degrees_of_freedom():
    """freq-lifted, n auto (base 8), SISO, F = 3: the method's fit carries (5-3)/17 = 11.8 %,
    half of it is bridged; one hole may take all of that share."""
    lim = missing_limits("freq-lifted", 8, 2, 3, 1, 1, n_samples=14400, auto=True)
    assert lim.share == pytest.approx(0.5 * 2 / 17) and lim.gap == int(lim.share * 14400)


@pytest.fixture(scope="module")
def dropped(tmp_path_factory):
    """60 s of the paper's loop; 1 % of the /joint_states messages dropped at random."""
    model = load_model(PAPER)
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(0))
    rng = np.random.default_rng(7)
    drop = set(rng.choice(np.arange(5, sim.n_samples - 5), sim.n_samples // 100, replace=False))
    path = tmp_path_factory.mktemp("dropped") / "bag"
    joint_state_bag(path, sim, stamps(sim.n_samples, 240.0), drop=drop)
    return model, sim, path, np.array(sorted(drop))


def test_a_bag_with_dropped_messages_is_identified_whole(dropped):
    model, sim, path, drop = dropped
    loaded = load_recording(path, specs=SPECS, ratio=3, fs_high=240.0)
    data = loaded.data
    assert (data.first, data.end) == (0, sim.n_samples) and not loaded.notes
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(data.y[:, 0])), drop)
    res = identify(data.r, data.u, data.y, fs_high=240.0, ratio=3)
    assert res.n_missing.tolist() == [drop.size, drop.size]
    P = model.plant_discrete().freqresp(res.plant.frequency)
    assert float(np.median(np.abs(res.plant.response - P) / np.abs(P))) < 1e-4


def test_replay_and_diagnose_on_the_bag_with_holes(dropped, tmp_path, capsys):
    """replay: the node's last window over the holes; a bag read without bridging is its
    longest complete span (and says so); diagnose takes the record with its holes whole."""
    from dataclasses import replace

    from mr_ident.diagnosis.criterion.holes import diagnosable
    from mr_ident.diagnosis.diagnose import check_record

    model, sim, path, drop = dropped
    base = ["--r", R, "--u", U, "--y", Y, "--ratio", "3"]
    code = main(["replay", str(path), *base, "--out", str(tmp_path / "a.npz")])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert f"window [{sim.n_samples - 14400}, {sim.n_samples})" in out, out
    loaded = load_recording(path, specs=SPECS, ratio=3, fs_high=240.0, complete=True)
    assert not np.isnan(loaded.data.y).any() and "using the longest span" in loaded.notes[0]
    holes = load_recording(path, specs=SPECS, ratio=3, fs_high=240.0).data
    holes = replace(holes, fs_high=240.0, ratio=3)
    check_record(model, holes)  # within the limits: no error
    used, note = diagnosable(holes, model)
    assert used is holes and not note
    code = main(["diagnose", str(PAPER), str(path), "--r", R, "--u", U, "--y", Y,
                 "--json", str(tmp_path / "d.json")])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0 and "span" not in err and "stretch" not in err, err
    assert json.loads((tmp_path / "d.json").read_text())["cause"] == "none"


def test_the_periodic_average_with_missing_samples_is_an_error_naming_them():
    from mr_ident.errors import DataError
    from mr_ident.live.periodic import Periods, periodic_bla

    rng = np.random.default_rng(1)
    r, u, y = (rng.standard_normal((2, 4 * 60)) for _ in range(3))
    y[1, 70] = np.nan
    with pytest.raises(DataError, match="first at sample 70 of realization 1; the periodic"):
        periodic_bla(Periods(r, u, y, 60, "count"))


def test_the_lifting_phase_is_detected_over_missing_samples():
    from mr_ident.numerics.structure import held_phase

    rng = np.random.default_rng(2)
    x = np.repeat(rng.standard_normal(400), 3)[2:-1]  # held over 3, changing at index 1 mod 3
    x[[10, 11, 500, 777]] = np.nan
    phase, contrast = held_phase(0, x, 3)
    assert phase == 1 and contrast < 1e-12
    assert held_phase(0, np.column_stack([x, x]), 3)[0] == 1


def test_a_window_with_holes_beyond_the_limits_is_cut_to_its_longest_complete_stretch():
    from mr_ident.diagnosis.criterion.holes import complete_stretch
    from mr_ident.numerics.signals import LoopData

    x = np.ones((300, 1))
    u = x.copy()
    u[[50, 200]] = np.nan
    w = complete_stretch(LoopData(x, u, x, ratio=3, first=1001))
    assert (w.first, w.end) == (1053, 1200) and not np.isnan(w.u).any()


def test_options_the_channels_cannot_have_bridge_nothing_instead_of_failing_the_stream():
    from mr_ident.live.gaps import bridging

    rule = bridging(2400, 2400, ratio=3, n=4)  # n = 4 is too narrow for the lifted fit
    assert rule(1, 1) is None
    assert bridging(2400, 2400, ratio=3)(1, 1) is not None


def test_replay_of_every_span_bridges_the_holes_as_the_node_did(dropped):
    """The last window as the node saw it, and the same window cut from the whole span (its
    holes pushed as holes): one estimate."""
    from mr_ident.io.config import IdentConfig
    from mr_ident.live.replay import replay_bag

    _, _, path, _ = dropped
    cfg = IdentConfig(window_s=20.0, min_window_s=20.0)
    a = replay_bag(path, cfg, SPECS, fs_high=240.0, ratio=3)
    b = replay_bag(path, cfg, SPECS, fs_high=240.0, ratio=3, span="longest")
    assert (a.estimate.first, a.estimate.n_samples) == (b.estimate.first, b.estimate.n_samples)
    assert a.stats["output"].restarts == 0 and a.stats["output"].bridged > 100
    np.testing.assert_array_equal(
        a.estimate.identification.plant.response, b.estimate.identification.plant.response
    )
