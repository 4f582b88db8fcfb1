# SPDX-License-Identifier: Apache-2.0
"""Bags this project did not write: rosbag2 bags made with the independent ``rosbags`` library.

The loop is simulated by mr_ident (the exact truth is known); serialisation, the bag
layout (metadata.yaml + .mcap, split files) and the message types come from ``rosbags``:
installed common_interfaces types from its Jazzy typestore, ``control_msgs`` and
``pal_statistics_msgs`` registered from their ``.msg`` text (no package installed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

rosbags = __import__("pytest").importorskip("rosbags")
from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

T0 = 1_700_000_000_000_000_000  # ns: the first stamp

SINGLE_DOF_STATE = """string name
float64 reference
float64 feedback
float64 feedback_dot
float64 error
float64 error_dot
float64 time_step
float64 output
"""
MULTI_DOF_STATE_STAMPED = "std_msgs/Header header\nSingleDOFState[] dof_states\n"
STATISTICS_NAMES = "Header header\nstring[] names\nuint32 names_version\n"
STATISTICS_VALUES = "Header header\nfloat64[] values\nuint32 names_version\n"


def typestore():
    """Jazzy's types plus control_msgs' and pal_statistics_msgs' from their .msg text."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    types.update(get_types_from_msg(SINGLE_DOF_STATE, "control_msgs/msg/SingleDOFState"))
    types.update(
        get_types_from_msg(MULTI_DOF_STATE_STAMPED, "control_msgs/msg/MultiDOFStateStamped")
    )
    types.update(get_types_from_msg(STATISTICS_NAMES, "pal_statistics_msgs/msg/StatisticsNames"))
    types.update(get_types_from_msg(STATISTICS_VALUES, "pal_statistics_msgs/msg/StatisticsValues"))
    ts.register(types)
    return ts


def stamps(
    n: int, fs: float, rng: np.random.Generator | None = None, jitter: float = 0.0
) -> np.ndarray:
    """Stamps (ns) of n samples at fs, with uniform jitter of +-``jitter`` sample times."""
    t = T0 + np.rint(np.arange(n) * 1e9 / fs).astype(np.int64)
    if rng is not None and jitter:
        t = t + np.rint(rng.uniform(-jitter, jitter, n) * 1e9 / fs).astype(np.int64)
    return t


