"""The plugin on its own: the poles are where they were asked, a bad set is refused."""
import numpy as np
import pytest

from cartpole_control.controller import ControlContext, ControllerState
from cartpole_pole_placement.pole_placement import PolePlacementStabilizer
from cartpole_core.model import CartPoleParameters, linearise_upright

PLANT = CartPoleParameters()
CONTEXT = ControlContext(PLANT, PLANT.x_middle, PLANT.sample_time)


def test_the_closed_loop_poles_are_the_requested_ones():
    law = PolePlacementStabilizer()
    law.configure({'poles': (-1.0, -4.0, -10.0, -20.0)}, CONTEXT)
    a, b = linearise_upright(PLANT)
    poles = np.linalg.eigvals(a - b @ law.gain.reshape(1, 4))
    np.testing.assert_allclose(np.sort(poles.real), [-20.0, -10.0, -4.0, -1.0], rtol=1e-8)
    np.testing.assert_allclose(poles.imag, 0.0, atol=1e-8)


def test_upright_at_x_ref_gives_no_force_and_a_lean_to_the_left_a_push_to_the_left():
    law = PolePlacementStabilizer()
    law.configure({}, CONTEXT)
    law.activate(ControllerState(0.0, PLANT.x_middle, 0.0, 0.0, 0.0))
    assert law.update(ControllerState(0.0, PLANT.x_middle, 0.0, 0.0, 0.0)) == 0.0
    # theta > 0 leans the pendulum towards negative x: the cart must move left under it.
    assert law.update(ControllerState(0.0, PLANT.x_middle, 0.05, 0.0, 0.0)) < 0.0


def test_repeated_or_unstable_poles_are_refused_and_the_old_gain_kept():
    law = PolePlacementStabilizer()
    law.configure({}, CONTEXT)
    gain = law.gain.copy()
    with pytest.raises(ValueError, match='distinct'):
        law.configure({'poles': (-2.0, -2.0, -12.0, -16.0)}, CONTEXT)
    with pytest.raises(ValueError, match='above its maximum'):
        law.configure({'poles': (2.0, -3.0, -12.0, -16.0)}, CONTEXT)
    np.testing.assert_array_equal(law.gain, gain)
