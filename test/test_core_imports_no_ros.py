"""The numeric core, the CLI, the plots and the offline replay import no ROS code."""

import subprocess
import sys

CORE = ["mr_ident", "mr_ident.errors", "mr_ident.results", "mr_ident.lifting", "mr_ident.lpm",
        "mr_ident.loop", "mr_ident.pfg", "mr_ident.identify", "mr_ident.systems", "mr_ident.model",
        "mr_ident.simulate", "mr_ident.data", "mr_ident.plots", "mr_ident.paper", "mr_ident.cli",
        "mr_ident.config", "mr_ident.stream", "mr_ident.live", "mr_ident.recording", "mr_ident.validate",
        "mr_ident.report", "mr_ident._parallel", "mcap_ros2.decoder"]


def test_importing_the_core_loads_no_ros_module():
    code = ("import sys\n" + "".join(f"import {m}\n" for m in CORE)
            + "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
              "('rclpy', 'rosidl_runtime_py', 'std_msgs', 'diagnostic_msgs', 'rmw', 'rcl'))\n"
              "print(','.join(bad))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""
