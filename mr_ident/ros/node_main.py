# SPDX-License-Identifier: Apache-2.0
"""The console script ``mr-ident-node``: one identification node, spun until a signal.

One :class:`~mr_ident.ros.node.IdentNode` on a single-threaded executor until SIGINT or
SIGTERM (:mod:`mr_ident.ros.program`: one shutdown path).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Sequence

import rclpy
from rclpy.executors import SingleThreadedExecutor

from ..allocator import keep_freed_memory
from ..errors import ConfigError, MrIdentError
from .node import IdentNode
from .program import handle_signals, ros_context, spin_until_stopped


def main(argv: Sequence[str] | None = None) -> int:
    """Console script ``mr-ident-node`` (accepts ``--ros-args ...``).

    SIGINT and SIGTERM stop it at any moment through one path
    (:mod:`mr_ident.ros.program`): the recording finalised, a running identification awaited
    at most a second, then rclpy shut down; exit 0. Unconfigured until a lifecycle request
    comes, or with ``autostart:=true`` configured and activated at once; then a configure
    that fails (a bad params file, an unreadable reference) exits 2.
    """
    stop = handle_signals()
    args = list(sys.argv if argv is None else argv)
    keep_freed_memory()
    try:
        with ros_context(args):
            node = None
            try:
                node = IdentNode()
                if not node.autostart():
                    raise ConfigError(node.configure_error or "the node did not start")
                # Not rclpy.experimental.EventsExecutor: in rclpy 7.1.6 its spin() starves other
                # Python threads (measured: the identification thread and publishers from other
                # threads stall), and the identification must run off the executor thread.
                executor = SingleThreadedExecutor()
                executor.add_node(node)
                spin_until_stopped(executor, node, stop)
                executor.shutdown()
            finally:
                if node is not None:
                    with contextlib.suppress(Exception):  # finalized already
                        node.trigger_shutdown()  # the lifecycle's own shutdown transition
                    node.shutdown()
                    node.destroy_node()
    except (
        MrIdentError,
        rclpy.exceptions.InvalidParameterTypeException,
        rclpy.exceptions.InvalidParameterValueException,
    ) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0
