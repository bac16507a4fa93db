"""Robot description, kinematics, body leveling, the swing-down dynamic model of leg + AX-12A servo controller (Faigl & Cizek Eq. 11-17), the model node and the sim-vs-real discrepancy tool."""
