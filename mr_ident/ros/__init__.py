"""ROS 2 adapters (rclpy): the identification node, the simulated loop, recording and replay publishing."""
