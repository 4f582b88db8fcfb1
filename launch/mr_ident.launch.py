# SPDX-License-Identifier: Apache-2.0
"""Launch the simulated loop and the identification node (ros2 launch mr_ident mr_ident.launch.py).

Arguments: model (model YAML for mr-ident-sim), params (node params file),
rate (simulation speed-up). Defaults: the installed paper example and node.yaml.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description():
    share = get_package_share_directory("mr_ident")
    model = DeclareLaunchArgument(
        "model", default_value=os.path.join(share, "config", "paper_example.yaml")
    )
    params = DeclareLaunchArgument(
        "params", default_value=os.path.join(share, "config", "node.yaml")
    )
    rate = DeclareLaunchArgument("rate", default_value="1.0")
    return LaunchDescription(
        [
            model,
            params,
            rate,
            Node(
                package="mr_ident",
                executable="mr-ident-sim",
                name="mr_ident_sim",
                output="screen",
                arguments=[LaunchConfiguration("model"), "--rate", LaunchConfiguration("rate")],
            ),
            Node(
                package="mr_ident",
                executable="mr-ident-node",
                name="mr_ident",
                output="screen",
                parameters=[LaunchConfiguration("params"), {"autostart": True}],
            ),
        ]
    )
