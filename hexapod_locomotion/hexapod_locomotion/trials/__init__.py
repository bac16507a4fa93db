"""Simulated trials and the paper's experiments: the trial runner, Table 4, sweeps, the demo, bag analysis,
odometry against the sim's truth, the process-pool / Ray executor."""
