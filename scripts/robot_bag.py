# SPDX-License-Identifier: Apache-2.0
"""Write a simulated loop as a robot's rosbag2 bag (run: .venv/bin/python scripts/robot_bag.py).

The tutorial's data (docs/tutorial.md): a data file of ``mr-ident simulate`` (r, u, y at
fs_high) becomes the bag a ros2_control robot would leave after ``ros2 bag record -s mcap
/joint_states /ident/reference``: ``sensor_msgs/JointState`` on ``/joint_states`` every
high-rate cycle (joint ``j1``: y in ``position``, u in ``effort``; beside it a joint ``j0``
standing still) and the excitation r as the ``position`` of ``j1`` on ``/ident/reference``.
Stamps lie on the fs_high grid from a fixed origin, each message received 0.3 ms after its
stamp. Deterministic: the same data file gives the same bag. The serialisation and the bag's
layout (metadata.yaml and one MCAP file) are the independent ``rosbags`` library's.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

T0 = 1_767_225_600_000_000_000  # ns: the first stamp (2026-01-01 00:00 UTC)
DELAY = 300_000  # ns between a stamp and the message's receipt
JOINT_STATE = "sensor_msgs/msg/JointState"


def write_bag(data: Path, out: Path) -> int:
    """Write the bag ``out`` (a directory, which must not exist) from the NPZ ``data``;
    returns the number of messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    with np.load(data) as z:
        r, u, y = (np.asarray(z[k], float).reshape(len(z[k]), -1)[:, 0] for k in "ruy")
        fs = float(z["fs_high"])
    if not r.size == u.size == y.size:
        raise ValueError(
            f"data: r, u and y must have one length, got {r.size}, {u.size}, {y.size}"
        )
    ts = get_typestore(Stores.ROS2_JAZZY)
    state = ts.types[JOINT_STATE]
    header, stamp = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    stamps = T0 + np.rint(np.arange(r.size) * 1e9 / fs).astype(np.int64)

    def message(t: int, names: list[str], position: list[float], effort: list[float]):
        head = header(stamp=stamp(sec=t // 10**9, nanosec=t % 10**9), frame_id="")
        return state(
            header=head,
            name=names,
            position=np.asarray(position, float),
            velocity=np.zeros(0),
            effort=np.asarray(effort, float),
        )

    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        joints = w.add_connection("/joint_states", JOINT_STATE, typestore=ts)
        reference = w.add_connection("/ident/reference", JOINT_STATE, typestore=ts)
        for k in range(r.size):
            t = int(stamps[k])
            js = message(t, ["j0", "j1"], [0.5, y[k]], [0.0, u[k]])
            w.write(joints, t + DELAY, ts.serialize_cdr(js, JOINT_STATE))
            ref = message(t, ["j1"], [r[k]], [])
            w.write(reference, t + DELAY, ts.serialize_cdr(ref, JOINT_STATE))
    return 2 * r.size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="an NPZ of mr-ident simulate")
    parser.add_argument("out", type=Path, help="the bag directory to write (must not exist)")
    args = parser.parse_args(argv)
    if args.out.exists():
        print(
            f"error: {args.out} exists; the bag is written into a new directory", file=sys.stderr
        )
        return 2
    n = write_bag(args.data, args.out)
    print(f"wrote {args.out}: {n} messages on /joint_states and /ident/reference")
    return 0


if __name__ == "__main__":
    sys.exit(main())
