"""rosbag2 bags without ROS: writing, MCAP storage, repair after a kill, direct CDR readers."""
