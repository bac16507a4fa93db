"""The stand calibration routine: its plan of motions and the command that runs it on the robot."""
