# SPDX-License-Identifier: Apache-2.0
"""Console-script entry points of the ROS programs: signal handling first, then the imports.

Importing the node or the simulator takes a second (rclpy, numpy, scipy); a SIGINT or
SIGTERM in that second must already stop the program cleanly, so these entry points
install :func:`~mr_ident.ros.program.handle_signals` before importing anything slow.
"""

from __future__ import annotations

import sys

from .program import handle_signals, wants_help

NODE_USAGE = """\
usage: mr-ident-node [-h] [--ros-args -p NAME:=VALUE ... | --params-file FILE.yaml]

Identifies a running multirate loop from ROS 2 topics: the high-rate plant P_h with its
std, the PFG and its health on /diagnostics, and, with a reference model, monitoring.
A managed (lifecycle) node: it waits unconfigured for a launch file, a lifecycle manager
or `ros2 lifecycle set`; with `-p autostart:=true` it configures and activates at once.
Ctrl-C (SIGINT) or SIGTERM stops it, exit 0; a configuration that fails exits 2.

example:
  mr-ident-node --ros-args -p autostart:=true -p fs_high:=1000.0 -p ratio:=4 \\
    -p 'r_source:=["/ident/reference.data"]' \\
    -p 'u_source:=["/joint_states.effort{name==\\"j1\\"}"]' \\
    -p 'y_source:=["/joint_states.position{name==\\"j1\\"}"]'

parameters (docs/node.md, "All parameters"; config/node.yaml holds every default):
  autostart             configure and activate at start (default false)
  legacy_array_topics   also publish the Float64MultiArray topics (default false)
"""


def node_usage() -> str:
    """The node's usage, with every identification parameter and its description."""
    from ..io.config import PARAMETERS

    lines = [f"  {name:<21} {p.description}" for name, p in PARAMETERS.items()]
    return NODE_USAGE + "\n".join(lines) + "\n"


def node_main() -> int:
    """``mr-ident-node``; ``-h``/``--help`` prints its usage and exits 0, starting nothing."""
    if wants_help(sys.argv[1:]):
        print(node_usage(), end="")
        return 0
    handle_signals()
    from .node_main import main

    return main()


def sim_main() -> int:
    """``mr-ident-sim`` (its argparse answers ``-h``/``--help`` before anything starts)."""
    handle_signals()
    from .sim import main

    return main()
