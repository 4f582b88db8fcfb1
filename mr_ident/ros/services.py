# SPDX-License-Identifier: Apache-2.0
"""The node's services (made at configure, gone at cleanup).

=========================  ==========================  ======================================
``~/reset``                ``std_srvs/Trigger``        drop the window now: the next estimate
                                                       holds only samples received after it
``~/snapshot``             ``mr_ident_msgs/SaveEstimate``  the latest estimate (full resolution)
                                                       as a result file (``identify --out``'s)
``~/capture_reference``    ``mr_ident_msgs/SaveEstimate``  the same file, then used at once as
                                                       the monitoring reference
                                                       (``monitor_reference`` set to it)
``~/diagnose``             ``mr_ident_msgs/Diagnose``  the diagnosis of the current window
                                                       against ``monitor_model``, as JSON
``~/start_recording``      ``mr_ident_msgs/Record``    record the inputs to an MCAP file
``~/stop_recording``       ``std_srvs/Trigger``        finalise it
=========================  ==========================  ======================================

``~/diagnose`` runs on a thread of its own: its callback is a coroutine that awaits a
future the thread completes, in a callback group of its own (rclpy holds a callback's
group while its coroutine is pending: in the node's default group it would stop the
timers and subscriptions). So with the node's single-threaded executor the other
callbacks and the estimates go on meanwhile. Adapter only: the work is the node's and the
library's.
"""

from __future__ import annotations

import importlib
import json
import os
import threading
from pathlib import Path
from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.parameter import Parameter
from rclpy.task import Future
from std_srvs.srv import Trigger

from ..app.diagnose import window_report
from ..errors import MrIdentError
from ..io.datafile import write_result


def _interfaces() -> tuple[Any, Any, Any]:
    """(Diagnose, Record, SaveEstimate) of mr_ident_msgs; Nones without the package."""
    try:
        srv = importlib.import_module("mr_ident_msgs.srv")
    except ImportError:  # the node's configure says how to build it
        return None, None, None
    return srv.Diagnose, srv.Record, srv.SaveEstimate


Diagnose, Record, SaveEstimate = _interfaces()


def default_path(node: Any, kind: str, last: int) -> Path:
    """``$ROS_HOME/mr_ident/<node>_<kind>_<last sample>.npz`` (ROS_HOME: ~/.ros)."""
    home = Path(os.environ.get("ROS_HOME") or Path.home() / ".ros")
    name = node.get_fully_qualified_name().strip("/").replace("/", "_")
    return home / "mr_ident" / f"{name}_{kind}_{last}.npz"


class NodeServices:
    """The services of one configured :class:`~mr_ident.ros.node.IdentNode`."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self._diagnosis: threading.Thread | None = None
        self._wake = node.create_guard_condition(lambda: None)
        self._made = [
            node.create_service(Trigger, "~/reset", self._reset),
            node.create_service(Trigger, "~/stop_recording", self._stop_recording),
            node.create_service(SaveEstimate, "~/snapshot", self._snapshot),
            node.create_service(SaveEstimate, "~/capture_reference", self._capture),
            # its own group: while the coroutine awaits the worker, the node's default
            # (mutually exclusive) group - timers, subscriptions - goes on
            node.create_service(
                Diagnose,
                "~/diagnose",
                self._diagnose,
                callback_group=MutuallyExclusiveCallbackGroup(),
            ),
            node.create_service(Record, "~/start_recording", self._start_recording),
        ]

    def destroy(self) -> None:
        """The services destroyed (the node's cleanup)."""
        for srv in self._made:
            self.node.destroy_service(srv)
        self._made = []
        self.node.destroy_guard_condition(self._wake)

    def shutdown(self, timeout: float) -> None:
        """Wait for a running diagnosis (bounded)."""
        t = self._diagnosis
        if t is not None:
            t.join(timeout)

    # -- the window -------------------------------------------------------------------------
    def _reset(self, _req: Any, res: Any) -> Any:
        self.node.reset_window()
        res.success = True
        res.message = "window dropped: the next estimate holds only samples received from now"
        return res

    # -- the estimate as a file ---------------------------------------------------------------
    def _save(self, req: Any, res: Any, kind: str) -> Path | None:
        pub = self.node.published
        if pub is None:
            res.success, res.message = False, "no estimate yet"
            return None
        est = pub.estimate
        last = est.first + est.n_samples - 1
        path = Path(req.path) if req.path else default_path(self.node, kind, last)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_result(path, est.identification)
        except (MrIdentError, OSError) as err:
            res.success, res.message = False, f"cannot write {path}: {err}"
            return None
        res.success, res.path = True, str(path.resolve())
        res.window_first, res.window_last = int(est.first), int(last)
        res.message = f"estimate of samples {est.first}..{last} written"
        return path.resolve()

    def _snapshot(self, req: Any, res: Any) -> Any:
        self._save(req, res, "snapshot")
        return res

    def _capture(self, req: Any, res: Any) -> Any:
        path = self._save(req, res, "reference")
        if path is None:
            return res
        result = self.node.set_parameters([Parameter("monitor_reference", value=str(path))])[0]
        if not result.successful:
            res.success = False
            res.message = f"written, but not usable as the reference: {result.reason}"
        else:
            res.message += " and used as the monitoring reference (monitor_reference)"
        return res

    # -- the diagnosis ------------------------------------------------------------------------
    async def _diagnose(self, _req: Any, res: Any) -> Any:
        monitoring = self.node.monitoring
        model = monitoring.model if monitoring is not None else None
        window = self.node.current_window()
        busy = self._diagnosis is not None and self._diagnosis.is_alive()
        why = (
            "no model to diagnose against: set monitor_model"
            if model is None
            else "no window yet"
            if window is None
            else "a diagnosis is running already"
            if busy
            else ""
        )
        if why or model is None or window is None:
            res.success, res.message = False, why
            return res
        done: Future = Future()

        def work() -> None:
            try:
                done.set_result(window_report(model, window))
            except Exception as err:  # noqa: BLE001 - said in the response
                done.set_result(err)
            self._wake.trigger()  # the executor looks at the awaiting callback again

        self._diagnosis = threading.Thread(target=work, daemon=True, name="mr_ident-diagnose-srv")
        self._diagnosis.start()
        report = await done
        res.window_first = int(window.first)
        res.window_last = int(window.first + window.n_samples - 1)
        if isinstance(report, Exception):
            res.success, res.message = False, f"diagnosis failed: {report}"
            return res
        res.success, res.json = True, json.dumps(report)
        params = ", ".join(f"{k} = {v:.6g}" for k, v in report["parameters"].items())
        res.message = f"cause: {report['cause']}" + (f" ({params})" if params else "")
        return res

    # -- recording ----------------------------------------------------------------------------
    def _start_recording(self, req: Any, res: Any) -> Any:
        node = self.node
        cfg = node.config
        path = req.path or node.recording.last or (cfg.record_path if cfg is not None else "")
        if not node.active:
            res.success, res.message = False, "the node is not active"
        elif not path:
            res.success, res.message = False, "no path: give one, or set record_path"
        else:
            target = node.start_recording(path)
            res.success = target is not None
            res.path = str(target.resolve()) if target is not None else ""
            res.message = (
                node.recording.error
                if target is None
                else f"recording to {res.path}"
                + (f" ({path} exists: never overwritten)" if target != Path(path) else "")
            )
        return res

    def _stop_recording(self, _req: Any, res: Any) -> Any:
        path = self.node.stop_recording()
        res.success = True
        res.message = f"finalised {path}" if path is not None else "was not recording"
        return res
