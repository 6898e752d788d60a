"""The catch the stabiliser can hold: a simulated catch on the estimated plant decides."""
import pytest

from cartpole_control.catch_region import CatchRegion
from cartpole_control.manager import STABILIZING, SWINGUP_MODE, ControllerManager
from cartpole_core.model import CartPoleParameters

P = CartPoleParameters()
X_REF = P.x_middle


def holds(region, theta, theta_dot, x_err=0.0, x_dot=0.0):
    return region.holds(x_err, X_REF + x_err, theta, x_dot, theta_dot)


def test_a_pendulum_coming_up_with_the_upright_energy_is_held_one_going_away_is_not():
    region = CatchRegion(P, P.sample_time)
    assert holds(region, 0.05, 0.0)
    assert holds(region, 0.45, -3.1, x_err=0.13)      # the time-optimal plan's hand-over
    assert not holds(region, 0.5, 3.5)                 # 30 deg, falling away at 3.5 rad/s
    assert region.checks == 3


def test_a_weak_amplifier_holds_less():
    """The same state, held with the full amplifier (and with 40 % of it), is refused at a
    quarter of its force."""
    region = CatchRegion(P, P.sample_time)
    state = (0.3, -2.0)
    region.set_plant(P.g / P.l, 0.4)
    assert holds(region, *state)
    region.set_plant(P.g / P.l, 1.0)
    assert holds(region, *state)
    region.set_plant(P.g / P.l, 0.25)
    assert not holds(region, *state)
    region.set_plant(P.g / P.l, 1.0)
    assert holds(region, *state)


def test_the_rail_counts_a_catch_near_an_end_stop_needs_room():
    region = CatchRegion(P, P.sample_time)
    assert holds(region, 0.3, -2.0, x_err=0.0, x_dot=0.0)
    assert not region.holds(0.3, 0.74, 0.3, 1.0, -2.0)     # 3 cm from the stop, moving to it


def test_every_fall_tightens_the_force_budget_of_the_next_catch():
    region = CatchRegion(P, P.sample_time)
    edge = None
    for theta_dot in [x * 0.25 for x in range(0, 40)]:   # moving away, harder and harder
        if not holds(region, 0.2, theta_dot):
            edge = theta_dot
            break
    assert edge is not None
    inside = edge - 0.25
    assert holds(region, 0.2, inside)
    for _ in range(3):
        region.fell()
    assert not holds(region, 0.2, inside)
    region.reset()
    assert holds(region, 0.2, inside)


def test_the_manager_waits_inside_the_thesis_window_until_the_region_holds():
    """(6.4) holds (20 deg, upright energy) but the pendulum falls away fast: no catch with the
    region, a catch without it (the thesis's trigger alone)."""
    import math
    theta = math.radians(20.0)
    # the energy E* at 20 deg: theta_dot^2 = 2 g / l (1 - cos theta), falling away (> 0)
    theta_dot = math.sqrt(2.0 * P.g / P.l * (1.0 - math.cos(theta)))
    known = {'predict.horizon': 0.0, 'rail.actuator_dead_time': 0.0}
    with_region = ControllerManager(P, **known)
    thesis = ControllerManager(P, **known, **{'catch.region': False})
    a = with_region.update_values(0.0, X_REF, theta, 1.5, theta_dot)
    b = thesis.update_values(0.0, X_REF, theta, 1.5, theta_dot)
    assert b.mode == STABILIZING and b.catch_count == 1
    assert a.mode == SWINGUP_MODE and a.catch_count == 0
    c = with_region.update_values(0.005, X_REF, 0.02, 0.0, 0.0)
    assert c.mode == STABILIZING


def test_the_estimated_pendulum_changes_the_gain():
    region = CatchRegion(P, P.sample_time)
    nominal = region.gain
    region.set_plant(P.g / (1.15 * P.l), 1.0)
    assert region.estimated.l == pytest.approx(1.15 * P.l)
    assert region.gain != nominal


def test_a_dead_time_the_prediction_leaves_out_shrinks_the_region():
    """Each command acting 20 ms later (a lag not measured yet): the time-optimal plan's
    hand-over still holds, a pendulum 0.2 rad off at rest no longer does; with 40 ms the
    model's LQR holds nothing (why the catch allows for at most 20 ms)."""
    region = CatchRegion(P, P.sample_time)
    assert holds(region, 0.2, 0.0)
    assert not region.holds(0.0, X_REF, 0.2, 0.0, 0.0, dead_time=0.02)
    assert region.holds(0.13, X_REF + 0.13, 0.45, 0.0, -3.1, dead_time=0.02)
    assert not region.holds(0.0, X_REF, 0.02, 0.0, 0.0, dead_time=0.04)


def test_the_catch_keeps_the_cart_inside_the_guards_limiter_band():
    """A catch transient that needs the rail beyond the guard's limiter band (5 cm inside its
    margin) is refused: the limiter would hold the cart there and drop the pendulum."""
    from cartpole_control.rail_guard import RailGuard
    from cartpole_control.controller import ControllerState

    region = CatchRegion(P, P.sample_time)
    x, theta, x_dot, theta_dot = 0.6, 0.3, 0.2, -2.0
    assert region.holds(x - X_REF, x, theta, x_dot, theta_dot)          # the stops' margin: yes
    guard = RailGuard(P)
    state = ControllerState(0.0, x, theta, x_dot, theta_dot)
    assert not region.admits(state, X_REF, P.g / P.l, 1.0, guard)        # the limiter's band: no
    assert region.admits(ControllerState(0.0, X_REF, theta, 0.0, theta_dot), X_REF,
                         P.g / P.l, 1.0, guard)
