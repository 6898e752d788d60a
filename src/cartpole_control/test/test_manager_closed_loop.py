"""ControllerManager in closed loops on the simulated plant (rail guard, swing-up, catch,
switching, through the EKF), and the per-cycle fast paths against the plain ones."""
import math

import pytest

from cartpole_control.controller import ControllerState
from cartpole_control.manager import FAULT, STABILIZING, SWINGUP_MODE, ControllerManager
from cartpole_control.rail_guard import LIMITED
from cartpole_core.model import wrap_angle
from cartpole_sim.plant import Plant, Scenario
from manager_test_support import P, TS, make, state


# -- closed loops on the simulated plant (true state as the estimate) --------------------------
def run(manager, plant, seconds, on_step=None):
    outs = []
    for k in range(int(round(seconds / TS))):
        if on_step is not None:
            on_step(k, plant)
        s = plant.true_state()
        out = manager.update(ControllerState(plant.t, *s))
        outs.append(out)
        plant.step(out.force)
    return outs


def test_rail_guard_limiter_holds_a_controller_pushing_into_the_stop_without_a_fault():
    m = make(swingup='push_a', **{'push_a.force': 100.0})
    plant = Plant(P, Scenario(x0=P.x_middle))
    outs = run(m, plant, 1.5)
    assert not plant.end_stop_contact
    assert all(o.mode == SWINGUP_MODE and not o.event for o in outs)
    assert m.guard_status == LIMITED
    assert plant.true_state()[0] < P.travel - 0.02


def test_rail_guard_overrides_a_controller_pushing_into_the_stop():
    # The trip path: with the limiter off the guard trips at once.
    m = make(swingup='push_a', **{'push_a.force': 100.0, 'rail.limit': False})
    plant = Plant(P, Scenario(x0=P.x_middle))
    outs = run(m, plant, 1.5)
    assert not plant.end_stop_contact
    assert outs[-1].mode == FAULT and outs[-1].fault_reason == 'rail guard'
    assert outs[-1].force == 0.0
    assert sum(o.event == 'fault:rail guard' for o in outs) == 1
    assert abs(plant.true_state()[2]) < 0.05
    assert min(o.force for o in outs) < -25.0  # it braked, not just zeroed
    # Restart re-arms: back to the (still pushing) swing-up, now at rest near the stop.
    m.set_parameters({'push_a.force': -2.0})
    m.restart()
    out = m.update(ControllerState(plant.t, *plant.true_state()))
    assert out.mode == SWINGUP_MODE and out.force < 0.0


def test_rail_guard_at_the_left_stop_at_rest_lets_the_swingup_start():
    """Default start (x = 0, at rest): no trip; pushing into the stop withheld, out allowed."""
    m = make(swingup='push_a', **{'push_a.force': -5.0})
    plant = Plant(P, Scenario())
    outs = run(m, plant, 0.2)
    assert all(o.force == 0.0 and o.mode == SWINGUP_MODE for o in outs)
    m.set_parameters({'push_a.force': 2.0})
    outs = run(m, plant, 0.5)
    assert outs[-1].mode == SWINGUP_MODE and plant.true_state()[0] > 0.03


def test_without_feedforward_the_swingup_never_leaves_the_left_stop():
    """The first centring push (~1.9 N) is below the 3.4 N Coulomb friction
    (docs/controller_manager.md, "Modes and transitions")."""
    for steepness, moves in ((0.0, False), (20.0, True)):
        m = ControllerManager(P, **{'feedforward.steepness': steepness})
        plant = Plant(P, Scenario())
        outs = run(m, plant, 1.0)
        assert 1.5 < outs[0].raw_force < 2.5
        assert bool(plant.true_state()[0] > 0.01) is moves


