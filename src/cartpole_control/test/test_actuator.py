"""The actuator's gain and extra dead time, estimated from the cart's motion, and the loop that uses them."""
import math

import pytest

from cartpole_control.actuator import ActuatorEstimator
from cartpole_control.manager import ControllerManager
from cartpole_core.model import CartPoleParameters, accelerations

P = CartPoleParameters()


def shaken(gain=1.0, dead_time=0.0, seconds=4.0, ts=0.005):
    """(estimator, commands): a cart shaken by a commanded force that acts ``dead_time``
    late and ``gain`` times as strong, the pendulum swinging, sampled every ``ts``."""
    est = ActuatorEstimator(P)
    h = 0.0005
    x, th, xd, thd = 0.38, math.pi - 0.3, 0.0, 0.0
    per = int(round(ts / h))
    command = 0.0
    history = []
    for k in range(int(seconds / h) + 1):
        t = k * h
        if k % per == 0:
            est.update(t, x, th)
            command = 20.0 * math.sin(2 * math.pi * 1.3 * t) + 8.0 * math.sin(2 * math.pi * 3.1 * t)
            est.applied(t, command)
            history.append((t, command))
        late = t - dead_time
        acting = 0.0
        for t_c, c in history:
            if t_c <= late:
                acting = c
            else:
                break
        xdd, thdd = accelerations(x, th, xd, thd, gain * acting, P)
        x, th, xd, thd = x + h * xd, th + h * thd, xd + h * xdd, thd + h * thdd
    return est


@pytest.mark.parametrize('gain, dead_time', [(1.0, 0.0), (0.6, 0.0), (1.0, 0.03), (1.5, 0.05)])
def test_the_estimate_finds_the_gain_and_the_dead_time_of_the_actuator(gain, dead_time):
    est = shaken(gain, dead_time)
    assert est.ready
    assert est.gain == pytest.approx(gain, rel=0.05)
    assert est.delay == pytest.approx(dead_time, abs=0.0051)


def test_without_commands_or_near_a_stop_nothing_is_learnt():
    est = ActuatorEstimator(P)
    for k in range(200):
        est.update(0.005 * k, 0.001 * k, math.pi)       # moving, but no command known
    assert est.windows == 0 and est.gain == 1.0
    for k in range(200, 400):
        est.applied(0.005 * k, 20.0)
        est.update(0.005 * k, 0.002, math.pi)           # at the left stop: the stop pushes
    assert est.windows == 0 and est.gain == 1.0


def test_the_manager_divides_the_command_by_the_gain_within_the_amplifier_range():
    m = ControllerManager(P, stabilizer='lqg', **{'actuator.gain': 0.5, 'predict.horizon': 0.0})
    nominal = ControllerManager(P, stabilizer='lqg', **{'actuator.gain': 1.0,
                                                        'predict.horizon': 0.0})
    for manager in (m, nominal):
        manager.update_values(0.0, 0.38, 0.002, 0.0, 0.0)   # catch (upright, at rest)
    weak = m.update_values(0.005, 0.38, 0.002, 0.0, 0.005)
    ref = nominal.update_values(0.005, 0.38, 0.002, 0.0, 0.005)
    assert weak.mode == ref.mode == 'stabilizing'
    assert weak.actuator_gain == 0.5
    assert weak.force == pytest.approx(2.0 * ref.force)
    big = m.update_values(0.010, 0.38, 0.2, 0.0, 1.0)     # wants more than 0.5 x 34 N
    assert P.force_min <= big.force <= P.force_max


@pytest.mark.slow
@pytest.mark.parametrize('changes', [{'actuator_gain': 0.6}, {'actuator_tau': 0.06}],
                         ids=['gain x0.6', 'lag 60 ms'])
def test_the_default_pair_swings_up_and_balances_with_a_weak_or_slow_actuator(changes):
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario

    run = run_closed_loop(P, Scenario(noise=True, seed=0, **changes), duration=25.0,
                          stop_on_failure=True)
    assert run.summary['success'], run.summary
    fixed = run_closed_loop(P, Scenario(noise=True, seed=0, **changes), duration=25.0,
                            stop_on_failure=True,
                            manager_parameters={'actuator.gain': 1.0, 'actuator.delay': 0.0})
    assert not fixed.summary['success']            # the nominal actuator model loses it
