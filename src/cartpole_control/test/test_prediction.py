"""Delay compensation by prediction: the midpoint step against a fine integration, and the loop it saves."""
import math

import pytest

from cartpole_control.prediction import predict_over_commands, predict_state
from cartpole_core.model import CartPoleParameters, acceleration_function
from manager_test_support import THESIS_INTEGRAL

P = CartPoleParameters()
ACC = acceleration_function(P)


def fine_integration(state, force, horizon, steps=2000):
    x, theta, x_dot, theta_dot = state
    h = horizon / steps
    for _ in range(steps):
        x_ddot, theta_ddot = ACC(x, theta, x_dot, theta_dot, force)
        x, theta = x + h * x_dot + 0.5 * h * h * x_ddot, theta + h * theta_dot + 0.5 * h * h * theta_ddot
        x_dot, theta_dot = x_dot + h * x_ddot, theta_dot + h * theta_ddot
    return x, theta, x_dot, theta_dot


def test_zero_horizon_is_the_estimate_itself():
    state = (0.3, 0.1, 0.2, -0.5)
    assert predict_state(ACC, *state, 5.0, 0.0) == state


@pytest.mark.parametrize('state, force', [((0.38, 0.05, 0.1, 0.4), 8.0),
                                          ((0.2, -0.3, -0.5, 2.0), -15.0),
                                          ((0.5, math.pi - 0.2, 0.8, 6.0), 3.0)])
def test_the_prediction_follows_the_model_over_the_delay(state, force):
    # 15 ms ahead: the midpoint step against 2000 small steps of the same model, and
    # much closer to it than the estimate left alone (the error a delayed loop acts on).
    horizon = 0.015
    predicted = predict_state(ACC, *state, force, horizon)
    reference = fine_integration(state, force, horizon)
    for p, r, s in zip(predicted, reference, state):
        assert abs(p - r) <= 0.05 * abs(s - r) + 1e-6


def test_the_prediction_over_the_commands_in_flight_follows_the_model():
    # 40 ms ahead with eight commands in flight, against a fine integration of the
    # same piecewise force; predicting under the last command alone is far off.
    state = (0.38, 0.08, 0.2, 0.6)
    segments = [(0.005, f) for f in (-20.0, -12.0, -5.0, 2.0, 8.0, 14.0, 18.0, 20.0)]
    reference = state
    for duration, force in segments:
        reference = fine_integration(reference, force, duration, steps=400)
    predicted = predict_over_commands(ACC, *state, segments)
    last_only = predict_state(ACC, *state, 20.0, 0.04)
    for p, r, w in zip(predicted, reference, last_only):
        assert abs(p - r) <= 1e-3 * max(1.0, abs(r))
        assert abs(p - r) < 0.05 * abs(w - r)


@pytest.mark.slow
def test_the_prediction_saves_lqg_under_25_ms_of_delay():
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario

    from cartpole_estimation.ekf_config import EkfConfig

    scenario = Scenario(noise=True, seed=0, delay=0.025, jitter=0.005)
    # With nothing for the dead time the loop is marginal under 25 ms and the catch decides:
    # the swing-up's energy integral as the thesis has it (the catch 0.8 % above E*, as when
    # this was found); with the one confined near E* (1 % below) the force as it acts alone
    # holds seeds 0-15 in 5 of 16 (14 of 16 with the thesis's), the command as sent 0 and 0.
    unpredicted = {'stabilizer': 'lqg', 'predict.horizon': 0.0, 'actuator.delay': 0.0,
                   'lqg.dead_time_weight_max': 1.0, **THESIS_INTEGRAL}
    # The EKF fed the command as sent (the thesis's): nothing in the loop knows the delay.
    plain = run_closed_loop(P, scenario, duration=20.0, stop_on_failure=True,
                            manager_parameters=unpredicted,
                            ekf_config=EkfConfig(force_input='command'))
    predicted = run_closed_loop(P, scenario, duration=20.0,
                                manager_parameters={'stabilizer': 'lqg',
                                                    'predict.horizon': 0.015,
                                                    'lqg.dead_time_weight_max': 1.0})
    assert not plain.summary['success']
    assert predicted.summary['success']
    assert not predicted.end_stop_contact
    # The gain solved at the catch for the measured dead time (R x 5) saves it too.
    weighted = run_closed_loop(P, scenario, duration=20.0,
                               manager_parameters={'stabilizer': 'lqg', 'predict.horizon': 0.0,
                                                   'actuator.delay': 0.0})
    assert weighted.summary['success'] and not weighted.end_stop_contact
    # And so does the EKF fed the force as the measured latency says it acts.
    acting = run_closed_loop(P, scenario, duration=20.0, manager_parameters=unpredicted)
    assert acting.summary['success'] and not acting.end_stop_contact
