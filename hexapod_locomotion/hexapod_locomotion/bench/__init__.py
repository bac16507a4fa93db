"""Benchmarks of the ROS graph and of the sim-vs-real tool (they print figures)."""
