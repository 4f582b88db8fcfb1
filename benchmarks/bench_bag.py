# SPDX-License-Identifier: Apache-2.0
"""Bag decoding speed: ours beside rosbags and mcap_ros2, on a bag none of them wrote for us.

    make bench-bag        # .venv/bin/python benchmarks/bench_bag.py [--hours 1] [--rate 1000]

The bag: a rosbag2 directory (MCAP storage) written by the ``rosbags`` library, one hour
at 1 kHz of ``sensor_msgs/JointState`` on two topics (``/joint_states``: two joints,
position and effort; ``/ident/reference``: one joint), 7.2 M messages. Each topic's
payloads are rosbags' serialization of one message with the stamp and the values changed
in place (serializing 7.2 M messages one by one would take rosbags about an hour); the
bag is kept in ``out/bench_bag`` and reused.

Measured in one run:

* ours: :func:`mr_ident.io.sources.extract` of the three sources r, u, y (every message
  of both topics: stamps and values), messages per second; then the whole
  ``mr-ident identify`` of the bag as a process;
* rosbags: ``AnyReader`` + ``deserialize_cdr`` (and taking the value), on the first
  200 000 messages;
* mcap_ros2: ``read_ros2_messages`` on the first 200 000 messages;
* ours on a bag whose layout changes message to message (joint order and frame_id
  alternate; 400 000 messages);
* ours on the same messages in rosbag2's SQLite3 storage (written by ``rosbags``) and as a
  file-compressed bag (the MCAP bag's file zstd-compressed whole, as ``ros2 bag record
  --compression-mode file`` leaves it; read as a stream); rosbags on the SQLite3 bag.
"""

from __future__ import annotations

import argparse
import itertools
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))
SOURCES = {
    "r": ['/ident/reference.position{name=="j1"}'],
    "u": ['/joint_states.effort{name=="j1"}'],
    "y": ['/joint_states.position{name=="j1"}'],
}
SAMPLE = 200_000


