# SPDX-License-Identifier: Apache-2.0
"""Console-script entry points of the ROS programs: signal handling first, then the imports.

Importing the node or the simulator takes a second (rclpy, numpy, scipy); a SIGINT or
SIGTERM in that second must already stop the program cleanly, so these entry points
install :func:`~mr_ident.ros.program.handle_signals` before importing anything slow.
"""

from __future__ import annotations

from .program import handle_signals


def node_main() -> int:
    """``mr-ident-node``."""
    handle_signals()
    from .node_main import main

    return main()


def sim_main() -> int:
    """``mr-ident-sim``."""
    handle_signals()
    from .sim import main

    return main()
