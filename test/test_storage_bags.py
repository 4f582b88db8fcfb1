# SPDX-License-Identifier: Apache-2.0
"""SQLite3 bags and file-compressed bags, written by writers this project did not write.

SQLite3: ``rosbags.rosbag2.Writer`` with SQLite3 storage, rosbag2 format versions 8 and 9;
and the same with the ``message_definitions`` table dropped (the layout of Humble, whose
bags carry no definitions): types from the installed interface packages, or from
``--msg-path``. File compression: rosbag2's layout for ``ros2 bag record
--compression-mode file --compression-format zstd`` (each file zstd-compressed whole as
``<name>.mcap.zstd``, metadata.yaml saying so), made from a bag ``rosbags`` wrote.

The loop is the paper's example (240 Hz, F = 3) simulated by mr_ident: every storage must
give exactly the simulated samples (np.array_equal) and P_h within a median relative error
of 1e-4 of the exact model (as test/test_bags.py).
"""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest
import yaml
from bagmaker import BagWriter, joint_state_bag, paper_loop, plant_error, stamps
from conftest import require_interfaces
from rosbags.rosbag2 import StoragePlugin
from test_bags import R, U, Y

from mr_ident.cli import main
from mr_ident.io.blocks import encode_fields
from mr_ident.io.recording import read_blocks
from mr_ident.live.replay import bag_signals

SPECS = {"r": [R], "u": [U], "y": [Y]}
SQLITE = StoragePlugin.SQLITE3


@pytest.fixture(scope="module")
def loop():
    return paper_loop()


def _exact(model, sim, data) -> None:
    assert data.n_samples == sim.n_samples and data.fs_high == pytest.approx(240.0, rel=1e-9)
    for got, want in ((data.r, sim.r), (data.u, sim.u), (data.y, sim.y)):
        np.testing.assert_array_equal(got, want)
    assert plant_error(model, data) < 1e-4


def _drop_definitions(bag) -> None:
    """Make a bag look like Humble's: no message_definitions table."""
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DROP TABLE message_definitions")


@pytest.mark.parametrize("version", [8, 9])
def test_an_sqlite_bag_gives_the_exact_plant(loop, tmp_path, version):
    model, sim = loop
    bag = joint_state_bag(
        tmp_path / "js", sim, stamps(sim.n_samples, 240.0), storage=SQLITE, version=version
    )
    data, info = bag_signals(bag, SPECS, ratio=3)
    _exact(model, sim, data)
    assert info.messages == {"/joint_states": sim.n_samples, "/ident/reference": sim.n_samples}
    data, _ = bag_signals(next(bag.glob("*.db3")), SPECS, ratio=3)  # the bare file too
    _exact(model, sim, data)


def test_rows_joined_in_sqlite_and_rows_fetched_one_by_one_give_the_same(
    loop, tmp_path, monkeypatch
):
    """The fast path (group_concat, several groups of rows) equals fetching rows."""
    from mr_ident.io import sqlite_bag

    _, sim = loop
    bag = joint_state_bag(tmp_path / "js", sim, stamps(3000, 240.0), storage=SQLITE)
    monkeypatch.setattr(sqlite_bag, "ROWS", 1024)
    fast, _ = bag_signals(bag, SPECS, fs_high=240.0, ratio=3)
    monkeypatch.setattr(sqlite_bag, "AGGREGATE", False)
    rows, _ = bag_signals(bag, SPECS, fs_high=240.0, ratio=3)
    assert fast.n_samples == rows.n_samples == 3000
    for a, b in ((fast.r, rows.r), (fast.u, rows.u), (fast.y, rows.y)):
        np.testing.assert_array_equal(a, b)


def test_an_sqlite_bag_without_definitions_takes_the_installed_types(loop, tmp_path):
    require_interfaces("sensor_msgs/msg/JointState")
    model, sim = loop
    bag = joint_state_bag(tmp_path / "js", sim, stamps(sim.n_samples, 240.0), storage=SQLITE)
    _drop_definitions(bag)
    data, _ = bag_signals(bag, SPECS, ratio=3)
    _exact(model, sim, data)


def _pid_bag(path, sim, **writer):
    t = stamps(sim.n_samples, 240.0)
    with BagWriter(path, **writer) as bw:
        for k in range(sim.n_samples):
            state = {"name": "j1", "reference": sim.r[k, 0], "feedback": sim.y[k, 0]}
            bw.write(
                "/pid/state",
                "control_msgs/msg/MultiDOFStateStamped",
                bw.multi_dof(int(t[k]), [state | {"output": sim.u[k, 0]}]),
                t[k],
            )
    return path


def test_a_type_found_nowhere_is_an_error_naming_it_and_msg_path_reads_it(loop, tmp_path, capsys):
    """control_msgs is not installed and the bag (Humble layout) does not define it."""
    from bagmaker import MULTI_DOF_STATE_STAMPED, SINGLE_DOF_STATE

    require_interfaces("std_msgs/msg/Header")  # control_msgs' types use it
    model, sim = loop
    bag = _pid_bag(tmp_path / "pid", sim, storage=SQLITE)
    _drop_definitions(bag)
    base = '/pid/state.dof_states[:]{name=="j1"}'
    args = ["identify", str(bag), "--ratio", "3", "--out", str(tmp_path / "x.npz")]
    args += ["--r", base + ".reference", "--u", base + ".output", "--y", base + ".feedback"]
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err
    assert "control_msgs/msg/MultiDOFStateStamped" in err and "--msg-path" in err, err
    assert not (tmp_path / "x.npz").exists()
    msgs = tmp_path / "msgs" / "control_msgs" / "msg"
    msgs.mkdir(parents=True)
    (msgs / "SingleDOFState.msg").write_text(SINGLE_DOF_STATE)
    (msgs / "MultiDOFStateStamped.msg").write_text(MULTI_DOF_STATE_STAMPED)
    code = main([*args, "--msg-path", str(tmp_path / "msgs")])
    assert code == 0, capsys.readouterr().err
    z = np.load(tmp_path / "x.npz")
    P = model.plant_discrete().freqresp(z["frequency"])
    assert float(np.median(np.abs(z["P"] - P) / np.abs(P))) < 1e-4


