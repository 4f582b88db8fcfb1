# SPDX-License-Identifier: Apache-2.0
"""The node over real DDS (rclpy, FastDDS, localhost): estimates, faults, parameters.

Every test gets its own DDS domain and rclpy context (test/rosgraph.py); discovery is
localhost-only; every wait is bounded. Recording and replay: test_ros_record.py.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph import (  # noqa: E402
    CONTROLLER,
    PAPER,
    Feed,
    Listener,
    await_estimate_ending_at,
    await_subscribers,
    fast_params,
    publish_sim,
    publishers,
    wait_for,
)  # fmt: skip
from rosgraph import graph as graph  # noqa: E402  (the fixture)

from mr_ident.io.config import IdentConfig  # noqa: E402
from mr_ident.io.modelfile import load_model  # noqa: E402
from mr_ident.live.estimate import estimate  # noqa: E402
from mr_ident.live.replay import replay  # noqa: E402
from mr_ident.numerics.excitation.sources import SimSource  # noqa: E402
from mr_ident.ros.messages import BLOCK_QOS, BODE_TOPICS, block_msg  # noqa: E402
from mr_ident.ros.node import IdentNode  # noqa: E402


def test_sim_to_node_estimate_matches_the_exact_plant(graph):
    """Noise-free paper example, 20 s window: the published plant_frf within 1e-4 (median relative)
    and 1e-2 (max, at the resonances) of the exact P_h on the published grid. (The LPM's bias grows
    with the bin spacing to the power R+1: 1.6e-5 here against 3e-10 for the 600 s paper
    record.)"""
    model = load_model(PAPER)
    node = graph.ident(fast_params(legacy_array_topics=True))
    lis = Listener(graph)
    publish_sim(publishers(graph), model, 24.0)
    wait_for(
        lambda: (
            node.last_estimate is not None
            and "pfg" in lis.msgs
            and "pfg_data_std" in lis.msgs
            and "plant_frf" in lis.msgs
            and lis.msgs["plant_frf"].layout.dim[3].size > 0
        ),
        30,
        "an estimate",
    )
    wait_for(lambda: "bode_phase_deg" in lis.msgs, 10, "the plot topics")
    f, P = lis.plant_arrays()
    est = node.last_estimate
    assert est.n_samples == IdentConfig(window_s=20.0).window_samples
    Ptrue = model.plant_discrete().freqresp(f)
    rel = np.abs(P - Ptrue) / np.abs(Ptrue)
    assert np.median(rel) < 1e-4 and rel.max() < 1e-2
    pfg_data = np.frombuffer(lis.msgs["pfg_data"].data)  # published beside the model's PFG
    assert pfg_data.size == f.size and np.all(np.isfinite(pfg_data))

    def plot_topics_match_plant_frf() -> bool:
        """The plot topics equal the plant_frf they came with: log10 f (1e-12), dB (1e-9
        relative), unwrapped phase (1e-9 rad). Waited for, because the executor thread
        delivers the next estimate's messages one topic at a time while more data arrives."""
        f, P = lis.plant_arrays()
        b = {k: np.frombuffer(lis.msgs[k].data) for k in BODE_TOPICS}
        return (
            b["bode_mag_db"].size == f.size
            and np.allclose(b["log10_frequency"], np.log10(f), rtol=1e-12, atol=0)
            and np.allclose(b["bode_mag_db"], 20 * np.log10(np.abs(P[:, 0, 0])), rtol=1e-9, atol=0)
            and np.allclose(
                np.radians(b["bode_phase_deg"]), np.unwrap(np.angle(P[:, 0, 0])), rtol=0, atol=1e-9
            )
        )

    wait_for(plot_topics_match_plant_frf, 10, "plot topics equal to their plant_frf")
    assert f.size <= 1000 and [d.label for d in lis.msgs["plant_frf"].layout.dim] == [
        "output",
        "input",
        "part",
        "frequency",
    ]
    assert est.phase_source == "auto" and est.phase == model.sample_phase

    def estimate_equals_the_arrays() -> bool:
        """~/estimate carries the same estimate as the legacy arrays, with its window."""
        e, (f, P) = lis.estimate, lis.plant_arrays()
        return (
            e is not None
            and np.array_equal(e.frequency, f)
            and np.array_equal(e.response, P)
            and np.array_equal(e.pfg_data, np.frombuffer(lis.msgs["pfg_data"].data))
        )

    wait_for(estimate_equals_the_arrays, 10, "~/estimate equal to the legacy arrays")
    e = lis.estimate
    assert e.window_last - e.window_first + 1 == est.n_samples and e.window_first % 3 == 0
    assert e.stamp_ns > 1e18 and e.halfwidth.size == e.frequency.size and e.halfwidth.min() >= 8
    assert (e.fs_high, e.ratio, e.method, e.local_model) == (240.0, 3, "freq-lifted", "polynomial")


