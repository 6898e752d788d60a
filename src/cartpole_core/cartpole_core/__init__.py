"""What every layer shares: the thesis's plant model (parameters, dynamics, energies, linearisation) and the node plumbing (node runner, real-time settings, diagnostics, domain guard, DDS profile)."""
from .realtime import pin_numerical_threads

pin_numerical_threads()  # before numpy loads (cartpole_core.realtime; unless set already)
