"""Dynamixel AX-12A bus (Protocol 1.0) exposed as ROS topics, with an emulated bus for testing without hardware."""