def test_dropped_block_is_reported_and_excluded(graph):
    """One output block (240 samples, longer than a 10 s window bridges) never arrives:
    /diagnostics says gap (WARN), the window restarts after it and the next estimate, from
    clean data only, is as accurate as without the drop."""
    model = load_model(PAPER)
    node = graph.ident(fast_params(window_s=10.0))
    lis = Listener(graph)
    sent = publish_sim(publishers(graph), model, 26.0, skip=(2, 5), block=240)
    gap_end = sent[6][0]
    wait_for(
        lambda: (
            node.last_estimate is not None
            and node.last_estimate.first >= gap_end
            and node.last_estimate.first + node.last_estimate.n_samples == sent[-1][0] + 240
        ),
        30,
        "an estimate of the final window",
    )
    st = node.inputs.aligner.stats["output"]
    assert (st.gaps, st.gap_samples, st.bridged) == (1, 240, 0)
    # past the limit (a 10 s window bridges holes of up to 141 samples): the WARN says so
    assert "(longer than 141 samples); window restarts" in node.inputs.aligner.breaks[0]
    wait_for(
        lambda: lis.diag and lis.last_diag()[2].get("output.gaps") == "1",
        5,
        "diagnostics with the gap",
    )
    level, message, values = lis.last_diag()
    assert level == b"\x01" or level == 1, (level, message)
    assert "gap" in message or "stalled" in message
    assert float(values["warm_up_s"]) > 0.0  # done before the estimates
    P = node.last_estimate.identification.plant
    Ptrue = model.plant_discrete().freqresp(P.frequency)
    assert np.median(np.abs(P.response - Ptrue) / np.abs(Ptrue)) < 1e-3  # 10 s window: bias ~1e-4


