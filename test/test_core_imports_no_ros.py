# SPDX-License-Identifier: Apache-2.0
"""The numeric core, I/O, live, diagnosis, the CLI, the plots and the offline replay import
no ROS code: only ``mr_ident.ros`` does."""

import pkgutil
import subprocess
import sys
from pathlib import Path

import mr_ident

ROOT = Path(__file__).resolve().parents[1]
ALL = sorted(m.name for m in pkgutil.walk_packages(mr_ident.__path__, "mr_ident."))
CORE = (
    ["mr_ident"]
    + [m for m in ALL if not m.startswith("mr_ident.ros") and not m.endswith("__main__")]
    + ["mcap_ros2.decoder"]
)


def test_importing_the_core_loads_no_ros_module():
    assert "mr_ident.numerics.lifting" in CORE and "mr_ident.diagnosis.causes.cause" in CORE
    code = (
        "import sys\n"
        + "".join(f"import {m}\n" for m in CORE)
        + "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'rosidl_runtime_py', 'std_msgs', 'diagnostic_msgs', 'rmw', 'rcl'))\n"
        "print(','.join(bad))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""
