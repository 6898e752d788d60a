"""The simulated rig: the thesis's plant with its actuator, end stops, encoders and disturbances, and the simulator node."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
