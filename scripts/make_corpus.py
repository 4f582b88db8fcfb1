# SPDX-License-Identifier: Apache-2.0
"""Write the bad-input corpus under test/corpus/ (run: .venv/bin/python scripts/make_corpus.py).

Every file breaks the file formats of docs/formats.md in exactly one way; test/test_corpus.py
feeds each to the CLI and expects ``error: <what, where>`` on stderr, exit status 2,
no traceback and no output file. The files are committed; this script is how they
were made (deterministic: a fixed seed, fixed MCAP times), so a change of format
can regenerate them. The MCAP files need rclpy's serializer (the ROS 2 wheels).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "test" / "corpus"
sys.path.insert(0, str(ROOT))

FS, F, N = 240.0, 3, 300  # CSV/NPZ: 300 samples of the paper example's rates
BLOCK, BLOCKS = 120, 12  # MCAP: 12 blocks of 120 samples per topic (6 s at 240 Hz)
CHUNK = 4096  # small MCAP chunks, so a cut lands after some finished chunks


def signals(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.systems.simulate import simulate

    model = load_model(ROOT / "config" / "paper_example.yaml")
    sim = simulate(model, duration=n / FS, rng=np.random.default_rng(7))
    return sim.r[:, 0], sim.u[:, 0], sim.y[:, 0]


def table(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> list[list[str]]:
    t = np.arange(r.size) / FS
    return [[repr(float(v)) for v in row] for row in zip(t, r, u, y, strict=False)]


def write_csv(name: str, rows: list[list[str]], header: str = "t,r,u,y") -> None:
    (OUT / name).write_text(header + "\n" + "".join(",".join(row) + "\n" for row in rows))


def csv_files(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    rows = table(r, u, y)
    bad = [row[:] for row in rows]
    bad[41][0] = "nan"  # t at data row 42 (a NaN of r, u or y is a missing sample, t never)
    write_csv("csv_nan.csv", bad)
    bad = [row[:] for row in rows]
    bad[99][2] = "inf"  # u at data row 100
    write_csv("csv_inf.csv", bad)
    bad = [row[:] for row in rows]
    bad[6][1] = "abc"  # text in r, data row 7
    write_csv("csv_text.csv", bad)
    write_csv("csv_missing_column.csv", [[a, b, d] for a, b, _, d in rows], header="t,r,y")
    bad = [row[:] for row in rows]
    bad[150] = bad[150][:3]  # data row 151 has 3 values
    write_csv("csv_unequal_lengths.csv", bad)
    (OUT / "csv_zero_rows.csv").write_text("")  # an empty file: not even a header
    write_csv("csv_header_only.csv", [])


def npz_files(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    np.savez(
        OUT / "npz_wrong_shape.npz",
        r=r.reshape(-1, 3, 2)[:50],
        u=u[:300],
        y=y[:300],
        fs_high=FS,
        ratio=F,
    )
    np.savez(
        OUT / "npz_empty_arrays.npz",
        r=np.zeros(0),
        u=np.zeros(0),
        y=np.zeros(0),
        fs_high=FS,
        ratio=F,
    )
    np.savez(OUT / "npz_non_integer_ratio.npz", r=r, u=u, y=y, fs_high=FS, ratio=2.5)
    np.savez(OUT / "npz_unequal_lengths.npz", r=r, u=u[:-3], y=y, fs_high=FS, ratio=F)
    np.savez(OUT / "npz_text_array.npz", r=np.array(["a"] * r.size), u=u, y=y, fs_high=FS, ratio=F)


MODEL = """\
fs_high: 240.0
ratio: {ratio}
plant:
  num: [0.5, 3.0, {k}]
  den: [0.25, 13.0, 30910.0, 603000.0, 59700000.0]
controller:
  num: [{kp}, -5400.0]
  den: [1.0, -0.3]