class BagWriter:
    """A rosbag2 bag written with rosbags (MCAP storage unless ``storage`` says otherwise,
    format version ``version``); messages built from dicts."""

    def __init__(self, path: Path, ts=None, *, storage=StoragePlugin.MCAP, version: int = 9):
        self.ts = ts or typestore()
        self.w = Writer(path, version=version, storage_plugin=storage)
        self.conns: dict[str, object] = {}

    def __enter__(self):
        self.w.open()
        return self

    def __exit__(self, *exc):
        self.w.close()

    def write(self, topic: str, msgtype: str, msg, log_ns: int) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.w.add_connection(topic, msgtype, typestore=self.ts)
        self.w.write(self.conns[topic], int(log_ns), self.ts.serialize_cdr(msg, msgtype))

    # -- message builders -----------------------------------------------------------------
    def header(self, t: int, frame: str = ""):
        H = self.ts.types["std_msgs/msg/Header"]
        T = self.ts.types["builtin_interfaces/msg/Time"]
        return H(
            stamp=T(sec=int(t // 1_000_000_000), nanosec=int(t % 1_000_000_000)), frame_id=frame
        )

    def joint_state(self, t: int, names, position=(), velocity=(), effort=()):
        JS = self.ts.types["sensor_msgs/msg/JointState"]
        f = np.asarray
        return JS(
            header=self.header(t),
            name=list(names),
            position=f(position, float),
            velocity=f(velocity, float),
            effort=f(effort, float),
        )

    def float64(self, value: float):
        return self.ts.types["std_msgs/msg/Float64"](data=float(value))

    def multi_dof(self, t: int, states: list[dict]):
        S = self.ts.types["control_msgs/msg/SingleDOFState"]
        M = self.ts.types["control_msgs/msg/MultiDOFStateStamped"]
        full = [
            S(
                **(
                    {
                        "name": "",
                        "reference": 0.0,
                        "feedback": 0.0,
                        "feedback_dot": 0.0,
                        "error": 0.0,
                        "error_dot": 0.0,
                        "time_step": 0.0,
                        "output": 0.0,
                    }
                    | s
                )
            )
            for s in states
        ]
        return M(header=self.header(t), dof_states=full)

    def block(self, first: int, x):
        """A block-contract message (std_msgs/Float64MultiArray) of samples ``x`` (n, c)."""
        from mr_ident.io.blocks import encode_fields

        A = self.ts.types["std_msgs/msg/Float64MultiArray"]
        L = self.ts.types["std_msgs/msg/MultiArrayLayout"]
        D = self.ts.types["std_msgs/msg/MultiArrayDimension"]
        dims, offset, data = encode_fields(first, x)
        return A(
            layout=L(dim=[D(label=a, size=b, stride=c) for a, b, c in dims], data_offset=offset),
            data=data,
        )

    def stats_names(self, t: int, names, version: int):
        N = self.ts.types["pal_statistics_msgs/msg/StatisticsNames"]
        return N(header=self.header(t), names=list(names), names_version=version)

    def stats_values(self, t: int, values, version: int):
        V = self.ts.types["pal_statistics_msgs/msg/StatisticsValues"]
        return V(header=self.header(t), values=np.asarray(values, float), names_version=version)


def joint_state_messages(bw, sim, t, *, skip=(), names=("j0", "j1"), drop=()):
    """``(topic, type, message, log_ns)`` of a simulated SISO loop as ros2_control publishes
    it: y and u in /joint_states (joint j1, beside a constant j0), r in /ident/reference;
    stamps ``t`` (ns), samples in ``skip`` dropped, received 0.3 ms after their stamp;
    samples in ``drop``: their /joint_states message only dropped (r kept)."""
    js = "sensor_msgs/msg/JointState"
    for k in range(t.size):
        if k in skip:
            continue
        tk = int(t[k])
        pos, eff = [0.5, sim.y[k, 0]], [0.0, sim.u[k, 0]]
        if k not in drop:
            yield (
                "/joint_states",
                js,
                bw.joint_state(tk, names, position=pos, effort=eff),
                tk + 300_000,
            )
        yield (
            "/ident/reference",
            js,
            bw.joint_state(tk, ["j1"], position=[sim.r[k, 0]]),
            tk + 300_000,
        )


def joint_state_bag(path, sim, t, *, skip=(), names=("j0", "j1"), drop=(), **writer):
    """:func:`joint_state_messages` as a rosbag2 bag (``writer``: :class:`BagWriter`'s
    storage and version)."""
    with BagWriter(path, **writer) as bw:
        msgs = joint_state_messages(bw, sim, t, skip=skip, names=names, drop=drop)
        for topic, type_, msg, log in msgs:
            bw.write(topic, type_, msg, log)
    return path


def joint_state_mcap(path, sim, t, *, skip=(), **options):
    """:func:`joint_state_messages` as one MCAP file written by the ``mcap`` library's own
    writer with ``options`` (use_chunking, index_types, use_statistics, ...); the schemas are
    rosbags' ``ros2msg`` text, the payloads rosbags' CDR, publish time = log time."""
    from mcap.writer import Writer as McapWriter

    bw = BagWriter.__new__(BagWriter)
    bw.ts = typestore()
    schemas, channels = {}, {}
    with open(path, "wb") as fh:
        w = McapWriter(fh, **options)
        w.start(profile="ros2", library="mcap python")
        for seq, (topic, type_, msg, log) in enumerate(
            joint_state_messages(bw, sim, t, skip=skip)
        ):
            if type_ not in schemas:
                text, _ = bw.ts.generate_msgdef(type_, ros_version=2)
                schemas[type_] = w.register_schema(type_, "ros2msg", text.encode())
            if topic not in channels:
                channels[topic] = w.register_channel(topic, "cdr", schemas[type_])
            data = bytes(bw.ts.serialize_cdr(msg, type_))
            w.add_message(channels[topic], log_time=log, data=data, publish_time=log, sequence=seq)
        w.finish()
    return path


def paper_loop():
    """The paper's loop simulated for 60 s (seed 0): (model, LoopData), the bags' content."""
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.systems.simulate import simulate

    model = load_model(Path(__file__).resolve().parents[1] / "config" / "paper_example.yaml")
    return model, simulate(model, duration=60.0, rng=np.random.default_rng(0))


def plant_error(model, data) -> float:
    """Median relative error of the default identification of ``data`` against the model."""
    from mr_ident.numerics.identify import identify

    res = identify(data.r, data.u, data.y, fs_high=data.fs_high, ratio=data.ratio)
    P = model.plant_discrete().freqresp(res.plant.frequency)
    return float(np.median(np.abs(res.plant.response - P) / np.abs(P)))
