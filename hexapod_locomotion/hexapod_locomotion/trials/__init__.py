"""Simulated trials and the paper's experiments: the trial runner, Table 4, sweeps, the demo, bag analysis, the process-pool / Ray executor."""
