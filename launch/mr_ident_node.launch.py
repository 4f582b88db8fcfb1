# SPDX-License-Identifier: Apache-2.0
"""The identification node alone, for a robot (ros2 launch mr_ident mr_ident_node.launch.py).

Arguments:

* ``namespace`` (default empty) and ``node_name`` (``mr_ident``): where the node lives; its
  topics, services and /diagnostics statuses carry that name;
* ``params_file`` (default: the installed ``config/node.yaml``, keyed ``/**``);
* ``use_sim_time`` (``false``): estimates follow /clock;
* ``autostart`` (``true``): this launch file brings the node up (configured and active at
  once); ``false``: it waits unconfigured, as the node alone does, for lifecycle transitions
  (a lifecycle manager, ``ros2 lifecycle set <node> configure``);
* ``log_level`` (``info``);
* ``reference``, ``input``, ``output``: remaps of the block topics, and of source topics
  given relative in the params file (``r_source: ["reference.data"]``).

E.g. ``ros2 launch mr_ident mr_ident_node.launch.py namespace:=arm params_file:=arm.yaml
output:=/arm/joint_states``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription

ARGUMENTS = {
    "namespace": ("", "namespace of the node"),
    "node_name": ("mr_ident", "name of the node"),
    "use_sim_time": ("false", "use /clock (estimates follow it)"),
    "autostart": ("true", "bring the node up: configure and activate at start"),
    "log_level": ("info", "debug, info, warn, error or fatal"),
    "reference": ("reference", "topic of r (block contract), or a remap of a source's topic"),
    "input": ("input", "topic of u (block contract), or a remap of a source's topic"),
    "output": ("output", "topic of y (block contract), or a remap of a source's topic"),
}


def generate_launch_description():
    share = get_package_share_directory("mr_ident")
    declared = [
        DeclareLaunchArgument(name, default_value=default, description=text)
        for name, (default, text) in ARGUMENTS.items()
    ]
    declared.append(
        DeclareLaunchArgument(
            "params_file",
            default_value=os.path.join(share, "config", "node.yaml"),
            description="the node's parameters (ROS 2 params file)",
        )
    )
    arg = LaunchConfiguration
    node = LifecycleNode(
        package="mr_ident",
        executable="mr-ident-node",
        name=arg("node_name"),
        namespace=arg("namespace"),
        output="screen",
        parameters=[
            arg("params_file"),
            {
                "use_sim_time": ParameterValue(arg("use_sim_time"), value_type=bool),
                "autostart": ParameterValue(arg("autostart"), value_type=bool),
            },
        ],
        remappings=[(topic, arg(topic)) for topic in ("reference", "input", "output")],
        ros_arguments=["--log-level", arg("log_level")],
    )
    return LaunchDescription([*declared, node])
