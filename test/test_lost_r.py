# SPDX-License-Identifier: Apache-2.0
"""Missing samples of r, the excitation: recovered where the loop determines them
(``mr_ident.numerics.missing_r``), guessed and counted as noise elsewhere; a bag whose r, u
and y each lose 1 % of their messages is identified from its whole record.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from bagmaker import BagWriter, stamps
from test_bags import PAPER

from mr_ident.cli import main
from mr_ident.errors import DataError
from mr_ident.io.modelfile import load_model
from mr_ident.live.recordings import load_recording
from mr_ident.numerics.identify import identify
from mr_ident.numerics.missing_r import MAX_UNKNOWN_SHARE, recover_r
from mr_ident.numerics.systems.simulate import simulate

#: The median of |z| for a complex error of total variance 1 (Rayleigh): sqrt(ln 2).
RAYLEIGH_MEDIAN = float(np.sqrt(np.log(2.0)))


def _loop(injection, seconds=60.0, noise=0.0, seed=3):
    model = replace(load_model(PAPER), injection=injection)
    N = int(seconds * model.fs_high) // model.ratio * model.ratio
    rng = np.random.default_rng(seed)
    r = rng.standard_normal((N, 1))
    return model, simulate(model, reference=r, noise=noise * rng.standard_normal((N, 1)))


def _lose(x, rng, share=0.01, block=1):
    """x with ``share`` of its blocks of ``block`` samples set to NaN (the mask too)."""
    lost = np.repeat(rng.random(-(-x.shape[0] // block)) < share, block)[: x.shape[0]]
    out = x.copy()
    out[lost] = np.nan
    return out, lost


def _recover(model, sim, r):
    return recover_r(
        r, sim.u, sim.y, ratio=model.ratio, injection=model.injection, phase=model.sample_phase
    )


@pytest.mark.parametrize("injection", ["plant_input", "setpoint"])
@pytest.mark.parametrize("block", [1, 3])
def test_r_lost_alone_is_recovered_to_round_off(injection, block):
    """Single samples and whole blocks of F: u - r held, or the controller's equation."""
    model, sim = _loop(injection)
    r, lost = _lose(sim.r, np.random.default_rng(block), block=block)
    got = _recover(model, sim, r)
    read = lost[:, None] if injection == "plant_input" else lost[:, None] & _taken(model, r)
    # round-off of the equation's solve, relative to r's scale (1e-13 to 1e-15 here)
    scale = np.abs(sim.r).max()
    np.testing.assert_allclose(got.r[read], sim.r[read], rtol=0, atol=1e-9 * scale)
    assert got.unknown == 0 and got.recovered + got.unused == lost.sum()
    assert "recovered exactly" in got.describe()


def _taken(model, r):
    taken = np.zeros(r.shape, dtype=bool)
    taken[model.sample_phase :: model.ratio] = True
    return taken


def test_a_setpoint_held_at_the_controllers_rate_takes_its_blocks_value():
    model = replace(load_model(PAPER), injection="setpoint")
    F = model.ratio
    r_l = np.random.default_rng(4).standard_normal((4800, 1))
    sim = simulate(model, reference=np.repeat(r_l, F, axis=0))
    r = sim.r.copy()
    r[[10, 11, 301, 1000]] = np.nan  # never a whole block
    got = recover_r(r, sim.u, sim.y, ratio=F, injection="setpoint", phase=model.sample_phase)
    np.testing.assert_array_equal(got.r, sim.r)
    assert "r held over blocks" in got.how


def test_r_with_its_u_lost_too_is_unknown_guessed_and_counted():
    model, sim = _loop("plant_input")
    r, u = sim.r.copy(), sim.u.copy()
    r[[500, 900]] = u[[500, 900]] = np.nan  # u - r cannot give these
    got = recover_r(r, u, sim.y, ratio=3, injection="plant_input")
    assert (got.unknown, got.recovered) == (2, 0) and np.isfinite(got.r).all()
    assert "not determined by the data" in got.describe()


def test_more_unknown_r_than_the_limit_is_refused_naming_the_share():
    model, sim = _loop("plant_input", seconds=20.0)
    r, u = sim.r.copy(), sim.u.copy()
    bad = np.arange(0, r.shape[0], 50)  # 2 % of the samples, u lost with them
    r[bad] = u[bad] = np.nan
    with pytest.raises(DataError, match=r"r has 96 of its 4800 read samples missing .*\(2\.00 %"):
        recover_r(r, u, sim.y, ratio=3, injection="plant_input")
    assert MAX_UNKNOWN_SHARE == 0.001


def test_identify_with_r_recovered_equals_the_complete_record():
    model, sim = _loop("plant_input")
    r, _ = _lose(sim.r, np.random.default_rng(0))
    kw = {"fs_high": model.fs_high, "ratio": model.ratio}
    full, lossy = identify(sim.r, sim.u, sim.y, **kw), identify(r, sim.u, sim.y, **kw)
    # r recovered to round-off: the estimates agree to round-off of P's scale
    P = full.plant.response
    np.testing.assert_allclose(lossy.plant.response, P, rtol=0, atol=1e-9 * np.abs(P).max())
    assert lossy.r_recovered == int(np.isnan(r).sum()) and lossy.r_unknown == 0


