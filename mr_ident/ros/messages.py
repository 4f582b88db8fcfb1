# SPDX-License-Identifier: Apache-2.0
"""Float64MultiArray <-> blocks and estimates; the QoS profiles of the topic contract."""

from __future__ import annotations

import array
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..io.blocks import BLOCK_TYPE, Block, BlockError, decode_block, encode_fields

__all__ = [
    "BLOCK_TYPE",
    "BLOCK_QOS",
    "RESULT_QOS",
    "block_msg",
    "block_of",
    "decode_raw",
    "frf_msgs",
    "qos_dict",
    "subscription_qos",
    "vector_msg",
]

#: Sample blocks: reliable, volatile, deep enough for ~1 s of 1000-sample blocks at 1 MS/s.
BLOCK_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: Estimates: the latest one reaches a late subscriber.
RESULT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def multiarray(
    dims: Sequence[tuple[str, int, int]], data: NDArray, data_offset: int = 0
) -> Float64MultiArray:
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label=lab, size=int(size), stride=int(stride))
        for lab, size, stride in dims
    ]
    msg.layout.data_offset = int(data_offset)
    # array.array from bytes: far cheaper than assigning a numpy array (docs/benchmarks.md)
    msg.data = array.array("d", np.ascontiguousarray(data, dtype=np.float64).tobytes())
    return msg


def block_msg(first: int, samples: NDArray) -> Float64MultiArray:
    """The message of one block of samples (n, channels) starting at index ``first``."""
    dims, offset, data = encode_fields(first, samples)
    return multiarray(dims, data, offset)


def block_of(msg: Float64MultiArray) -> Block:
    """Decode a block message; raises :class:`~mr_ident.io.blocks.BlockError`."""
    dims = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    return decode_block(dims, msg.layout.data_offset, np.frombuffer(msg.data, dtype=np.float64))


def decode_raw(raw: bytes) -> Block | BlockError:
    """A block from the CDR bytes of a block message.

    Or the BlockError saying why not (undecodable bytes are "malformed"): never raises, so
    no message can stop an executor.
    """
    from rclpy.serialization import deserialize_message

    try:
        return block_of(deserialize_message(raw, Float64MultiArray))
    except BlockError as err:
        return err
    except Exception as err:  # noqa: BLE001 - undecodable bytes
        return BlockError("malformed", f"undecodable message: {err}")


def frf_msgs(frequency: NDArray, response: NDArray, std: NDArray) -> tuple[Float64MultiArray, ...]:
    """(frequencies, plant_frf, plant_frf_std) for K bins of an (K, n_out, n_in) FRF.

    plant_frf dims: output x input x part[re, im] x frequency (frequency innermost);
    plant_frf_std: output x input x frequency.
    """
    K, ny, nu = response.shape
    f = multiarray([("frequency", K, 1)], frequency)
    parts = np.stack([response.real, response.imag], axis=0)  # (2, K, ny, nu)
    P = np.transpose(parts, (2, 3, 0, 1))  # (ny, nu, 2, K)
    p = multiarray(
        [
            ("output", ny, ny * nu * 2 * K),
            ("input", nu, nu * 2 * K),
            ("part", 2, 2 * K),
            ("frequency", K, K),
        ],
        P,
    )
    s = multiarray(
        [("output", ny, ny * nu * K), ("input", nu, nu * K), ("frequency", K, K)],
        np.transpose(std, (1, 2, 0)),
    )
    return f, p, s


def vector_msg(values: NDArray, label: str = "frequency") -> Float64MultiArray:
    """A 1-D Float64MultiArray labelled ``label``."""
    return multiarray([(label, len(values), 1)], values)


def subscription_qos(infos: Sequence[Any], depth: int = 1000) -> QoSProfile:
    """A QoS that matches every publisher of a topic (their ``get_publishers_info_by_topic``).

    Reliable only if all are, transient local only if all are; ``depth`` deep.
    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE
        if all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in infos)
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
        else DurabilityPolicy.VOLATILE,
    )


def qos_dict(q: QoSProfile) -> dict[str, Any]:
    """A QoS profile as rosbag2 Jazzy's ``offered_qos_profiles`` entry."""

    def dur(d: Duration) -> dict[str, int]:
        sec, nsec = divmod(int(d.nanoseconds), 1_000_000_000)
        return {"sec": sec, "nsec": nsec}

    return {
        "history": q.history.name.lower(),
        "depth": int(q.depth),
        "reliability": q.reliability.name.lower(),
        "durability": q.durability.name.lower(),
        "deadline": dur(q.deadline),
        "lifespan": dur(q.lifespan),
        "liveliness": q.liveliness.name.lower(),
        "liveliness_lease_duration": dur(q.liveliness_lease_duration),
        "avoid_ros_namespace_conventions": bool(q.avoid_ros_namespace_conventions),
    }


