"""What a run did, from its time series (no ROS): series, the run summary, plots, animations."""
