"""Directions, lifecycle and discovery of the six controller plugins (pure, no ROS)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cartpole_control import registry
from cartpole_control.controller import (API_VERSION, STABILIZER, SWINGUP, CommandFeedback,
                                         ControlContext, Controller, ControllerState)
from cartpole_control.manager import ControllerManager
from cartpole_control.controllers.full_energy import FullEnergySwingUp
from cartpole_control.controllers.pendulum_energy import PendulumEnergySwingUp
from cartpole_control.controllers.pid import PidStabilizer
from cartpole_control.controllers.sign_based import SignBasedSwingUp
from cartpole_core.model import CartPoleParameters, accelerations, pendulum_energy, system_energy

PARAMS = CartPoleParameters()
X_REF = PARAMS.x_middle
CONTEXT = ControlContext(plant=PARAMS, x_ref=X_REF, sample_time=PARAMS.sample_time)
SWINGUPS = ('full_energy', 'pendulum_energy', 'sign_based')
STABILIZERS = ('lqg', 'pid', 'smc')


def make(kind, name, **gains):
    controller = registry.create(kind, name)
    controller.configure(gains, CONTEXT)
    return controller


def consistent_state(t, x, theta, x_dot, theta_dot, force=0.0):
    """A state with the model accelerations under ``force`` filled in, as the manager does."""
    x_ddot, theta_ddot = accelerations(x, theta, x_dot, theta_dot, force, PARAMS, friction=False)
    return ControllerState(t, x, theta, x_dot, theta_dot, x_ddot, theta_ddot)


# -- discovery -------------------------------------------------------------------
def test_registry_finds_all_six_by_entry_point():
    swingups = registry.load_controllers(SWINGUP)
    stabilizers = registry.load_controllers(STABILIZER)
    assert set(SWINGUPS) <= set(swingups)
    assert set(STABILIZERS) <= set(stabilizers)
    for kind, found in ((SWINGUP, swingups), (STABILIZER, stabilizers)):
        for name, cls in found.items():
            if name in SWINGUPS + STABILIZERS:
                assert issubclass(cls, Controller)
                assert cls.name == name and cls.kind == kind
                assert cls.api_version == API_VERSION


def test_registry_refuses_an_unknown_name_with_the_list():
    with pytest.raises(ValueError, match='unknown stabilizer controller') as info:
        registry.create(STABILIZER, 'lqr')
    for name in STABILIZERS:
        assert name in str(info.value)
    with pytest.raises(ValueError, match='pendulum_energy'):
        registry.create(SWINGUP, 'energy')


@pytest.mark.parametrize('kind, name', [(SWINGUP, n) for n in SWINGUPS]
                         + [(STABILIZER, n) for n in STABILIZERS])
def test_parameters_have_thesis_descriptions_and_valid_defaults(kind, name):
    cls = registry.load_controllers(kind)[name]
    assert cls.parameters, name
    for spec in cls.parameters:
        assert spec.validate(spec.default) == spec.default     # defaults pass their own ranges
        assert '[' in spec.description, f'{name}.{spec.name}: no unit'
    assert cls.validate_gains(cls.defaults()) == cls.defaults()


# -- swing-up directions ----------------------------------------------------------------
@pytest.mark.parametrize('name', SWINGUPS)
def test_first_push_from_the_left_stop_is_to_the_right(name):
    controller = make(SWINGUP, name)
    state = consistent_state(0.0, 0.0, math.pi, 0.0, 0.0)
    controller.activate(state)
    force = controller.update(state)
    assert math.isfinite(force) and force > 0.0
    # ... and from the right end it pulls left.
    state = consistent_state(0.0, PARAMS.travel, math.pi, 0.0, 0.0)
    controller.activate(state)
    assert controller.update(state) < 0.0


@pytest.mark.parametrize('name', ['pendulum_energy', 'sign_based'])
@pytest.mark.parametrize('theta, theta_dot', [(math.pi - 0.4, 2.0), (math.pi + 0.4, 2.0),
                                               (math.pi - 0.4, -2.0), (2.0, 3.0), (-2.5, -1.5)])
def test_energy_laws_pump_below_and_drain_above_e_star(name, theta, theta_dot):
    """dE_p/dt = m_p l u theta_dot cos(theta) (7.4) > 0 while E_p < E*, < 0 above."""
    controller = make(SWINGUP, name)
    for speed, grows in ((theta_dot, True), (theta_dot * 10.0, False)):
        state = consistent_state(1.0, X_REF, theta, 0.0, speed)
        below = pendulum_energy(theta, speed, PARAMS) < PARAMS.upright_energy
        assert below == grows
        controller.activate(state)
        u = controller.acceleration(state)
        energy_rate = PARAMS.m_p * PARAMS.l * u * speed * math.cos(theta)
        assert (energy_rate > 0.0) == grows, (u, energy_rate)


def test_sign_based_is_a_saturated_sign_of_u_max_as_acceleration():
    sb = make(SWINGUP, 'sign_based')
    state = consistent_state(0.0, X_REF, math.pi - 0.4, 0.0, 2.0)
    assert sb.acceleration(state) == pytest.approx(-1.0)          # cos < 0, theta_dot > 0
    force = sb.update(state)
    assert -6.0 < force < -3.0          # u_max = 1 m/s^2 is about 5 N on the 5 kg cart
    sb.configure({'width': 50.0}, CONTEXT)
    assert -1.0 < sb.acceleration(state) < 0.0                    # linear zone


def test_pendulum_energy_integral_accumulates_the_deficit_near_e_star_and_is_bounded():
    pe = make(SWINGUP, 'pendulum_energy', i_max=1.0)
    state = consistent_state(0.0, X_REF, 0.3, 0.0, 1.0)        # 2 % short of E*: in the band
    pe.activate(state)
    deficit = PARAMS.upright_energy - pendulum_energy(state.theta, state.theta_dot, PARAMS)
    assert 0.0 < deficit <= pe.gains['i_band'] * PARAMS.upright_energy
    for k in range(1, 101):
        pe.update(consistent_state(k * 0.005, X_REF, 0.3, 0.0, 1.0))
    assert pe.integral == pytest.approx(100 * 0.005 * deficit)
    for k in range(101, 20001):
        pe.update(consistent_state(k * 0.005, X_REF, 0.3, 0.0, 1.0))
    assert pe.integral == pe.gains['i_max']


def test_pendulum_energy_integral_holds_far_from_e_star():
    """Conditional integration: hanging (E_p far below E*) the integral does not wind up, and
    with ``i_band`` 1000 (the thesis law) it does."""
    held, thesis = make(SWINGUP, 'pendulum_energy'), make(SWINGUP, 'pendulum_energy', i_band=1000.0)
    state = consistent_state(0.0, X_REF, math.pi - 0.3, 0.0, 1.0)
    deficit = PARAMS.upright_energy - pendulum_energy(state.theta, state.theta_dot, PARAMS)
    for pe in (held, thesis):
        pe.activate(state)
        for k in range(1, 101):
            pe.update(consistent_state(k * 0.005, X_REF, math.pi - 0.3, 0.0, 1.0))
    assert held.integral == 0.0
    assert thesis.integral == pytest.approx(100 * 0.005 * deficit)


def test_full_energy_law_gives_v2_dot_equal_to_minus_k_d_x_dot_squared():
    """With k_i = 0, (7.20) makes dV_2/dt = -k_d x_dot^2 (7.21) on the frictionless model."""
    fe = make(SWINGUP, 'full_energy', k_i=0.0)
    rng = np.random.default_rng(3)
    g = fe.gains
    for _ in range(200):
        x, theta, x_dot, theta_dot = rng.uniform([0.0, -4.0, -1.0, -8.0], [0.769, 4.0, 1.0, 8.0])
        state = consistent_state(0.0, x, theta, x_dot, theta_dot)
        fe.activate(state)
        u = fe.update(state)
        x_ddot, _ = accelerations(x, theta, x_dot, theta_dot, u, PARAMS, friction=False)
        error = PARAMS.upright_energy - system_energy(np.array([x, theta, x_dot, theta_dot]),
                                                      PARAMS)
        v2_dot = (-g['k_e'] * error * x_dot * u + g['k_v'] * x_dot * x_ddot
                  - g['k_x'] * (X_REF - x) * x_dot)                       # (7.15), E_dot = x_dot u
        assert v2_dot == pytest.approx(-g['k_d'] * x_dot ** 2, abs=1e-6 * (1 + abs(u)))


def test_full_energy_integral_term_pumps_with_theta_dot_cos_theta():
    fe = make(SWINGUP, 'full_energy', k_x=0.0, k_d=0.0)
    state = consistent_state(0.0, X_REF, math.pi, 0.0, 0.0)
    fe.activate(state)
    for k in range(1, 201):                 # 1 s hanging: the integral grows by about E* s
        fe.update(consistent_state(k * 0.005, X_REF, math.pi, 0.0, 0.0))
    assert fe.integral == pytest.approx(PARAMS.upright_energy, rel=1e-9)
    swinging = consistent_state(1.005, X_REF, math.pi, 0.0, 2.0)  # theta_dot cos theta = -2
    assert fe.update(swinging) < 0.0
    # Above E* the integral term is gated off: only the (7.20) part remains.
    above = consistent_state(1.01, X_REF, math.pi, 0.0, 12.0)
    assert fe.energy_error(above) < 0.0
    without = make(SWINGUP, 'full_energy', k_x=0.0, k_d=0.0, k_i=0.0)
    without.activate(above)
    assert fe.update(above) == pytest.approx(without.update(above))
    assert fe.integral > 0.0


# -- stabiliser directions -----------------------------------------------------------
@pytest.mark.parametrize('name', STABILIZERS)
@pytest.mark.parametrize('lean, direction', [(-0.1, +1.0), (0.1, -1.0)])
def test_stabilisers_push_the_cart_under_the_leaning_pendulum(name, lean, direction):
    """theta < 0 leans right (tip at x - l sin theta > x): the cart must go right."""
    controller = make(STABILIZER, name)
    state = consistent_state(0.0, X_REF, lean, 0.0, 0.0)
    controller.activate(state)
    force = controller.update(state)
    assert force * direction > 5.0, force


@pytest.mark.parametrize('name', STABILIZERS)
def test_stabilisers_use_the_wrapped_angle(name):
    a, b = make(STABILIZER, name), make(STABILIZER, name)
    s1 = consistent_state(0.0, X_REF + 0.02, 0.05, 0.1, -0.2)
    s2 = consistent_state(0.0, X_REF + 0.02, 0.05 + 4 * math.pi, 0.1, -0.2)
    a.activate(s1)
    b.activate(s2)
    assert b.update(s2) == pytest.approx(a.update(s1), rel=1e-9)


@pytest.mark.parametrize('name', STABILIZERS)
def test_stabilisers_hold_the_upright_equilibrium(name):
    controller = make(STABILIZER, name)
    state = consistent_state(0.0, X_REF, 0.0, 0.0, 0.0)
    controller.activate(state)
    assert controller.update(state) == pytest.approx(0.0, abs=1e-9)


# -- lifecycle ----------------------------------------------------------------------
@pytest.mark.parametrize('kind, name', [(SWINGUP, n) for n in SWINGUPS]
                         + [(STABILIZER, n) for n in STABILIZERS])
def test_activation_is_bumpless_and_resets_integrators(kind, name):
    """After any history, activating at a state gives the output of a fresh controller there."""
    used = make(kind, name)
    start = consistent_state(0.0, 0.2, 0.3, 0.1, -0.5)
    used.activate(start)
    for k in range(1, 400):
        used.update(consistent_state(k * 0.005, 0.2, 0.3 + 0.001 * k, 0.1, -0.5))
    catch = consistent_state(7.3, 0.35, -0.4, -0.2, 2.5)
    used.activate(catch)
    fresh = make(kind, name)
    fresh.activate(catch)
    first = used.update(catch)
    assert math.isfinite(first)
    assert first == pytest.approx(fresh.update(catch), rel=1e-12, abs=1e-12)
    for attr in ('integral', 'integral_x', 'integral_theta'):
        if hasattr(used, attr):
            assert getattr(used, attr) == 0.0


def _integrals(controller):
    return [getattr(controller, a) for a in ('integral', 'integral_x', 'integral_theta')
            if hasattr(controller, a)]


RIGHT_OF_X_REF = 0.01
"""The cart 1 cm right of x*, pendulum upright at rest: every law's integral then pushes the
force to the right (positive). The cart must first move right so that the pendulum leans
left and then carries it back left (the non-minimum phase of the cart position): the
steady-state gain of every stabiliser on x - x* is positive, and so is its integral's."""


