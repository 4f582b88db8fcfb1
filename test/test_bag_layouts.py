# SPDX-License-Identifier: Apache-2.0
"""Every MCAP layout the spec allows reads completely, and files cut short read their prefix.

The files are written by the ``mcap`` library's own writer (not by this project) with every
layout option: chunked or not, message indexes and chunk indexes on or off, statistics and
summary offsets on or off, no summary at all. The loop is the paper's example (240 Hz,
F = 3) simulated by mr_ident; every layout must give exactly the samples of the simulation
(np.array_equal) and P_h within a median relative error of 1e-4 of the exact model (the
LPM's bias for a 60 s record is about 1e-6; a sample misplaced by one index gives errors of
order 1).
"""

from __future__ import annotations

import numpy as np
import pytest
from bagmaker import joint_state_bag, joint_state_mcap, paper_loop, plant_error, stamps
from test_bags import R, U, Y

from mr_ident.io import mcap_scan
from mr_ident.io.bags import Bag
from mr_ident.live.replay import bag_signals

SPECS = {"r": [R], "u": [U], "y": [Y]}
LAYOUTS = {
    "chunked, all indexes": {},
    "unchunked": {"use_chunking": False},
    "unchunked, no summary": {
        "use_chunking": False,
        "index_types": "NONE",
        "repeat_channels": False,
        "repeat_schemas": False,
        "use_statistics": False,
        "use_summary_offsets": False,
    },
    "chunked, no chunk index": {"index_types": "MESSAGE"},
    "chunked, no message index": {"index_types": "CHUNK"},
    "chunked, no index at all": {"index_types": "NONE"},
    "chunked, no summary at all": {
        "index_types": "NONE",
        "repeat_channels": False,
        "repeat_schemas": False,
        "use_statistics": False,
        "use_summary_offsets": False,
    },
    "no statistics, no summary offsets": {"use_statistics": False, "use_summary_offsets": False},
    "small lz4 chunks": {"chunk_size": 4096, "compression": "LZ4"},
    "uncompressed chunks, no channels in summary": {
        "compression": "NONE",
        "repeat_channels": False,
        "repeat_schemas": False,
    },
}


def _options(layout: dict) -> dict:
    from mcap.writer import CompressionType, IndexType

    out = dict(layout)
    if "index_types" in out:
        out["index_types"] = IndexType[out["index_types"]]
    if "compression" in out:
        out["compression"] = CompressionType[out["compression"]]
    return out


@pytest.fixture(scope="module")
def loop():
    return paper_loop()


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_gives_every_sample_and_the_exact_plant(loop, tmp_path, layout):
    model, sim = loop
    path = joint_state_mcap(
        tmp_path / "x.mcap", sim, stamps(sim.n_samples, 240.0), **_options(LAYOUTS[layout])
    )
    data, info = bag_signals(path, SPECS, ratio=3)
    assert data.n_samples == sim.n_samples and not info.truncated and not info.broken
    for got, want in ((data.r, sim.r), (data.u, sim.u), (data.y, sim.y)):
        np.testing.assert_array_equal(got, want)
    assert data.fs_high == pytest.approx(240.0, rel=1e-9)
    assert plant_error(model, data) < 1e-4
    assert info.messages == {"/joint_states": sim.n_samples, "/ident/reference": sim.n_samples}


@pytest.mark.parametrize("window", [1000, 5000, 70_000])
@pytest.mark.parametrize("layout", ["chunked, all indexes", "unchunked", "small lz4 chunks"])
def test_the_window_size_does_not_change_what_is_read(loop, tmp_path, monkeypatch, layout, window):
    """Records, chunks and their message indexes cut by the window's edge: same samples."""
    _, sim = loop
    n = 3000
    path = joint_state_mcap(
        tmp_path / "x.mcap", sim, stamps(n, 240.0), **_options(LAYOUTS[layout])
    )
    whole, _ = bag_signals(path, SPECS, fs_high=240.0, ratio=3)
    monkeypatch.setattr(mcap_scan, "WINDOW", window)
    data, _ = bag_signals(path, SPECS, fs_high=240.0, ratio=3)
    np.testing.assert_array_equal(data.y, whole.y)
    np.testing.assert_array_equal(data.u, whole.u)
    assert data.n_samples == n


def test_rosbag2_layout_and_the_mcap_writers_agree_on_topics_and_counts(loop, tmp_path):
    _, sim = loop
    t = stamps(600, 240.0)
    ours = joint_state_mcap(tmp_path / "a.mcap", sim, t, **_options(LAYOUTS["unchunked"]))
    theirs = joint_state_bag(tmp_path / "b", sim, t)
    for path in (ours, theirs):
        bag = Bag.open(path)
        topics = bag.scanned_topics()
        assert {k: (v.type, v.messages) for k, v in topics.items()} == {
            "/joint_states": ("sensor_msgs/msg/JointState", 600),
            "/ident/reference": ("sensor_msgs/msg/JointState", 600),
        }
        assert "float64[] position" in topics["/joint_states"].schema


@pytest.mark.parametrize("layout", ["chunked, all indexes", "unchunked", "small lz4 chunks"])
def test_a_file_cut_short_reads_up_to_its_last_whole_record(loop, tmp_path, layout):
    """Cut at several places: what is read is the start of the recording, sample for sample,
    and the reading says it was cut short (unless only the summary was lost)."""
    _, sim = loop
    n = 3000
    opts = {"chunk_size": 16384} | _options(LAYOUTS[layout])  # several chunks
    path = joint_state_mcap(tmp_path / "x.mcap", sim, stamps(n, 240.0), **opts)
    raw = path.read_bytes()
    got = [0]
    for frac in (0.35, 0.7, 0.97):
        cut = tmp_path / f"cut_{frac}.mcap"
        cut.write_bytes(raw[: int(len(raw) * frac)])
        data, info = bag_signals(cut, SPECS, fs_high=240.0, ratio=3)
        if data.n_samples < n:
            assert info.truncated and "what came before is used" in info.reason
        else:  # cut inside the summary (after the data end record): nothing is missing
            assert frac > 0.9 and not info.truncated
        assert data.first == 0 and got[-1] < data.n_samples  # more kept the later the cut
        got.append(data.n_samples)
        np.testing.assert_array_equal(data.y, sim.y[: data.n_samples])
        np.testing.assert_array_equal(data.r, sim.r[: data.n_samples])