def _compress(bag, *, drop_plain: bool = True) -> None:
    """rosbag2's file compression: every file <name>.zstd, metadata.yaml saying so."""
    import zstandard

    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    names = []
    for rel in info["relative_file_paths"]:
        plain = bag / rel
        with open(plain, "rb") as src, open(bag / f"{rel}.zstd", "wb") as dst:
            zstandard.ZstdCompressor(level=3).copy_stream(src, dst)
        if drop_plain:
            plain.unlink()
        names.append(f"{rel}.zstd")
    info.update(relative_file_paths=names, compression_format="zstd", compression_mode="FILE")
    for f in info.get("files", []):
        f["path"] = f["path"] + ".zstd"
    meta_path.write_text(yaml.safe_dump(meta))


def test_a_file_compressed_bag_is_read_streamed_without_a_copy_on_disk(loop, tmp_path):
    model, sim = loop
    bag = joint_state_bag(tmp_path / "js", sim, stamps(sim.n_samples, 240.0))
    _compress(bag)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    data, info = bag_signals(bag, SPECS, ratio=3)
    _exact(model, sim, data)
    assert not info.truncated
    data, _ = bag_signals(next(bag.glob("*.mcap.zstd")), SPECS, ratio=3)  # the bare file too
    _exact(model, sim, data)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written


def test_a_file_compressed_sqlite_bag_is_read_in_memory(loop, tmp_path):
    model, sim = loop
    bag = joint_state_bag(tmp_path / "js", sim, stamps(sim.n_samples, 240.0), storage=SQLITE)
    _compress(bag)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    data, _ = bag_signals(bag, SPECS, ratio=3)
    _exact(model, sim, data)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written


def test_a_compressed_file_cut_short_reads_what_it_holds(loop, tmp_path):
    """A bare .mcap.zstd (chunks of 16 kB, written by the mcap library) cut in half: the
    samples of its whole records, sample for sample, and a note that it was cut short."""
    import zstandard
    from bagmaker import joint_state_mcap
    from mcap.writer import CompressionType

    _, sim = loop
    plain = joint_state_mcap(
        tmp_path / "x.mcap", sim, stamps(3000, 240.0), chunk_size=16384,
        compression=CompressionType.NONE,
    )  # fmt: skip
    raw = zstandard.ZstdCompressor().compress(plain.read_bytes())  # as rosbag2: one frame
    cut = tmp_path / "cut.mcap.zstd"
    cut.write_bytes(raw[: int(len(raw) * 0.6)])  # zstd blocks of 128 kB: a few decode
    data, info = bag_signals(cut, SPECS, fs_high=240.0, ratio=3)
    assert info.truncated and "what came before is used" in info.reason
    assert data.first == 0 and 500 < data.n_samples < 3000
    np.testing.assert_array_equal(data.y, sim.y[: data.n_samples])


def _block_bag(path, sim, **writer):
    """The block contract (Float64MultiArray on reference/input/output), blocks of 24."""
    with BagWriter(path, **writer) as bw:
        A = bw.ts.types["std_msgs/msg/Float64MultiArray"]
        L = bw.ts.types["std_msgs/msg/MultiArrayLayout"]
        D = bw.ts.types["std_msgs/msg/MultiArrayDimension"]
        for first in range(0, sim.n_samples, 24):
            for topic, x in (("/reference", sim.r), ("/input", sim.u), ("/output", sim.y)):
                dims, offset, data = encode_fields(first, x[first : first + 24])
                msg = A(
                    layout=L(dim=[D(label=a, size=b, stride=c) for a, b, c in dims],
                             data_offset=offset),
                    data=data,
                )  # fmt: skip
                bw.write(topic, "std_msgs/msg/Float64MultiArray", msg, 1000 + first)
    return path


@pytest.mark.parametrize("storage", ["sqlite3", "compressed"])
def test_the_block_contract_reads_the_same_from_every_storage(loop, tmp_path, storage):
    _, sim = loop
    ref = read_blocks(_block_bag(tmp_path / "mcap", sim))
    if storage == "sqlite3":
        bag = _block_bag(tmp_path / "other", sim, storage=SQLITE)
    else:
        bag = _block_bag(tmp_path / "other", sim)
        _compress(bag)
    got = read_blocks(bag)
    assert len(got[0]) == len(ref[0]) == 3 * sim.n_samples // 24
    for (s1, _, b1), (s2, _, b2) in zip(got[0], ref[0], strict=True):
        assert s1 == s2 and b1.first == b2.first
        np.testing.assert_array_equal(b1.samples, b2.samples)
    assert got[2] == ref[2]


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"not a database at all" * 100, "not an SQLite3 bag"),
        (None, "not a rosbag2 SQLite3 bag: expected tables 'topics' and 'messages'"),
    ],
    ids=["garbage", "other-database"],
)
def test_a_db3_that_is_not_a_bag_is_an_error_naming_the_file(tmp_path, capsys, content, match):
    path = tmp_path / "x.db3"
    if content is None:
        with sqlite3.connect(path) as con:
            con.execute("CREATE TABLE t (a INTEGER)")
    else:
        path.write_bytes(content)
    args = ["identify", str(path), "--r", R, "--u", U, "--y", Y, "--ratio", "3"]
    code = main([*args, "--out", str(tmp_path / "o.npz")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"error: {path}") and match in err, err
