"""The ROS nodes: the locomotion node and its parameters, the composed robot, /cmd_vel publishers, the ROS bus."""
