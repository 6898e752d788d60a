"""The closed loop without ROS, the very objects the nodes host."""