def _hold_right_of_x_ref(controller, feedback, steps=200):
    state = consistent_state(0.0, X_REF + RIGHT_OF_X_REF, 0.0, 0.0, 0.0)
    controller.activate(state)
    first = controller.update(state)
    controller.command_applied(feedback)
    last = first
    for k in range(1, steps):
        last = controller.update(consistent_state(k * 0.005, X_REF + RIGHT_OF_X_REF, 0.0, 0.0,
                                                  0.0))
        controller.command_applied(feedback)
    return first, last


@pytest.mark.parametrize('name', STABILIZERS)
def test_integrators_integrate_the_cart_error_when_the_command_passes(name):
    controller = make(STABILIZER, name)
    first, last = _hold_right_of_x_ref(controller, CommandFeedback(raw=1.0, force=4.0, limited=0))
    assert any(abs(v) > 1e-4 for v in _integrals(controller)), _integrals(controller)
    assert last > first + 0.5   # the integral action pushes right, ever harder


@pytest.mark.parametrize('name', STABILIZERS)
@pytest.mark.parametrize('feedback', [
    CommandFeedback(raw=60.0, force=34.25, limited=1),            # saturated at force_max
    CommandFeedback(raw=3.0, force=0.0, limited=1),               # rail guard withheld a push right
    CommandFeedback(raw=-3.0, force=12.0, limited=-1, held=True),  # rail guard braking
], ids=['saturated', 'rail-guard-limited', 'rail-guard-holds'])
def test_integrators_do_not_wind_up_while_the_command_is_cut_or_held(name, feedback):
    controller = make(STABILIZER, name)
    first, last = _hold_right_of_x_ref(controller, feedback)
    assert all(v == 0.0 for v in _integrals(controller)), _integrals(controller)
    # still the law without its integral, up to this cycle's increment (taken back after it)
    assert last == pytest.approx(first, abs=0.05)


