"""What a run leaves behind, read back: rosbag2 bags (writer, reader, repair), the run summary and plots, animations and the live viewer."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