def test_swingup_catch_and_switching_stabilisers_keeps_the_pendulum_up():
    m = ControllerManager(P)  # pendulum_energy + lqg
    plant = Plant(P, Scenario())
    outs = run(m, plant, 7.0)
    assert outs[-1].mode == STABILIZING and outs[-1].catch_count == 1
    assert 2.0 < outs[-1].catch_time < 7.0  # 2.8 s with the default gains, 4.8 s with the thesis k_e
    for name in ('smc', 'pid', 'lqg'):
        assert m.set_parameters({'stabilizer': name}).successful
        angles = []
        outs = run(m, plant, 2.5, lambda k, pl: angles.append(abs(wrap_angle(pl.state[1]))))
        assert outs[0].event == f'switch:stabilizer={name}' and outs[0].stabilizer == name
        assert all(o.mode == STABILIZING for o in outs)
        assert max(angles) < math.radians(3.0), name
    assert outs[-1].fall_count == 0 and not plant.end_stop_contact
    assert abs(plant.true_state()[0] - P.x_middle) < 0.1


def test_switching_the_swingup_while_swinging_keeps_swinging():
    m = ControllerManager(P, swingup='pendulum_energy')
    plant = Plant(P, Scenario(x0=P.x_middle))
    outs = run(m, plant, 2.0)
    assert outs[-1].mode == SWINGUP_MODE
    energy_before = max(o.energy for o in outs)
    assert m.set_parameters({'swingup': 'sign_based'}).successful
    outs = run(m, plant, 10.0)
    assert outs[0].event == 'switch:swingup=sign_based'
    assert max(o.energy for o in outs) > energy_before
    assert outs[-1].catch_count >= 1 and outs[-1].mode == STABILIZING
    assert not plant.end_stop_contact


def test_closed_loop_through_the_ekf_catches_and_switches_without_losing_the_pendulum():
    """The architecture's cycle: quantised measurement -> EKF -> manager -> plant (ZOH)."""
    ekf_module = pytest.importorskip('cartpole_estimation.ekf')
    ekf = ekf_module.ExtendedKalmanFilter(P)
    m = ControllerManager(P)
    plant = Plant(P, Scenario(theta0=math.pi + 0.03))
    force, angles, outs = 0.0, [], []
    switches = {9.0: 'smc', 11.0: 'pid', 13.0: 'lqg'}
    for k in range(int(15.0 / TS)):
        t = k * TS
        if round(t, 6) in switches:
            assert m.set_parameters({'stabilizer': switches[round(t, 6)]}).successful
        meas = plant.measure()
        est = ekf.update(meas.t, meas.x, meas.theta, force)
        out = m.update(ControllerState(est.t, est.x, est.theta, est.x_dot, est.theta_dot))
        outs.append(out)
        force = out.force
        plant.step(force)
        if t > 8.0:
            angles.append(abs(wrap_angle(plant.state[1])))
    assert outs[-1].catch_time is not None and outs[-1].catch_time < 8.0
    assert [o.event for o in outs if o.event.startswith('switch')] == [
        'switch:stabilizer=smc', 'switch:stabilizer=pid', 'switch:stabilizer=lqg']
    assert outs[-1].mode == STABILIZING and outs[-1].fall_count == 0
    assert max(angles) < math.radians(3.0)
    assert not plant.end_stop_contact


# -- the per-cycle fast paths give the same cycle ------------------------------------------------
def test_update_values_gives_the_same_cycle_as_update():
    """The offline loop's entry (the estimate as numbers) and update(ControllerState) agree
    to the bit, through swing-up, catch and stabilisation."""
    a, b = ControllerManager(P), ControllerManager(P)
    plant = Plant(P, Scenario())
    for _ in range(int(7.0 / TS)):
        x, theta, x_dot, theta_dot = plant.state
        out_a = a.update(ControllerState(plant.t, x, theta, x_dot, theta_dot))
        out_b = b.update_values(plant.t, x, theta, x_dot, theta_dot)
        assert out_a == out_b
        plant.step(out_a.force)
    assert out_a.mode == STABILIZING and out_a.catch_count == 1