def test_node_survives_faults_reports_each_and_never_estimates_across_one(graph, monkeypatch):
    """Faults, one after another, between clean blocks: a NaN sample, a wrong layout, a wrong
    length, a negative index, a repeated block, a repeated index with other samples, all streams
    stopping, the publisher restarting from index 0, and a burst of 400 blocks at once.

    Each is reported on /diagnostics (WARN, its reason in the message or recent_anomalies), the
    node keeps estimating, and every window it identified is exactly one stretch of clean
    published data: no gap, no NaN, no two runs mixed."""
    import mr_ident.ros.node as node_mod

    windows = []
    real_estimate = node_mod.estimate

    def checked(window, cfg):
        windows.append((window.first, window.r.copy(), window.u.copy(), window.y.copy()))
        return real_estimate(window, cfg)

    monkeypatch.setattr(node_mod, "estimate", checked)

    model = load_model(PAPER)
    node = graph.ident(fast_params(window_s=5.0, stall_timeout_s=1.0))
    lis = Listener(graph)
    pubs = publishers(graph)
    await_subscribers(pubs)
    feed = Feed(pubs, model, seed=1)

    def estimates_after(n_before, what):
        wait_for(lambda: node._estimates > n_before, 20, f"an estimate after {what}")

    def reported(text, what, level=1):
        def seen():
            for st in list(lis.diag):
                vals = {kv.key: kv.value for kv in st.values}
                if st.level[0] == level and (
                    text in st.message or text in vals.get("recent_anomalies", "")
                ):
                    return True
            return False

        wait_for(seen, 10, f"/diagnostics to report {what} ({text!r})")
        lis.diag.clear()

    feed.send(60)
    estimates_after(0, "the clean start")

    def fault(what, text, inject, level=1):
        n = node._estimates
        inject()
        feed.send(9)  # the first whole window that could include the fault ...
        time.sleep(0.6)  # ... is up for identification (3 update periods)
        feed.send(51)
        reported(text, what, level)
        estimates_after(n, what)

    def nan_block():
        first, xs = feed.take()
        xs[2] = xs[2].copy()
        xs[2][17] = np.nan
        for p, x in zip(pubs, xs, strict=False):
            p.publish(block_msg(first, x))

    def bad(stream, edit):
        msg = block_msg(feed.src.next_index, np.ones(feed.block))
        edit(msg)
        pubs[stream].publish(msg)

    def relabel(m):
        m.layout.dim[0].label = "rows"

    def shorten(m):
        m.data = m.data[:-5]

    def negative(m):
        m.data[0] = -240.0

    def repeat_block():
        first, *xs = feed.runs[-1][-1]
        for p, x in zip(pubs, xs, strict=False):
            p.publish(block_msg(first, x))

    def repeat_other():
        first = feed.src.next_index - feed.block
        pubs[0].publish(block_msg(first, np.zeros(feed.block)))

    fault("a NaN sample", "is NaN or inf", nan_block)
    fault("a wrong layout", "layout dims must be labelled", lambda: bad(1, relabel))
    fault("a wrong length", "data has", lambda: bad(0, shorten))
    fault("a negative index", "first sample index", lambda: bad(2, negative))
    fault("a repeated block", "received twice", repeat_block)
    fault("a repeated index with other samples", "with other samples", repeat_other)
    fault(
        "streams that stop", "stalled", lambda: time.sleep(2.5)
    )  # > stall_timeout_s + one 1 Hz tick
    fault("a publisher restart", "index went back", lambda: feed.restart(seed=2))
    n = node._estimates
    feed.send(400, pause=0.0)  # a burst: 48 000 samples per topic at once
    estimates_after(n, "a burst")
    feed.send(60)
    await_estimate_ending_at(node, feed.src.next_index, 20)

    stats = node.inputs.aligner.stats
    assert stats["output"].nonfinite == 1 and stats["input"].malformed == 1
    assert stats["reference"].malformed == 1 and stats["output"].malformed == 1
    assert all(stats[s].duplicates >= 1 for s in stats) and stats["reference"].restarts >= 2
    assert all(st.gaps == 0 or st.gap_samples > 0 for st in stats.values())
    assert len(windows) >= 10
    for first, r, u, y in windows:
        assert np.isfinite(r).all() and np.isfinite(u).all() and np.isfinite(y).all()
        assert feed.truth_of(first, r, u, y), f"window at {first} is not one clean stretch"
    P = node.last_estimate.identification.plant
    Ptrue = model.plant_discrete().freqresp(P.frequency)
    assert (
        np.median(np.abs(P.response - Ptrue) / np.abs(Ptrue)) < 1e-2
    )  # 5 s window after the burst


def test_parameters_are_validated_with_a_reason(graph):
    node = graph.ident(fast_params())
    bad = {
        "ratio": 0,
        "lifting_phase": "7",
        "method": "welch",
        "window_s": 1.0,
        "n": 1,
        "controller_num": [1.0, 2.0, 3.0],
    }
    for name, value in bad.items():
        res = node.set_parameters([Parameter(name, value=value)])[0]
        assert not res.successful, name
        assert name in res.reason or "LPM" in res.reason or "min_window_s" in res.reason, (
            res.reason
        )
    assert node.config.ratio == 3 and node.config.method == "freq-lifted"
    res = node.set_parameters([Parameter("lifting_phase", value="2"), Parameter("n", value=10)])
    assert all(r.successful for r in res)
    assert node.config.phase == 2 and node.config.n == 10