def test_the_std_stays_honest_with_unknown_r_samples():
    """0.08 % of r lost with its u (not determined): the guesses' error is noise the local
    fit's residual contains. |P - P_h|/std is then Rayleigh-like, median sqrt(ln 2) = 0.83;
    over ~14 000 bins in windows of about 55 (about 260 independent), the sample median's
    spread is 1/(2 f(m) sqrt(260)) = 0.037 (f(m) = 0.83, the density at the median), and
    the local fit's few degrees of freedom widen the ratio's tail: 0.72..0.97 holds it."""
    model, sim = _loop("plant_input", seconds=120.0, noise=1e-6, seed=0)
    rng = np.random.default_rng(1)
    hole = rng.random(sim.n_samples) < 0.0008
    r, u = sim.r.copy(), sim.u.copy()
    r[hole] = u[hole] = np.nan
    res = identify(r, u, sim.y, fs_high=model.fs_high, ratio=model.ratio)
    P = model.plant_frf(sim.n_samples)[1:]
    z = np.abs(res.plant.response - P) / res.plant.std
    assert res.r_unknown == hole.sum()
    assert 0.72 < float(np.median(z)) < 0.97, np.median(z)


def _lossy_bag(path, sim, rng, share=0.01):
    """r, u, y on three topics (JointState: /ident/reference, /cmd, /state), each losing
    ``share`` of its messages independently."""
    t = stamps(sim.n_samples, 240.0)
    kept = [rng.random(sim.n_samples) >= share for _ in range(3)]
    js = "sensor_msgs/msg/JointState"
    with BagWriter(path) as bw:
        for k in range(sim.n_samples):
            tk = int(t[k])
            for (topic, field, x), keep in zip(
                (("/ident/reference", "position", sim.r), ("/cmd", "effort", sim.u),
                 ("/state", "position", sim.y)), kept, strict=True
            ):  # fmt: skip
                if keep[k]:
                    msg = bw.joint_state(tk, ["j1"], **{field: [x[k, 0]]})
                    bw.write(topic, js, msg, tk + 300_000)
    return [~k for k in kept]


LOSSY = ["--r", '/ident/reference.position{name=="j1"}', "--u", '/cmd.effort{name=="j1"}',
         "--y", '/state.position{name=="j1"}']  # fmt: skip


def test_a_bag_losing_1_percent_of_each_topic_is_identified_from_its_whole_record(
    tmp_path, capsys
):
    model, sim = _loop("plant_input", seconds=60.0, seed=8)
    lost = _lossy_bag(tmp_path / "bag", sim, np.random.default_rng(9))
    specs = {"r": [LOSSY[1]], "u": [LOSSY[3]], "y": [LOSSY[5]]}
    data = load_recording(tmp_path / "bag", specs=specs, ratio=3, fs_high=240.0).data
    first, end = data.first, data.end
    assert (end - first) >= 0.9 * sim.n_samples, (first, end)
    assert np.isnan(data.r).sum() >= 0.8 * lost[0][first:end].sum()
    code = main(["identify", str(tmp_path / "bag"), *LOSSY, "--model", str(PAPER),
                 "--out", str(tmp_path / "res.npz")])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "samples of r missing" in out and "recovered exactly" in out, out
    res = np.load(tmp_path / "res.npz")
    P = model.plant_discrete().freqresp(res["frequency"])
    e = np.abs(res["P"][:, 0, 0] - P[:, 0, 0]) / np.abs(P[:, 0, 0])
    assert float(np.median(e)) < 1e-3


def test_a_live_window_whose_r_the_loop_cannot_give_restarts_after_its_last_hole():
    """u measured with noise (no hold): r's holes are not determined; the node's estimate
    takes the window's part after the last of them (as after a hole it cannot bridge) and
    says so; offline, a recording falls back to its longest span without holes."""
    from mr_ident.io.config import IdentConfig
    from mr_ident.live.estimate import estimate
    from mr_ident.numerics.signals import LoopData

    model, sim = _loop("plant_input", seconds=60.0, noise=1e-6)
    rng = np.random.default_rng(2)
    u = sim.u + 1e-3 * np.abs(sim.u).max() * rng.standard_normal(sim.u.shape)  # no hold
    r = sim.r.copy()
    r[[4000, 9001]] = np.nan
    r[9002:9030] = np.nan  # 30 of 14400 in all: 0.21 %, beyond the 0.1 % a fit takes
    cfg = IdentConfig(window_s=60.0, min_window_s=10.0)
    est = estimate(LoopData(r, u, sim.y, ratio=3, first=0), cfg)
    assert "identified after the last of them, [9030, 14400)" in est.structure
    assert (est.first, est.n_samples) == (9030, 14400 - 9030)


def test_a_periodic_r_is_recovered_from_its_own_period_where_the_loop_cannot_give_it():
    """A multisine of two realizations x 4 periods at the plant input, u measured with noise
    (no hold: the loop does not determine r): a lost r is the same sample one period away,
    exactly; none is taken across a realization's edge."""
    from mr_ident.numerics.excitation.multisine import design

    model = load_model(PAPER)
    ms = design(fs_high=240.0, period=480, band=(0.5, 100.0), kind="odd", periods=4,
                realizations=2)  # fmt: skip
    r_full = ms.r.reshape(-1, 1)  # realization after realization
    sim = simulate(model, reference=r_full)
    rng = np.random.default_rng(3)
    u = sim.u + 1e-3 * rng.standard_normal(sim.u.shape)  # no hold
    r, lost = _lose(sim.r, rng)
    got = recover_r(r, u, sim.y, ratio=3, injection="plant_input")
    assert got.unknown <= 2 and "r's own period" in got.how  # 2 at most: near an edge
    exact = np.abs(got.r - sim.r)[:, 0] <= 1e-12 * np.abs(sim.r).max()  # the design's round-off
    assert exact[lost].sum() == got.recovered == lost.sum() - got.unknown
