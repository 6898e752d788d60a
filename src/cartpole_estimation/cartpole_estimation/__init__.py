"""Extended Kalman Filter of the full cart-pendulum state from the encoders, and its node."""
