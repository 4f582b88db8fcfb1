# SPDX-License-Identifier: Apache-2.0
"""The node's result topics: one ``mr_ident_msgs/Estimate`` per estimate, and a Summary.

``~/estimate`` (reliable, transient local, depth 1: a late subscriber gets the latest)
carries everything of one estimate in one stamped message (header stamp: the window's last
sample); ``~/summary`` a few scalars of it for plotting tools (PlotJuggler, rqt_plot).
Both on at most ``publish_points`` log-spaced bins. With ``legacy_array_topics`` the
Float64MultiArray topics of earlier versions go out too
(:class:`~mr_ident.ros.messages.ResultPublishers`).

Adapter only: arrays to messages (:func:`estimate_message`) and back
(:func:`estimate_arrays`); the scalars come from :func:`mr_ident.live.summary.summary`.
"""

from __future__ import annotations

import array
import importlib
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..io.config import IdentConfig
from ..live.estimate import Estimate, publish_grid
from ..live.summary import summary
from .messages import RESULT_QOS, ResultPublishers


def _interfaces() -> tuple[Any, Any, Any]:
    """(Estimate, Summary, Drift) of mr_ident_msgs; Nones without it (no configure then)."""
    try:
        msg = importlib.import_module("mr_ident_msgs.msg")
    except ImportError:  # the node's configure says how to build it
        return None, None, None
    return msg.Estimate, msg.Summary, msg.Drift


EstimateMsg, SummaryMsg, DriftMsg = _interfaces()


def floats(x: Any) -> array.array:
    """A float64 array field's value (``array.array``: fast to assign)."""
    return array.array("d", np.ascontiguousarray(x, dtype=np.float64).tobytes())


def stamp(msg: Any, ns: int) -> None:
    """``msg.header.stamp`` set to ``ns`` (ROS time, ns)."""
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), 1_000_000_000)


def estimate_message(
    est: Estimate, picks: NDArray[np.intp], stamp_ns: int, missing: int = 0
) -> Any:
    """The Estimate message of ``est`` on the bins ``picks`` (flat, row-major arrays).

    ``missing``: samples of the window where r, u or y was missing (u and y estimated as
    unknowns, r recovered from the loop).
    """
    ident = est.identification
    plant = ident.plant
    P = plant.response[picks]
    m = EstimateMsg()
    stamp(m, stamp_ns)
    m.window_first = int(est.first)
    m.window_last = int(est.first + est.n_samples - 1)
    m.missing_samples = int(missing)
    m.fs_high = float(ident.fs_high)
    m.ratio = int(ident.ratio)
    m.method = str(plant.method)
    m.local_model = str(ident.local)
    m.injection = str(ident.injection)
    m.loop_structure = str(est.structure)
    m.n_out, m.n_in = int(P.shape[1]), int(P.shape[2])
    m.frequency = floats(plant.frequency[picks])
    m.response_real = floats(P.real)
    m.response_imag = floats(P.imag)
    m.response_std = floats(plant.std[picks])
    n = ident.n_used[picks] if ident.n_used is not None else np.zeros(picks.size)
    m.halfwidth = array.array("I", np.asarray(n, dtype=np.uint32).tobytes())
    if ident.undetermined is not None:
        m.undetermined = [bool(b) for b in ident.undetermined[picks]]
    for key in ("pfg", "pfg_data"):
        g = getattr(ident, key)
        if g is not None:
            setattr(m, key, floats(g.gain[picks]))
            setattr(m, f"{key}_std", floats(g.std[picks]))
    return m


@dataclass(frozen=True)
class EstimateArrays:
    """An Estimate message as arrays: P (K, n_out, n_in) complex, PFGs (K,) or None."""

    stamp_ns: int
    window_first: int
    window_last: int
    fs_high: float
    ratio: int
    method: str
    local_model: str
    injection: str
    loop_structure: str
    frequency: NDArray[np.float64]
    response: NDArray[np.complex128]
    std: NDArray[np.float64]
    halfwidth: NDArray[np.uint32]
    pfg: NDArray[np.float64] | None
    pfg_std: NDArray[np.float64] | None
    pfg_data: NDArray[np.float64] | None
    pfg_data_std: NDArray[np.float64] | None
    undetermined: NDArray[np.bool_] | None


