# SPDX-License-Identifier: Apache-2.0
"""Build script (ament_python for colcon, plain setuptools for pip)."""

import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "mr_ident"

setup(
    name=package_name,
    version=re.search(
        r"__version__ = \"(.+)\"",
        (Path(__file__).resolve().parent / "mr_ident" / "version.py").read_text(),
    ).group(1),
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    package_data={package_name: ["py.typed", "view/page/*.html", "view/page/*.js"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.json")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
    ],
    # the range tested: from requirements-apt.txt (what Ubuntu 24.04's apt gives a Jazzy
    # robot: numpy 1.26, scipy 1.11, matplotlib 3.6) to requirements.txt (the newest)
    install_requires=[
        "setuptools",
        "numpy>=1.26.4,<3",
        "scipy>=1.11.4,<2",
        "threadpoolctl>=3.1",
        "PyYAML>=6.0.1",
        "matplotlib>=3.6.3,<4",
        "mcap>=1.3.1",
        "mcap-ros2-support>=0.5.7",
        # read directly (MCAP chunks, compressed rosbag2 files); both also come with mcap
        "zstandard>=0.22",
        "lz4>=4.3.2",
        "plotly>=5.15,<8",
    ],
    extras_require={"cluster": ["dask[distributed]>=2024.1"], "control": ["control>=0.10"]},
    zip_safe=True,
    maintainer="mr_ident developers",
    maintainer_email="mr-ident@example.org",
    description="Frequency-domain identification of multirate control loops (lifted LPM).",
    license="Apache-2.0",
    python_requires=">=3.10",
    tests_require=["pytest", "hypothesis", "rosbags", "control", "scikit-rf"],
    entry_points={
        "console_scripts": [
            "mr-ident = mr_ident.cli:main",
            "mr-ident-node = mr_ident.ros.entry:node_main",
            "mr-ident-sim = mr_ident.ros.entry:sim_main",
        ],
    },
)
