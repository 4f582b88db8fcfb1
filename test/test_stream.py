# SPDX-License-Identifier: Apache-2.0
"""Topic contract, index alignment, phase detection, config and MCAP reading (no ROS)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import require_interfaces

from mr_ident.errors import ConfigError, DataError
from mr_ident.io.blocks import Block, BlockError, decode_block, encode_fields
from mr_ident.io.config import IdentConfig, load_params
from mr_ident.live.align import Aligner
from mr_ident.live.estimate import detect_phase, estimate, publish_grid, warm_up
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import LoopStream, simulate

ROOT = Path(__file__).resolve().parents[1]


def _blocks(x, sizes):
    out, k = [], 0
    for n in sizes:
        if k >= x.shape[0]:
            break
        out.append(Block(k, x[k : k + n]))
        k += n
    return out


def test_encode_decode_round_trip():
    x = np.arange(12.0).reshape(6, 2)
    b = decode_block(*encode_fields(17, x))
    assert b.first == 17 and np.array_equal(b.samples, x)


@pytest.mark.parametrize(
    "dims, offset, data, kind",
    [
        ([("samples", 2, 2)], 1, [0, 1, 2], "malformed"),  # one dim
        ([("channels", 2, 2), ("samples", 1, 1)], 1, [0, 1, 2], "malformed"),  # labels swapped
        ([("samples", 2, 3), ("channels", 1, 1)], 1, [0, 1, 2], "malformed"),  # stride
        ([("samples", 2, 2), ("channels", 1, 1)], 0, [0, 1, 2], "malformed"),  # offset
        ([("samples", 2, 2), ("channels", 1, 1)], 1, [0, 1], "malformed"),  # length
        ([("samples", 2, 2), ("channels", 1, 1)], 1, [-1, 1, 2], "malformed"),  # negative index
        ([("samples", 2, 2), ("channels", 1, 1)], 1, [0.5, 1, 2], "malformed"),  # fractional index
        ([("samples", 2, 2), ("channels", 1, 1)], 1, [0, np.nan, 2], "nonfinite"),
    ],
)
def test_decode_rejects_contract_violations(dims, offset, data, kind):
    with pytest.raises(BlockError) as err:
        decode_block(dims, offset, np.asarray(data, dtype=float))
    assert err.value.kind == kind


def _streams(N=3000, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.standard_normal((N, 1)) for _ in range(3)]


def test_reordered_split_and_duplicated_blocks_give_the_original_window():
    rng = np.random.default_rng(1)
    x = _streams()
    al = Aligner(capacity=3000, ratio=3, reorder_blocks=4)
    for s in range(3):
        blocks = _blocks(x[s], rng.integers(1, 200, size=200))
        order = np.argsort(
            np.arange(len(blocks)) + rng.uniform(0, 3, len(blocks))
        )  # local shuffles
        for i in order:
            assert al.push(s, blocks[i]) is None
        al.push(s, blocks[3])  # a duplicate
    w = al.window()
    assert w.first == 0 and w.n_samples == 3000
    for s, a in enumerate((w.r, w.u, w.y)):
        np.testing.assert_array_equal(a, x[s])
    st = al.stats["output"]
    assert st.gaps == 0 and st.duplicates >= 1 and st.samples == 3000


def test_a_gap_restarts_the_window_after_it():
    x = _streams()
    al = Aligner(capacity=3000, ratio=3, reorder_blocks=2)
    for s in range(3):
        for b in _blocks(x[s], [100] * 30):
            if not (s == 1 and b.first == 1000):
                al.push(s, b)
    st = al.stats["input"]
    assert (st.gaps, st.gap_samples) == (1, 100)
    w = al.window()
    assert w.first >= 1100 and w.first % 3 == 0 and w.end <= 3000
    np.testing.assert_array_equal(w.u, x[1][w.first : w.end])


def test_missing_block_is_declared_a_gap_after_the_wait():
    x = _streams(600)
    al = Aligner(capacity=600, ratio=3, reorder_blocks=100)
    for b in _blocks(x[0], [100] * 6):
        if b.first != 200:
            al.push(0, b, now=1.0)
    assert al.expire(now=1.2, max_wait=0.5) == []
    notes = al.expire(now=2.0, max_wait=0.5)
    assert len(notes) == 1 and "gap of 100 samples at [200, 300)" in notes[0]


def test_nan_block_is_a_hole_and_index_restart_is_detected():
    x = _streams(1200)
    al = Aligner(capacity=1200, ratio=3)
    for s in range(3):
        for b in _blocks(x[s], [300] * 4):
            if s == 2 and b.first == 300:
                al.hole(2, 300, 300)
            else:
                al.push(s, b)
    assert al.window().first >= 600
    note = al.push(0, Block(0, x[0][:300] + 1.0))  # publisher restarted from 0
    assert "restarts" in note and al.stats["reference"].restarts == 1


def test_an_overlap_with_other_samples_restarts_the_stream_instead_of_splicing():
    """A block whose index range overlaps held samples but disagrees there: the stream
    restarts at it, so no window holds two different samples for one index."""
    x = _streams(900)
    al = Aligner(capacity=900, ratio=3)
    for s in range(3):
        for b in _blocks(x[s], [150] * 6):
            al.push(s, b)
    assert al.push(0, Block(300, x[0][300:450])) is not None  # an exact duplicate: reported
    assert al.stats["reference"].duplicates == 1 and al.window().n_samples == 900
    other = x[0][450:600] + 1.0
    note = al.push(0, Block(820, other))  # overlaps [820, 900) with other values
    assert "index went back from 900 to 820 with other samples; stream restarts at 970" in note
    assert al.stats["reference"].restarts == 1 and al.stats["reference"].overlaps == 0
    assert al.window() is None  # neither version of [820, 970) is used
    y = _streams(1200)
    al.push(0, Block(970, y[0][970:1200]))
    for s in (1, 2):
        al.push(s, Block(900, y[s][900:1200]))
    w = al.window()
    assert (w.first, w.end) == (972, 1200)  # the F = 3 grid after the block
    np.testing.assert_array_equal(w.r, y[0][972:1200])


def test_channel_count_change_is_malformed():
    al = Aligner(capacity=100, ratio=1)
    al.push(0, Block(0, np.zeros((10, 1))))
    assert "channels" in al.push(0, Block(10, np.zeros((10, 2))))
    assert al.stats["reference"].malformed == 1


@pytest.mark.parametrize("phase, delay", [(0, 0), (1, 0), (2, 0), (1, 1)])
def test_phase_detection_finds_the_sampling_phase(paper_model, phase, delay):
    m = dataclasses.replace(
        paper_model, sample_phase=phase, control_delay=delay, controller=paper_model.controller
    )
    if delay:  # a computation delay needs a gentler controller to stay stable
        from mr_ident.numerics.systems.lti import TransferMatrix

        m = dataclasses.replace(
            m, controller=TransferMatrix.siso([600.0, -540.0], [1.0, -0.3], 3 / 240)
        )
    sim = simulate(m, duration=10, rng=np.random.default_rng(0))
    det = detect_phase(300, sim.r, sim.u, 3, control_delay=delay)
    assert det.determined and det.phase == phase and det.contrast < 1e-6


def test_phase_detection_is_undetermined_in_open_loop():
    rng = np.random.default_rng(0)
    r = rng.standard_normal(300)
    assert not detect_phase(0, r, r, 3).determined


def test_publish_grid_is_log_spaced_and_bounded():
    g = publish_grid(100_000, 1000)
    assert g.size <= 1000 and g[0] == 0 and g[-1] == 99_999 and np.all(np.diff(g) > 0)
    assert np.array_equal(publish_grid(10, 1000), np.arange(10))


def test_loop_stream_continues_exactly(paper_model):
    sim = simulate(paper_model, n_samples=1200, rng=np.random.default_rng(0))
    ls = LoopStream(paper_model)
    parts = [ls.next(sim.r[k : k + 300]) for k in range(0, 1200, 300)]
    np.testing.assert_allclose(
        np.concatenate([p[1] for p in parts]), sim.y, rtol=0, atol=1e-15 * np.abs(sim.y).max()
    )


def test_estimate_from_a_window_matches_the_plant(paper_model):
    sim = simulate(paper_model, duration=120, rng=np.random.default_rng(0))
    cfg = IdentConfig(window_s=120.0, controller_num=(6000.0, -5400.0), controller_den=(1.0, -0.3))
    al = Aligner(cfg.window_samples, 3)
    for s, x in enumerate((sim.r, sim.u, sim.y)):
        for b in _blocks(x, [1000] * 100):
            al.push(s, b)
    est = estimate(al.window(cfg.min_samples), cfg)
    P = est.identification.plant
    Ptrue = paper_model.plant_discrete().freqresp(P.frequency)
    assert np.median(np.abs(P.response - Ptrue) / np.abs(Ptrue)) < 1e-6
    assert est.identification.pfg is not None and est.phase_source == "auto"


def test_warm_up_identifies_a_synthetic_window_of_the_configured_size_silently(recwarn):
    cfg = IdentConfig(window_s=30.0, controller_num=(6000.0, -5400.0), controller_den=(1.0, -0.3))
    assert warm_up(cfg) > 0.0
    assert warm_up(cfg, n_samples=1000) > 0.0  # rounded down to whole periods
    assert not recwarn.list  # no rank-deficient bins, no NaN


def test_node_params_file_loads_and_bad_values_name_the_parameter(tmp_path):
    cfg = load_params(ROOT / "config" / "node.yaml")
    assert cfg.ratio == 3 and cfg.controller is not None
    for bad, name in (
        ({"ratio": 0}, "ratio"),
        ({"lifting_phase": "3"}, "lifting_phase"),
        ({"window_s": "long"}, "window_s"),
        ({"controller_num": [1.0]}, "controller_num"),
        ({"typo": 1}, "typo"),
        ({"min_window_s": 0.01}, "min_window_s"),
    ):
        with pytest.raises(ConfigError, match=name):
            IdentConfig().replace(**bad)
    f = tmp_path / "p.yaml"
    f.write_text("other_node:\n  ros__parameters: {ratio: 2}\n")
    with pytest.raises(ConfigError, match="no entry for node"):
        load_params(f)


def test_truncated_recording_reports_what_it_recovered(tmp_path):
    pytest.importorskip("mcap_ros2")
    require_interfaces("std_msgs/msg/Float64MultiArray")
    rec = _make_recording(tmp_path / "full.mcap")
    data = rec.read_bytes()
    from mr_ident.io.recording import read_blocks

    items, info, _ = read_blocks(rec)
    assert not info.truncated and len(items) == 3 * 40
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    items2, info2, _ = read_blocks(cut)
    assert info2.truncated and 0 < len(items2) < len(items)
    cut.write_bytes(data[:20])
    with pytest.raises(DataError):
        read_blocks(cut)


def _make_recording(path: Path) -> Path:
    """A small recording written with mcap_ros2's own writer (ROS-free)."""
    from mcap_ros2.writer import Writer

    from mr_ident.io.msgdef import message_definition

    schema_text = message_definition("std_msgs/msg/Float64MultiArray")
    rng = np.random.default_rng(0)
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2000)
        schema = w.register_msgdef("std_msgs/msg/Float64MultiArray", schema_text)
        for k in range(40):
            for topic in ("/reference", "/input", "/output"):
                dims, off, data = encode_fields(k * 50, rng.standard_normal(50))
                msg = {
                    "layout": {
                        "dim": [{"label": a, "size": b, "stride": c} for a, b, c in dims],
                        "data_offset": off,
                    },
                    "data": data.tolist(),
                }
                w.write_message(topic, schema, msg, log_time=k, publish_time=k)
        w.finish()
    return path