def estimate_arrays(m: Any) -> EstimateArrays:
    """The arrays of an Estimate message (inverse of :func:`estimate_message`)."""
    K = len(m.frequency)
    shape = (K, int(m.n_out), int(m.n_in))

    def vec(x: Any) -> NDArray[np.float64] | None:
        return np.array(x, dtype=np.float64) if len(x) == K and K else None

    P = np.array(m.response_real, float) + 1j * np.array(m.response_imag, float)
    return EstimateArrays(
        stamp_ns=int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec),
        window_first=int(m.window_first),
        window_last=int(m.window_last),
        fs_high=float(m.fs_high),
        ratio=int(m.ratio),
        method=str(m.method),
        local_model=str(m.local_model),
        injection=str(m.injection),
        loop_structure=str(m.loop_structure),
        frequency=np.array(m.frequency, dtype=np.float64),
        response=P.reshape(shape),
        std=np.array(m.response_std, dtype=np.float64).reshape(shape),
        halfwidth=np.array(m.halfwidth, dtype=np.uint32),
        pfg=vec(m.pfg),
        pfg_std=vec(m.pfg_std),
        pfg_data=vec(m.pfg_data),
        pfg_data_std=vec(m.pfg_data_std),
        undetermined=np.array(m.undetermined, dtype=bool) if len(m.undetermined) else None,
    )


def summary_message(est: Estimate, stamp_ns: int, state: Any) -> Any:
    """The Summary message of ``est``; ``state``: the monitor's state (or None)."""
    d = state.drift if state is not None else None
    s = summary(
        est.identification,
        d.deviation if d is not None else None,
        d.sigma_error if d is not None else None,
    )
    m = SummaryMsg()
    stamp(m, stamp_ns)
    m.window_last = int(est.first + est.n_samples - 1)
    for field in (
        "pfg_peak",
        "pfg_peak_frequency",
        "pfg_data_peak",
        "pfg_data_peak_frequency",
        "median_relative_std",
        "drift_max_sigma",
        "drift_max_relative",
    ):
        setattr(m, field, float(getattr(s, field)))
    return m


class Outputs:
    """The result publishers of one configured node (lifecycle publishers)."""

    def __init__(self, node: Any, legacy: bool) -> None:
        self._node = node
        self._pubs: list[Any] = []
        self._estimate = self._make(EstimateMsg, "~/estimate")
        self._summary = self._make(SummaryMsg, "~/summary")
        self._legacy = ResultPublishers(node, self._make) if legacy else None

    def _make(self, kind: Any, topic: str) -> Any:
        pub = self._node.create_lifecycle_publisher(kind, topic, RESULT_QOS)
        self._pubs.append(pub)
        return pub

    def publish(
        self, est: Estimate, cfg: IdentConfig, stamp_ns: int, state: Any, missing: int = 0
    ) -> Any:
        """One estimate out on every result topic; its Estimate message.

        ``missing``: the window's missing samples (r, u or y), as ``Estimate.missing_samples``.
        """
        picks = publish_grid(est.identification.plant.frequency.size, cfg.publish_points)
        msg = estimate_message(est, picks, stamp_ns, missing)
        self._estimate.publish(msg)
        self._summary.publish(summary_message(est, stamp_ns, state))
        if self._legacy is not None:
            self._legacy.publish(est.identification, picks)
        return msg

    def destroy(self) -> None:
        """Every publisher destroyed (the node's cleanup)."""
        for pub in self._pubs:
            self._node.destroy_lifecycle_publisher(pub)
        self._pubs = []
