"""Saturated energy swing-up: the law's properties and offline closed-loop runs."""
import math

import pytest

from cartpole_control.controller import ControlContext, ControllerState
from cartpole_control.controllers.energy_saturated import (DEFAULT_GAINS, EnergySaturatedSwingUp,
                                                           exact_force_for_acceleration,
                                                           saturated_energy_acceleration)
from cartpole_control.registry import load_controllers
from cartpole_core.model import CartPoleParameters, accelerations, pendulum_energy

P = CartPoleParameters()
X_MID = P.x_middle
LEFT_STOP_BOUND = 1.17
"""The reference minimum-time bound from the left stop [s] (ISSUE_BOUNDS)."""


def plugin(**gains):
    c = EnergySaturatedSwingUp()
    c.configure(gains, ControlContext(P, X_MID, P.sample_time))
    return c


@pytest.mark.parametrize('theta,theta_dot', [(2.5, 3.0), (3.5, -2.0), (-2.8, -4.0), (2.0, -1.0)])
def test_pumping_raises_the_energy_below_e_star(theta, theta_dot):
    """dE_p/dt = m_p l a theta_dot cos theta (7.4) > 0 while E_p < E* (centring off)."""
    a = saturated_energy_acceleration(X_MID, theta, 0.0, theta_dot, P, X_MID)
    assert pendulum_energy(theta, theta_dot, P) < P.upright_energy
    assert P.m_p * P.l * a * theta_dot * math.cos(theta) > 0.0


def test_pumping_is_saturated_at_n_g_and_lowers_an_excess():
    a = saturated_energy_acceleration(X_MID, 3.0, 0.0, 5.0, P, X_MID, {'k': 1000.0, 'n': 0.3})
    assert abs(a) == pytest.approx(0.3 * P.g)
    # Above E*: the sign reverses (energy is taken out).
    theta, theta_dot = 0.5, 8.0
    assert pendulum_energy(theta, theta_dot, P) > P.upright_energy
    a = saturated_energy_acceleration(X_MID, theta, 0.0, theta_dot, P, X_MID)
    assert a * theta_dot * math.cos(theta) < 0.0


def test_kick_from_hanging_rest_goes_towards_x_ref():
    assert saturated_energy_acceleration(0.0, math.pi, 0.0, 0.0, P, X_MID) > 0.0
    assert saturated_energy_acceleration(0.7, math.pi, 0.0, 0.0, P, X_MID) < 0.0


def test_rail_brake_overrides_the_pumping_near_an_end():
    # Right end, moving right fast: brake whatever the energy term says.
    for theta_dot in (-5.0, 5.0):
        a = saturated_energy_acceleration(0.65, 2.0, 1.2, theta_dot, P, X_MID)
        assert a <= -DEFAULT_GAINS['brake_acceleration']
    a = saturated_energy_acceleration(0.12, 2.0, -1.2, 3.0, P, X_MID)
    assert a >= DEFAULT_GAINS['brake_acceleration']


@pytest.mark.parametrize('theta,theta_dot,a', [(2.5, 3.0, 4.0), (0.3, -1.0, -6.0), (4.0, 7.0, 1.0)])
def test_force_conversion_gives_the_commanded_acceleration(theta, theta_dot, a):
    """(7.10) with theta_ddot from (7.2) is the exact inverse of the frictionless (4.18)."""
    force = exact_force_for_acceleration(a, theta, theta_dot, P)
    x_ddot, _ = accelerations(0.3, theta, 0.0, theta_dot, force, P.replace(c_p=0.0, v_p=0.0),
                              friction=False)
    assert x_ddot == pytest.approx(a, rel=1e-12)


def test_plugin_is_registered_and_refuses_bad_gains():
    assert load_controllers('swingup')['energy_saturated'] is EnergySaturatedSwingUp
    c = plugin()
    with pytest.raises(ValueError, match='n = 5 is above'):
        c.configure({'n': 5.0}, c.context)
    with pytest.raises(ValueError, match='leaves no travel'):
        c.configure({'rail_margin': 0.3, 'k': 3.0}, c.context.__class__(
            P.replace(travel=0.5), 0.25, P.sample_time))
    assert c.gains['k'] == DEFAULT_GAINS['k']  # a refused change changes nothing
    state = ControllerState(0.0, 0.0, math.pi, 0.0, 0.0)
    c.activate(state)
    assert c.update(state) > 0.0


@pytest.mark.slow
@pytest.mark.parametrize('stabilizer', ['pid', 'lqg', 'smc'])
def test_offline_from_the_left_stop_catches_within_2x_the_bound(stabilizer):
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    run = run_closed_loop(duration=14.0, manager_parameters={
        'swingup': 'energy_saturated', 'stabilizer': stabilizer})
    s = run.summary
    assert s['success'], s
    assert not s['end_stop_contact']
    assert s['catch_time_s'] <= 2.0 * LEFT_STOP_BOUND
