"""MuJoCo hexapod standing in for the hardware: same topics as the driver, terrain mockup, MCAP recording."""
