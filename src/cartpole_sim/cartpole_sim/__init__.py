"""Plant model of the thesis's cart-pendulum (dynamics, friction, actuator, end stops, encoders) and the simulator node."""