def test_a_stream_running_ahead_does_not_shorten_the_window():
    x = _streams(6000)
    al = Aligner(capacity=1500, ratio=3)
    blocks = [_blocks(x[s], [500] * 12) for s in range(3)]
    for k in range(5):  # all three to 2500
        for s in range(3):
            al.push(s, blocks[s][k])
    for b in blocks[0][5:8]:  # reference runs a window ahead, to 4000
        al.push(0, b)
    for s in (1, 2):  # input and output reach 3000
        al.push(s, blocks[s][5])
    w = al.window()
    assert (w.first, w.n_samples) == (1500, 1500)
    np.testing.assert_array_equal(w.r, x[0][1500:3000])
    for b in blocks[0][8:]:  # further ahead: memory stays bounded
        al.push(0, b)
    assert sum(c[1].shape[0] for c in al._s[0].chunks) <= 2 * 1500 + 500


@pytest.mark.parametrize("end", [16000, 16001, 16002])
def test_windows_are_full_length_on_the_period_grid(end):
    x = _streams(end)
    al = Aligner(capacity=1500, ratio=3)
    for s in range(3):
        for b in _blocks(x[s], [1000] * 17):
            al.push(s, b)
    w = al.window()
    assert w.n_samples == 1500 and w.first % 3 == 0 and w.end == end // 3 * 3