def _patched(
    template: bytes, n: int, stamps: np.ndarray, offsets: dict[int, np.ndarray]
) -> list[bytes]:
    """``n`` copies of a serialized JointState, header.stamp and float64s at ``offsets`` set."""
    buf = np.tile(np.frombuffer(template, np.uint8), (n, 1))
    sec = (stamps // 1_000_000_000).astype("<i4")
    nsec = (stamps % 1_000_000_000).astype("<u4")
    buf[:, 4:8] = sec.view(np.uint8).reshape(n, 4)
    buf[:, 8:12] = nsec.view(np.uint8).reshape(n, 4)
    for off, values in offsets.items():
        buf[:, off : off + 8] = values.astype("<f8").view(np.uint8).reshape(n, 8)
    return [row.tobytes() for row in buf]


def _offset_of(template: bytes, value: float) -> int:
    pos = template.find(np.float64(value).tobytes())
    assert pos >= 0, value
    return pos


def make_bag(path: Path, seconds: float, rate: float, storage: str = "mcap") -> int:
    from bagmaker import T0, BagWriter
    from rosbags.rosbag2 import StoragePlugin

    n = int(seconds * rate)
    rng = np.random.default_rng(0)
    t = T0 + np.rint(np.arange(n) * 1e9 / rate).astype(np.int64)
    with BagWriter(path, storage=StoragePlugin[storage.upper()]) as bw:
        js = bw.ts.serialize_cdr(
            bw.joint_state(T0, ["j0", "j1"], position=[1.25, 2.5], effort=[3.75, 4.125]),
            "sensor_msgs/msg/JointState",
        ).tobytes()
        ref = bw.ts.serialize_cdr(
            bw.joint_state(T0, ["j1"], position=[5.5]), "sensor_msgs/msg/JointState"
        ).tobytes()
        for topic in ("/joint_states", "/ident/reference"):
            bw.conns[topic] = bw.w.add_connection(
                topic, "sensor_msgs/msg/JointState", typestore=bw.ts
            )
        block = 100_000
        for a in range(0, n, block):
            m = min(block, n - a)
            y, u, r = (rng.standard_normal(m) for _ in range(3))
            pj = _patched(
                js,
                m,
                t[a : a + m],
                {
                    _offset_of(js, 2.5): y,
                    _offset_of(js, 4.125): u,
                    _offset_of(js, 1.25): np.zeros(m),
                    _offset_of(js, 3.75): np.zeros(m),
                },
            )
            pr = _patched(ref, m, t[a : a + m], {_offset_of(ref, 5.5): r})
            for k in range(m):
                bw.w.write(bw.conns["/joint_states"], int(t[a + k]) + 200_000, pj[k])
                bw.w.write(bw.conns["/ident/reference"], int(t[a + k]) + 200_000, pr[k])
    return 2 * n


def make_changing_bag(path: Path, n: int) -> int:
    from bagmaker import T0, BagWriter, stamps

    t = stamps(n, 1000.0)
    rng = np.random.default_rng(1)
    with BagWriter(path) as bw:
        for k in range(n):
            names = ["j0", "j1"] if k % 2 else ["j1", "j0"]
            v = rng.standard_normal(3)
            pos = [v[0], v[1]] if k % 2 else [v[1], v[0]]
            msg = bw.joint_state(int(t[k]), names, position=pos, effort=[v[2], v[2]])
            msg.header.frame_id = "base" if k % 3 else "world_frame"
            bw.write("/joint_states", "sensor_msgs/msg/JointState", msg, t[k])
            bw.write(
                "/ident/reference",
                "sensor_msgs/msg/JointState",
                bw.joint_state(int(t[k]), ["j1"], position=[v[0]]),
                t[k],
            )
    assert T0
    return 2 * n


def compress(plain: Path, out: Path) -> None:
    """rosbag2's file compression of a bag: each file zstd-compressed whole (``.zstd``)."""
    import yaml
    import zstandard

    out.mkdir(parents=True)
    meta = yaml.safe_load((plain / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    names = []
    for rel in info["relative_file_paths"]:
        with open(plain / rel, "rb") as src, open(out / f"{rel}.zstd", "wb") as dst:
            zstandard.ZstdCompressor(level=3).copy_stream(src, dst)
        names.append(f"{rel}.zstd")
    info.update(relative_file_paths=names, compression_format="zstd", compression_mode="FILE")
    (out / "metadata.yaml").write_text(yaml.safe_dump(meta))


def size_gb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.iterdir()) / 1e9


def ours(path: Path) -> tuple[float, int]:
    from mr_ident.io.bags import Bag
    from mr_ident.io.sources import bag_types, extract
    from mr_ident.live.replay import resolve_sources  # (imported before the clock starts)

    t0 = time.perf_counter()
    bag = Bag.open(path)
    sources = resolve_sources(bag_types(bag), SOURCES)
    out = extract(bag, [s for _, _, s in sources.all])
    dt = time.perf_counter() - t0
    return dt, out[0].stamps.size + out[1].stamps.size  # messages of the two topics


def rosbags_rate(path: Path) -> float:
    from rosbags.highlevel import AnyReader

    t0 = time.perf_counter()
    with AnyReader([path]) as reader:
        got = 0
        for conn, _, raw in itertools.islice(reader.messages(), SAMPLE):
            msg = reader.deserialize(raw, conn.msgtype)
            _ = msg.position[-1]
            got += 1
    return got / (time.perf_counter() - t0)


def mcap_ros2_rate(path: Path) -> float:
    from mcap_ros2.reader import read_ros2_messages

    file = next(path.glob("*.mcap"))
    t0 = time.perf_counter()
    got = 0
    for m in itertools.islice(read_ros2_messages(str(file)), SAMPLE):
        _ = m.ros_msg.position[-1]
        got += 1
    return got / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--out-dir", type=Path, default=ROOT / "out" / "bench_bag")
    args = ap.parse_args()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    big = args.out_dir / f"js_{args.hours:g}h_{args.rate:g}Hz"
    if not (big / "metadata.yaml").exists():
        t0 = time.perf_counter()
        n = make_bag(big, args.hours * 3600, args.rate)
        print(
            f"wrote {big} ({n} messages, "
            f"{sum(f.stat().st_size for f in big.iterdir()) / 1e9:.2f} GB) "
            f"with rosbags in {time.perf_counter() - t0:.0f} s"
        )
    sqlite = args.out_dir / f"js_{args.hours:g}h_{args.rate:g}Hz_sqlite3"
    if not (sqlite / "metadata.yaml").exists():
        t0 = time.perf_counter()
        n = make_bag(sqlite, args.hours * 3600, args.rate, storage="sqlite3")
        print(f"wrote {sqlite} ({n} messages) with rosbags in {time.perf_counter() - t0:.0f} s")
    zstd = args.out_dir / f"js_{args.hours:g}h_{args.rate:g}Hz_zstd"
    if not (zstd / "metadata.yaml").exists():
        compress(big, zstd)
    small = args.out_dir / "changing_layout"
    if not (small / "metadata.yaml").exists():
        make_changing_bag(small, 200_000)
    dt, n = ours(big)
    print(f"bag: {big.name}, {n} messages (JointState, fixed layout), {size_gb(big):.2f} GB")
    print(
        f"  ours        {n / dt / 1e6:7.2f} M messages/s   ({dt:.1f} s for every message: "
        "stamps and values "
        f"of r, u, y)"
    )
    rb = rosbags_rate(big)
    print(
        f"  rosbags     {rb / 1e6:7.3f} M messages/s   (AnyReader + deserialize, first {SAMPLE} "
        "messages)"
    )
    mc = mcap_ros2_rate(big)
    print(
        f"  mcap_ros2   {mc / 1e6:7.3f} M messages/s   (read_ros2_messages, first {SAMPLE} "
        "messages)"
    )
    print(f"  ours / rosbags = {n / dt / rb:.0f} x, ours / mcap_ros2 = {n / dt / mc:.0f} x")
    for kind, bag in (("sqlite3", sqlite), ("mcap.zstd", zstd)):
        dt3, n3 = ours(bag)
        print(f"bag: {bag.name}, {n3} messages ({kind}: the same messages), {size_gb(bag):.2f} GB")
        print(
            f"  ours        {n3 / dt3 / 1e6:7.2f} M messages/s   ({dt3:.1f} s for every message)"
        )
        if kind == "sqlite3":
            rs = rosbags_rate(bag)
            print(
                f"  rosbags     {rs / 1e6:7.3f} M messages/s   (AnyReader + deserialize, first "
                f"{SAMPLE} messages)"
            )
    dt2, n2 = ours(small)
    print(f"bag: {small.name}, {n2} messages (joint order and frame_id change message to message)")
    print(f"  ours        {n2 / dt2 / 1e6:7.2f} M messages/s")
    t0 = time.perf_counter()
    cmd = [
        sys.executable,
        "-m",
        "mr_ident.cli",
        "identify",
        str(big),
        "--ratio",
        "3",
        *[x for sig in "ruy" for x in (f"--{sig}", SOURCES[sig][0])],
        "--out",
        str(args.out_dir / "id.npz"),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    tail = ": " + proc.stderr.strip().splitlines()[-1] if proc.returncode else ""
    print(
        f"mr-ident identify of the whole bag as a process: {time.perf_counter() - t0:.1f} s "
        f"(exit {proc.returncode}{tail})"
    )


if __name__ == "__main__":
    main()