def frf_of(msg: Float64MultiArray) -> NDArray[np.complex128]:
    """The (K, n_out, n_in) FRF of a ``plant_frf`` message (inverse of :func:`frf_msgs`)."""
    d = [x.size for x in msg.layout.dim]
    P = np.frombuffer(msg.data, dtype=float).reshape(d)  # out x in x part x freq
    return np.transpose(P[:, :, 0] + 1j * P[:, :, 1], (2, 0, 1))


def std_of(msg: Float64MultiArray) -> NDArray[np.float64]:
    """The (K, n_out, n_in) std of a ``plant_frf_std`` message."""
    d = [x.size for x in msg.layout.dim]
    return np.transpose(np.frombuffer(msg.data, dtype=float).reshape(d), (2, 0, 1))


def status_values(status: Any) -> dict[str, str]:
    """A DiagnosticStatus as key -> value, with its ``level`` and ``message``."""
    values = {kv.key: kv.value for kv in status.values}
    level = status.level
    values["level"] = str(int.from_bytes(level, "little") if isinstance(level, bytes) else level)
    values["message"] = status.message
    return values


#: The plotting topics (under the node's name), for Foxglove and PlotJuggler: their plot
#: panels have no log axis and no complex numbers.
BODE_TOPICS = ("log10_frequency", "bode_mag_db", "bode_phase_deg")


def bode_msgs(frequency: NDArray, response: NDArray) -> tuple[Float64MultiArray, ...]:
    """(log10 f, |P| in dB, phase in degrees) of a (K, n_out, n_in) FRF.

    Magnitude and phase: output x input x frequency (frequency innermost), as
    ``plant_frf_std``; the phase is unwrapped along frequency.
    """
    K, ny, nu = response.shape
    dims = [("output", ny, ny * nu * K), ("input", nu, nu * K), ("frequency", K, K)]
    with np.errstate(divide="ignore"):
        mag = 20.0 * np.log10(np.abs(response))
    phase = np.degrees(np.unwrap(np.angle(response), axis=0))
    return (
        multiarray([("frequency", K, 1)], np.log10(frequency)),
        multiarray(dims, np.transpose(mag, (1, 2, 0))),
        multiarray(dims, np.transpose(phase, (1, 2, 0))),
    )


class ResultPublishers:
    """The node's result topics (under its name) and how an estimate goes out on them."""

    def __init__(self, node: Any, make: Any = None) -> None:
        def pub(name: str) -> Any:
            if make is not None:  # e.g. a lifecycle publisher of the node's
                return make(Float64MultiArray, f"~/{name}")
            return node.create_publisher(Float64MultiArray, f"~/{name}", RESULT_QOS)

        self._frf = [pub(t) for t in ("frequencies", "plant_frf", "plant_frf_std")]
        self._bode = [pub(t) for t in BODE_TOPICS]
        self._pfg = {
            key: [pub(key), pub(f"{key}_std")] for key in ("pfg", "pfg_data")
        }  # ~/pfg: from P_h and the controller; ~/pfg_data: from data alone

    def publish(self, ident: Any, picks: NDArray[np.intp]) -> None:
        """An identification on the bins ``picks``: FRF, plot topics, then the PFGs it has."""
        plant = ident.plant
        f, P = plant.frequency[picks], plant.response[picks]
        for p, m in zip(self._frf, frf_msgs(f, P, plant.std[picks]), strict=True):
            p.publish(m)
        for p, m in zip(self._bode, bode_msgs(f, P), strict=True):
            p.publish(m)
        for key, g in (("pfg", ident.pfg), ("pfg_data", ident.pfg_data)):
            if g is not None:
                self._pfg[key][0].publish(vector_msg(g.gain[picks]))
                self._pfg[key][1].publish(vector_msg(g.std[picks]))
