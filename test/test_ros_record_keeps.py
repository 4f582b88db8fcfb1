# SPDX-License-Identifier: Apache-2.0
"""The node's recording never destroys one: an existing file is never truncated, every
start is a new file, ``record_path`` names what is being recorded, and a killed node's
file keeps all but its last few seconds (a chunk is bounded in time).

Own domain, localhost only, every wait bounded (test/rosgraph.py).
"""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("mr_ident_msgs", reason="mr_ident_msgs is not built (make venv builds it)")
from rclpy.lifecycle import TransitionCallbackReturn  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph import (  # noqa: E402
    PAPER,
    Feed,
    await_subscribers,
    child,  # noqa: E402
    fast_params,
    publishers,
    wait_for,
)
from rosgraph import graph as graph  # noqa: E402  (the fixture)
from std_srvs.srv import Trigger  # noqa: E402

from mr_ident.io.modelfile import load_model  # noqa: E402
from mr_ident.ros.recorder import CHUNK_S  # noqa: E402
from mr_ident_msgs.srv import Record  # noqa: E402


def messages(path: Path) -> int:
    """Messages of an MCAP file read as it is, every record up to where it was cut."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    n = 0
    with path.open("rb") as fh:
        try:
            for record in StreamReader(fh).records:
                n += isinstance(record, Message)
        except Exception:  # the end of the file: cut inside a record
            pass
    return n


def finalised(path: Path) -> int:
    """Messages of a finalised MCAP file (its summary)."""
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None, f"{path} has no summary"
    return summary.statistics.message_count


def call(graph, kind, name: str, **fields):
    n = graph.node(f"caller_{name}_{time.monotonic_ns()}")
    cli = n.create_client(kind, f"/mr_ident/{name}")
    assert cli.wait_for_service(timeout_sec=10), name
    future = cli.call_async(kind.Request(**fields))
    wait_for(future.done, 20, f"the response of {name}")
    return future.result()


def test_an_existing_file_is_never_truncated_and_every_start_is_a_new_file(graph, tmp_path):
    """record_path naming an existing file: a new name beside it, said in record_path and
    the log; deactivate + activate, start_recording('') and start_recording(path) each a new
    file; stop_recording empties record_path; nothing written before is touched."""
    rec = tmp_path / "run.mcap"
    rec.write_bytes(b"an earlier recording")
    node = graph.ident(fast_params(window_s=5.0, record_path=str(rec)))
    feed = Feed(publishers(graph), load_model(PAPER), seed=3, block=240)
    await_subscribers(feed.pubs)

    def record_path() -> str:
        return node.get_parameter("record_path").value

    def written(path: Path) -> None:
        """Blocks sent until the open file holds them (the recording runs)."""
        sent = len(feed.send(2))
        wait_for(lambda: node.recording._rec.messages >= 3 * sent, 10, f"blocks in {path}")

    first = tmp_path / "run_1.mcap"
    assert record_path() == str(first) and node.recording.path == first
    written(first)
    assert node.trigger_deactivate() == TransitionCallbackReturn.SUCCESS
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    second = tmp_path / "run_2.mcap"
    assert record_path() == str(second) and finalised(first) > 0
    written(second)

    res = call(graph, Record, "start_recording", path="")
    third = tmp_path / "run_3.mcap"
    assert res.success and res.path == str(third) and "never overwritten" in res.message
    assert record_path() == str(third) and finalised(second) > 0
    written(third)

    res = call(graph, Trigger, "stop_recording")
    assert res.success and str(third) in res.message
    assert record_path() == "" and node.recording.path is None and finalised(third) > 0
    res = call(graph, Record, "start_recording", path="")  # after the last one
    assert res.success and res.path == str(tmp_path / "run_4.mcap")
    res = call(graph, Record, "start_recording", path=str(rec))
    assert res.success and res.path == str(tmp_path / "run_5.mcap")
    other = tmp_path / "other.mcap"
    assert node.set_parameters([Parameter("record_path", value=str(other))])[0].successful
    assert node.recording.path == other and record_path() == str(other)
    written(other)
    assert rec.read_bytes() == b"an earlier recording"
    for path in (first, second, third):
        assert finalised(path) > 0


def test_a_killed_node_keeps_all_but_the_last_seconds_of_its_recording(graph, tmp_path):
    """mr-ident-node records ~10 s of blocks (10 a second), then SIGKILL: the file holds every
    message sent more than CHUNK_S before the kill (+2 s for delivery on a loaded machine)."""
    rec = tmp_path / "killed.mcap"
    args = ("--ros-args", "-p", "autostart:=true", "-p", f"record_path:={rec}")
    with child(
        graph, "mr-ident-node", *args, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT
    ) as proc:
        feed = Feed(publishers(graph), load_model(PAPER), seed=3, block=24)
        await_subscribers(feed.pubs, 30)
        times = []
        t_end = time.monotonic() + 10.0
        while time.monotonic() < t_end:
            feed.send(1, pause=0.0)
            times.append(time.monotonic())
            time.sleep(0.1)
        killed = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    due = sum(1 for t in times if t < killed - CHUNK_S - 2.0)
    kept = messages(rec)
    assert due >= 20, due  # the check means something: most of the 10 s were due
    assert kept >= 3 * due, (kept, 3 * due, 3 * len(times))
