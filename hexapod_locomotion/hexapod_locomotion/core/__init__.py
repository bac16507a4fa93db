"""The controller in plain Python: gaits, swing phases, Algorithm 1 and the fixed-threshold baseline, leveling,
metrics, read timing, leg odometry and course keeping. No ROS import."""
