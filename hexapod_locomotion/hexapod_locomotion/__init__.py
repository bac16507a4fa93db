"""Gaits, swing phases, Algorithm 1 adaptive ground detection and the fixed-threshold baseline, body leveling,
leg odometry, the locomotion node and the paper's experiments."""
