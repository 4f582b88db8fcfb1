# SPDX-License-Identifier: Apache-2.0
"""ROS 2 adapters (rclpy): the node, the simulated loop, recording, replay publishing."""
