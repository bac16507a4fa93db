"""Robot description, kinematics, body leveling, the AX-12A servo law, the swing-down dynamic model of leg +
servo controller (Faigl & Cizek Eq. 11-17), the ROS contract, the ServoBus interface and the model node."""