def test_a_damaged_chunk_is_skipped_said_and_the_rest_read(loop, tmp_path):
    """Bytes of one compressed chunk in the middle overwritten: its messages are left out
    (a gap: the longest gap-free span is used), the reading says so and how many are
    missing against the summary's statistics; the samples read are the simulated ones."""
    _, sim = loop
    n = 3000
    path = joint_state_mcap(tmp_path / "x.mcap", sim, stamps(n, 240.0), chunk_size=16384)
    raw = bytearray(path.read_bytes())
    info = mcap_scan.read_summary(open(path, "rb"), len(raw))
    starts = [p for p in mcap_scan.walk(raw, 8, info.data_end)[0] if raw[p] == 0x06]
    mid = starts[len(starts) // 2]
    raw[mid + 200 : mid + 400] = bytes(200)  # inside the zstd data of that chunk
    path.write_bytes(bytes(raw))
    data, rinfo = bag_signals(path, SPECS, fs_high=240.0, ratio=3)
    assert rinfo.truncated and "unreadable chunk at byte" in rinfo.reason
    assert "that its summary counts" in rinfo.reason and "gap" in rinfo.broken
    assert 0 < data.n_samples < n
    np.testing.assert_array_equal(data.y, sim.y[data.first : data.end])


def test_a_record_length_past_the_end_of_the_file_ends_the_reading_there(loop, tmp_path):
    """An unchunked file whose last record's length field is damaged (2**60): what came
    before it is read, no attempt to read 2**60 bytes."""
    _, sim = loop
    path = joint_state_mcap(
        tmp_path / "x.mcap", sim, stamps(600, 240.0), **_options(LAYOUTS["unchunked, no summary"])
    )
    raw = bytearray(path.read_bytes())
    offs, _ = mcap_scan.walk(raw, 8, len(raw))
    last = [p for p in offs if raw[p] == 0x05][-1]
    raw[last + 1 : last + 9] = (1 << 60).to_bytes(8, "little")
    path.write_bytes(bytes(raw))
    data, info = bag_signals(path, SPECS, fs_high=240.0, ratio=3)
    assert info.truncated and data.n_samples >= 594
    np.testing.assert_array_equal(data.y, sim.y[: data.n_samples])


class _Counting(__import__("io").BufferedReader):
    """A file that counts the bytes read from it."""

    bytes = 0

    def read(self, size=-1):
        out = super().read(size)
        self.bytes += len(out)
        return out


def test_chunks_of_other_topics_are_skipped_by_the_chunk_index(loop, tmp_path, monkeypatch):
    """A bag with a large topic nobody reads (a burst of 400 'images' of 4 kB before and
    after the loop): with the chunk index its chunks are not read at all; without it every
    byte is read (the message indexes still spare decompressing them). Same samples."""
    import io

    from mcap.writer import IndexType
    from mcap.writer import Writer as McapWriter

    _, sim = loop
    n, got = 3000, {}
    for name, index in (("indexed", IndexType.ALL), ("walked", IndexType.MESSAGE)):
        path = tmp_path / f"{name}.mcap"
        joint_state_mcap(path, sim, stamps(n, 240.0), chunk_size=16384, index_types=index)
        raw = path.read_bytes()  # re-write with the burst around the loop's messages
        with open(path, "wb") as fh:
            w = McapWriter(fh, chunk_size=16384, index_types=index)
            w.start(profile="ros2", library="test")
            sid = w.register_schema("pkg/msg/Blob", "ros2msg", b"uint8[] data\n")
            cam = w.register_channel("/camera", "cdr", sid)
            noise = np.random.default_rng(1).integers(0, 256, 4000, dtype=np.uint8)
            blob = b"\x00\x01\x00\x00" + noise.tobytes()  # incompressible
            for k in range(400):
                w.add_message(cam, log_time=k, data=blob, publish_time=k)
            from mcap.reader import make_reader

            src = make_reader(io.BytesIO(raw))
            ids = {}
            for schema, channel, msg in src.iter_messages():
                if channel.topic not in ids:
                    s = w.register_schema(schema.name, schema.encoding, schema.data)
                    ids[channel.topic] = w.register_channel(channel.topic, "cdr", s)
                w.add_message(
                    ids[channel.topic], log_time=msg.log_time, data=msg.data,
                    publish_time=msg.publish_time,
                )  # fmt: skip
            for k in range(400):
                w.add_message(cam, log_time=k, data=blob, publish_time=k)
            w.finish()
        data, _ = bag_signals(path, SPECS, fs_high=240.0, ratio=3)
        scanner = Bag.open(path)._parts[0].scanner
        counted = _Counting(io.FileIO(path))
        scanner.opener = lambda: counted  # noqa: B023
        for _ in scanner.messages({"/joint_states", "/ident/reference"}):
            pass
        got[name] = (data, counted.bytes)
    assert got["indexed"][1] < got["walked"][1] / 3  # the /camera chunks: not read
    for data, _ in got.values():
        for x, want in ((data.r, sim.r), (data.u, sim.u), (data.y, sim.y)):
            np.testing.assert_array_equal(x, want[:n])