def test_live_and_replay_take_the_same_path_for_every_block_bad_ones_included(graph, tmp_path):
    """The same CDR bytes - clean blocks, a block with a NaN sample, a wrong layout, bytes
    that do not decode, a repeated block - go to the node's callback and, recorded, through
    replay: the streams' counters, the window and the estimate are identical."""
    from rclpy.serialization import serialize_message

    from mr_ident.io.blocks import BLOCK_TYPE
    from mr_ident.io.recording import McapRecorder
    from mr_ident.ros.messages import qos_dict

    model = load_model(PAPER)
    src = SimSource(model, block=240, seed=5)
    raws: list[tuple[int, bytes]] = []
    for k in range(40):
        first, r, u, y = src.next()
        for s, x in enumerate((r, u, y)):
            if (k, s) == (12, 2):
                x = x.copy()
                x[7] = np.nan  # a NaN sample: a hole of 240
            msg = block_msg(first, x)
            if (k, s) == (20, 1):
                msg.layout.dim[0].label = "rows"  # wrong layout
            raws.append((s, bytes(serialize_message(msg))))
            if (k, s) == (25, 0):
                raws.append((s, b"\x00\x01\x02 not CDR"))  # undecodable
            if (k, s) == (30, 2):
                raws.append((s, raws[-1][1]))  # the same block again
    cfg = IdentConfig(
        window_s=5.0,
        min_window_s=5.0,
        controller_num=(6000.0, -5400.0),
        controller_den=(1.0, -0.3),
    )
    node = IdentNode(
        context=graph.ctx,
        parameter_overrides=[
            Parameter(k, value=v)
            for k, v in cfg.as_dict().items()
            if k in ("window_s", "min_window_s")
        ]
        + CONTROLLER
        + [Parameter("autostart", value=True)],
    )
    try:
        assert node.autostart()
        for s, raw in raws:
            node.inputs.on_block(s, raw)
        node.inputs.ingest.expire(float("inf"), 0.0)
        live_stats = {k: v.as_dict() for k, v in node.inputs.aligner.stats.items()}
        window = node.inputs.aligner.window(node.config.min_samples)
    finally:
        node.shutdown()
        node.destroy_node()
    rec = tmp_path / "same.mcap"
    with McapRecorder(rec) as mcap:
        qos = [qos_dict(BLOCK_QOS)]
        ch = [mcap.add_topic(t, BLOCK_TYPE, qos) for t in ("/reference", "/input", "/output")]
        for i, (s, raw) in enumerate(raws):
            mcap.write(ch[s], raw, i, i)
    res = replay(rec, node.config)
    assert {k: v.as_dict() for k, v in res.stats.items()} == live_stats
    assert live_stats["output"]["nonfinite"] == 1 and live_stats["output"]["gaps"] == 1
    assert live_stats["input"]["malformed"] == 1 and live_stats["reference"]["malformed"] == 1
    assert live_stats["output"]["duplicates"] == 1
    assert window is not None and (res.estimate.first, res.estimate.n_samples) == (
        window.first,
        window.n_samples,
    )
    live = estimate(window, node.config)
    np.testing.assert_array_equal(
        res.estimate.identification.plant.response, live.identification.plant.response
    )


def test_a_setpoint_excited_loop_is_read_as_such_and_identified(graph):
    """r is the controller's setpoint: the node reads it from the held u, says so on
    /diagnostics, and publishes P_h right away from the hold's zeros (noise-free, 20 s)."""
    from dataclasses import replace

    model = replace(load_model(PAPER), injection="setpoint")
    node = graph.ident(fast_params())
    lis = Listener(graph)
    publish_sim(publishers(graph), model, 24.0)
    wait_for(lambda: node.last_estimate is not None and lis.estimate is not None, 30, "one")
    est = node.last_estimate
    assert est.identification.injection == "setpoint" and "setpoint" in est.structure
    f, P = lis.plant()
    exact = model.plant_discrete().freqresp(f)
    away = np.minimum(f % 80.0, 80.0 - f % 80.0) > 1.0
    rel = np.abs(P - exact)[away] / np.abs(exact[away])
    assert np.median(rel) < 1e-4  # the LPM's bias at 20 s, as with r at the plant input

    def said() -> bool:
        values = {kv.key: kv.value for d in lis.diag[-3:] for kv in d.values}
        return values.get("injection") == "setpoint" and "F = 3" in values.get(
            "loop_structure", ""
        )

    wait_for(said, 10, "/diagnostics naming the setpoint")
    e = lis.estimate
    assert e.injection == "setpoint" and "F = 3" in e.loop_structure
    assert e.undetermined is not None and e.undetermined.size == e.frequency.size
    assert np.isnan(e.response[e.undetermined]).sum() <= e.undetermined.sum()
