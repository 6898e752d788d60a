"""Plant model of the thesis's cart-pendulum (dynamics, friction, actuator, end stops, encoders) and the simulator node."""
from .realtime import pin_numerical_threads

pin_numerical_threads()  # before numpy loads (cartpole_sim.realtime; unless set already)