def test_a_mimo_controller_from_node_parameters_gives_the_models_pfg():
    """K_l 2x2 given as the node's flat parameters (entries row-major, padded) is the model's
    K_l; the estimate of a noise-free MIMO loop then has the model's PFG (1e-5 median
    relative) and the warm-up runs with the configured channels."""
    from mr_ident.io.modelfile import model_from_dict
    from mr_ident.numerics.lifted.pfg import pfg_of_model

    model = model_from_dict(
        {
            "fs_high": 100.0,
            "ratio": 2,
            "plant": {"num": [[[1.0], [0.2]], [[0.1], [2.0]]], "den": [1.0, 3.0, 10.0]},
            "controller": {"num": [[[0.5, 0.0], [0.0]], [[0.0], [0.4, 0.0]]], "den": [1.0, -0.5]},
        }
    )
    cfg = IdentConfig(
        fs_high=100.0,
        ratio=2,
        window_s=200.0,
        n=10,
        controller_rows=2,
        controller_cols=2,
        controller_num=(0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.0),  # [0,1], [1,0] padded zeros
        controller_den=(1.0, -0.5) * 4,
    )
    M = 1000
    np.testing.assert_allclose(
        cfg.controller.dft_response(M), model.controller_frf(M), rtol=1e-12, atol=1e-15
    )
    sim = simulate(model, duration=200.0, rng=np.random.default_rng(3))
    est = estimate(LoopData(sim.r, sim.u, sim.y, 100.0, 2), cfg)
    truth = pfg_of_model(model, sim.r.shape[0])
    rel = np.abs(est.identification.pfg.gain - truth.gain) / np.abs(truth.gain)
    assert np.nanmedian(rel) < 1e-5
    assert warm_up(cfg, n_samples=4000) > 0.0
    with pytest.raises(ConfigError, match="not a multiple of the 4 entries"):
        cfg.replace(controller_num=(1.0, 2.0, 3.0))
    with pytest.raises(ConfigError, match=r"improper of entry \[1,1\]"):
        cfg.replace(controller_den=(1.0, -0.5) * 3 + (0.0, 1.0))