noise_std: 0.0
"""


def model_files() -> None:
    (OUT / "model_non_numeric.yaml").write_text(MODEL.format(ratio=3, k="29850.0x", kp=6000.0))
    (OUT / "model_unstable.yaml").write_text(MODEL.format(ratio=3, k=29850.0, kp=60000.0))
    (OUT / "model_ratio_zero.yaml").write_text(MODEL.format(ratio=0, k=29850.0, kp=6000.0))
    (OUT / "model_unknown_key.yaml").write_text(
        MODEL.format(ratio=3, k=29850.0, kp=6000.0) + "noise_sdt: 0.01\n"
    )
    (OUT / "model_not_yaml.yaml").write_text(
        "fs_high: 240.0\nplant: {num: [1.0, den: [1.0, 2.0]\n"
    )


def mcap_files(r: np.ndarray, u: np.ndarray, y: np.ndarray) -> None:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray, String

    from mr_ident.io.recording import McapRecorder
    from mr_ident.ros.messages import BLOCK_QOS, BLOCK_TYPE, block_msg, qos_dict

    qos = [qos_dict(BLOCK_QOS)]
    sig = {"/reference": r, "/input": u, "/output": y}

    def write(
        name: str,
        order: list[tuple[str, int]],
        types: dict[str, str] | None = None,
        override: dict[tuple[str, int], int] | None = None,
    ) -> Path:
        """Blocks (topic, block number) in this order; override maps one to another first index."""
        path = OUT / name
        types = types or {}
        with McapRecorder(path, chunk_size=CHUNK, library="mr_ident corpus") as rec:
            cids = {
                t: rec.add_topic(t, types.get(t, BLOCK_TYPE), qos)
                for t in dict.fromkeys(t for t, _ in order)
            }
            for i, (topic, b) in enumerate(order):
                if types.get(topic, BLOCK_TYPE) == BLOCK_TYPE:
                    first = (override or {}).get((topic, b), b * BLOCK)
                    data = serialize_message(
                        block_msg(first, sig[topic][b * BLOCK : (b + 1) * BLOCK])
                    )
                else:
                    data = serialize_message(String(data=f"block {b}"))
                t = 1_700_000_000_000_000_000 + i * 10_000_000
                rec.write(cids[topic], data, t, t)
        return path

    assert Float64MultiArray.__name__ == BLOCK_TYPE.rsplit("/", 1)[1]
    order = [(t, b) for b in range(BLOCKS) for t in sig]
    whole = write("_whole.mcap", order).read_bytes()
    (OUT / "_whole.mcap").unlink()
    # Cut at several offsets: inside the magic, inside the header/schemas, inside the
    # first chunk, and after the first finished chunks (too little for one window).
    first_chunk = 8  # walk the records (opcode u8, length u64 LE) to the first Chunk (0x06)
    while whole[first_chunk] != 0x06:
        first_chunk += 9 + int.from_bytes(whole[first_chunk + 1 : first_chunk + 9], "little")
    for name, cut in [
        ("mcap_truncated_magic.mcap", 5),
        ("mcap_truncated_header.mcap", 40),
        ("mcap_truncated_first_chunk.mcap", first_chunk + 200),
        ("mcap_truncated_late.mcap", len(whole) * 2 // 3),
    ]:
        (OUT / name).write_bytes(whole[:cut])
    write("mcap_wrong_schema.mcap", order, types={"/reference": "std_msgs/msg/String"})
    # The reference stream's index goes back every other block, with other samples there.
    write(
        "mcap_non_monotonic.mcap",
        order,
        override={("/reference", b): (b - 1) * BLOCK + 7 for b in range(2, BLOCKS, 2)},
    )
    write("mcap_missing_topic.mcap", [(t, b) for t, b in order if t != "/output"])
    (OUT / "mcap_not_mcap.mcap").write_text("t,r,u,y\n0,1,2,3\n")


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    r, u, y = signals(BLOCK * BLOCKS)
    csv_files(r[:N], u[:N], y[:N])
    npz_files(r[:N], u[:N], y[:N])
    model_files()
    mcap_files(r, u, y)
    for p in sorted(OUT.iterdir()):
        print(f"{p.stat().st_size:8d}  {p.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