@pytest.mark.parametrize('name', STABILIZERS)
def test_a_command_cut_the_other_way_does_not_stop_the_integrator(name):
    """Saturated at force_min while the integrator pushes the force up: it keeps integrating."""
    controller = make(STABILIZER, name)
    _hold_right_of_x_ref(controller, CommandFeedback(raw=-60.0, force=-37.36, limited=-1), 40)
    assert any(abs(v) > 1e-4 for v in _integrals(controller))


def test_pid_outer_integrator_holds_while_theta_ref_is_limited():
    pid = make(STABILIZER, 'pid')
    far = consistent_state(0.0, 0.0, 0.0, 0.0, 0.0)         # cart 0.38 m off: theta* limited
    pid.activate(far)
    for k in range(1, 50):
        pid.update(consistent_state(k * 0.005, 0.0, 0.0, -1.5, 0.0))
    assert abs(pid.theta_ref) == pytest.approx(pid.gains['theta_max'])
    assert pid.integral_x == 0.0


@pytest.mark.slow
@pytest.mark.parametrize('name', STABILIZERS)
def test_integrators_in_the_manager_stay_put_while_the_force_saturates(name):
    """The manager's own feedback: a stabiliser held at force_min does not wind up.

    The state is a pendulum leaning far right with the cart right of x*: the
    law wants far more than the amplifier's -37 N... in the manager, which
    reports the cut to the plugin every cycle.
    """
    manager = ControllerManager(PARAMS, stabilizer=name)
    manager.update_values(0.0, X_REF, math.pi, 0.0, 0.0)       # hanging: swing-up
    t = 0.005
    out = manager.update_values(t, X_REF + 0.05, 0.0, 0.0, 0.0)  # upright at rest: a catch
    assert out.mode == 'stabilizing'
    plugin = manager.active_plugins()[STABILIZER]
    for k in range(2, 60):
        t = k * 0.005
        out = manager.update_values(t, X_REF + 0.05, -0.35, 0.0, -3.0)
        assert out.force == pytest.approx(PARAMS.force_max) or out.force == pytest.approx(
            PARAMS.force_min), out.force
    integrals = _integrals(plugin)
    pushed = [abs(v) for v in integrals]
    assert max(pushed) < 1e-2, integrals


def test_stateless_laws_are_deterministic():
    for kind, name in ((SWINGUP, 'sign_based'), (STABILIZER, 'lqg'), (STABILIZER, 'smc')):
        c = make(kind, name)
        state = consistent_state(1.0, 0.3, 0.2, 0.1, -0.3)
        c.activate(state)
        assert c.update(state) == c.update(state)


def test_plugin_classes_are_the_entry_points():
    found = registry.load_controllers(SWINGUP)
    assert found['full_energy'] is FullEnergySwingUp
    assert found['pendulum_energy'] is PendulumEnergySwingUp
    assert found['sign_based'] is SignBasedSwingUp
    assert registry.load_controllers(STABILIZER)['pid'] is PidStabilizer
