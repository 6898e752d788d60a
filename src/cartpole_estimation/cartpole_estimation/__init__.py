"""Extended Kalman Filter of the full cart-pendulum state from the encoders, and its node."""
import cartpole_core  # noqa: F401,E402 - pins numerical threads to one before numpy loads
