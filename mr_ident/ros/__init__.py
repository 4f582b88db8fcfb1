"""ROS 2 adapters (rclpy): the node, the simulated loop, recording, replay publishing."""
