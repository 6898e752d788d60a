"""The loop's latency from the plant's reports, the commands in flight, and the prediction over them."""
import math

import numpy as np
import pytest

from cartpole_control.latency import LATENCY_MAX, CommandsInFlight, LatencyEstimator
from cartpole_control.manager import ControllerManager
from cartpole_core.model import CartPoleParameters, acceleration_function

P = CartPoleParameters()
ACC = acceleration_function(P)


def test_the_estimate_is_the_mean_of_the_window_and_zero_until_enough_reports():
    est = LatencyEstimator(window=4, min_reports=3)
    est.report(1.0, 1.010)
    est.report(1.005, 1.017)
    assert not est.ready and est.latency == 0.0          # two reports: no compensation yet
    est.report(1.010, 1.024)
    assert est.ready and est.latency == pytest.approx((0.010 + 0.012 + 0.014) / 3)
    for k in range(3, 8):                                # the window slides: only the last 4
        est.report(1.0 + 0.005 * k, 1.0 + 0.005 * k + 0.020)
    assert est.latency == pytest.approx(0.020) and est.reports == 8


@pytest.mark.parametrize('source, applied', [(1.0, 0.999), (1.0, 1.0 + LATENCY_MAX + 0.01),
                                             (1.0, math.nan)])
def test_impossible_reports_are_counted_and_left_out(source, applied):
    est = LatencyEstimator(window=4, min_reports=1)
    est.report(0.0, 0.02)
    est.report(source, applied)
    assert est.rejected == 1 and est.latency == pytest.approx(0.02)


def test_commands_in_flight_give_the_force_the_cart_feels_over_the_horizon():
    flight = CommandsInFlight()
    for k, force in enumerate([1.0, 2.0, 3.0, 4.0, 5.0]):   # samples at 0, 5, ..., 20 ms
        flight.sent(0.005 * k, force)
    # At t = 25 ms with 12 ms of latency: the command of the sample at 10 ms (3 N) acts
    # since 22 ms, the 15 ms one from 27 ms, the 20 ms one from 32 ms, up to 37 ms.
    segments = flight.segments(0.025, 0.012)
    assert [f for _, f in segments] == [3.0, 4.0, 5.0]
    assert [round(d, 9) for d, _ in segments] == [0.002, 0.005, 0.005]
    assert sum(d for d, _ in segments) == pytest.approx(0.012)
    # Within one sample the last command alone (the one-piece prediction of before).
    assert flight.segments(0.025, 0.003) == [(pytest.approx(0.003), 5.0)]
    assert flight.segments(0.025, 0.0) == []


def test_the_mean_force_over_an_interval_is_the_commands_delayed_and_one_command_is_itself():
    flight = CommandsInFlight()
    assert flight.mean_force(0.0, 0.005, 0.0) is None          # nothing sent
    for k, force in enumerate([1.0, 2.0, 3.0, 4.0, 5.0]):   # samples at 0, 5, ..., 20 ms
        flight.sent(0.005 * k, force)
    # Over [20, 25] ms with 7.5 ms of dead time: the 10 ms command (3 N) until 22.5 ms,
    # the 15 ms one (4 N) after it.
    assert flight.mean_force(0.020, 0.025, 0.0075) == pytest.approx(3.5)
    # No dead time: the last command alone, exactly (not a mean that rounds it).
    third = 1.0 / 3.0
    flight.sent(0.025, third)
    assert flight.mean_force(0.025, 0.030, 0.0) == third
    assert flight.mean_force(0.025, 0.025, 0.0) is None
    assert flight.last_stamp == 0.025


def test_the_plant_estimate_gives_the_force_acting_over_the_next_interval():
    """What the EKF predicts with: the commands delayed by latency + the compensated dead
    time, times the gain the commands were divided by; None for a cycle that sent nothing."""
    from cartpole_control.plant_estimate import PlantEstimate
    estimate = PlantEstimate(P, 0.005)
    for k, force in enumerate([10.0, 20.0, 30.0]):
        estimate.in_flight.sent(0.005 * k, force)
    estimate.used_gain, estimate.used_delay = 0.8, 0.0025
    assert estimate.dead_time == 0.0025
    assert estimate.acting_force(0.010) == pytest.approx(0.8 * 25.0)
    assert estimate.acting_force(0.015) is None
    # What the EKF gets: the acting force within the amplifier's range, else the command.
    assert estimate.force_for_filter(0.010, 99.0) == pytest.approx(20.0)
    assert estimate.force_for_filter(0.015, -3.0) == -3.0
    estimate.used_gain = 2.0
    estimate.in_flight.sent(0.015, 34.0)
    assert estimate.force_for_filter(0.015, 34.0) == P.force_max


def test_a_stamp_that_goes_back_starts_a_new_history():
    flight = CommandsInFlight()
    flight.sent(1.0, 5.0)
    flight.sent(0.0, -2.0)            # a plant reset: time starts again
    assert flight.segments(0.005, 0.02) == [(pytest.approx(0.02), -2.0)]


def test_auto_horizon_predicts_over_the_measured_latency():
    m = ControllerManager(P, stabilizer='lqg')
    assert m.get_parameters()['predict.horizon'] == 'auto'
    for k in range(40):
        m.command_applied(0.005 * k, 0.005 * k + 0.02)
    out = m.update_values(1.0, 0.38, 0.05, 0.1, 0.2)
    assert out.latency == pytest.approx(0.02) and out.horizon == pytest.approx(0.02)
    assert m.set_parameters({'predict.horizon': 0.01}).successful
    out = m.update_values(1.005, 0.38, 0.05, 0.1, 0.2)
    assert out.horizon == 0.01 and out.latency == pytest.approx(0.02)


@pytest.mark.parametrize('value, reason', [('fast', "'auto' or a number"), (-0.01, 'minimum'),
                                           (0.5, 'maximum')])
def test_a_bad_horizon_is_refused_and_the_old_one_kept(value, reason):
    m = ControllerManager(P)
    result = m.set_parameters({'predict.horizon': value})
    assert not result.successful and reason in result.reason
    assert m.get_parameters()['predict.horizon'] == 'auto'


def test_offline_the_estimate_is_within_1_ms_of_an_injected_20_ms_delay_after_2_s():
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario

    run = run_closed_loop(P, Scenario(noise=True, seed=0, delay=0.02), duration=2.0)
    assert abs(run.summary['latency_s'] - 0.02) <= 0.001
    assert run.summary['predict_horizon_s'] == run.summary['latency_s']
    plain = run_closed_loop(P, Scenario(noise=True, seed=0), duration=2.0)
    assert plain.summary['latency_s'] == 0.0      # this plant applies at the sample itself


def _velocity_errors(force_input, duration, **changes):
    """RMS of the EKF's x_dot [m/s] and theta_dot [rad/s] errors after 1 s, and its estimates."""
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_estimation.ekf import EkfConfig
    from cartpole_sim.plant import Scenario

    errors = []

    def observe(measurement, estimate, output, true):
        if estimate.t > 1.0:
            errors.append(((estimate.x_dot - true[2]) ** 2, (estimate.theta_dot - true[3]) ** 2))
    result = run_closed_loop(P, Scenario(noise=True, seed=changes.pop('seed', 0), **changes),
                             duration, ekf_config=EkfConfig(force_input=force_input),
                             observer=observe)
    n = len(errors)
    return (math.sqrt(sum(e[0] for e in errors) / n), math.sqrt(sum(e[1] for e in errors) / n),
            np.column_stack([result.x_dot_est, result.theta_dot_est, result.force]))


def test_on_a_nominal_plant_the_force_acting_is_the_command_bit_for_bit():
    """No latency, no dead time, gain 1 (offline): the EKF's input is the command itself."""
    *_, acting = _velocity_errors('acting', 3.0)
    *_, command = _velocity_errors('command', 3.0)
    assert (acting == command).all()


@pytest.mark.slow
@pytest.mark.parametrize('changes', [{'delay': 0.02},
                                     {'seed': 1, 'actuator_gain': 0.75, 'actuator_tau': 0.02,
                                      'delay': 0.015}])
def test_the_ekf_fed_the_force_as_it_acts_tracks_the_velocities_better(changes):
    """20 ms of delay, or a weak (0.75), slow (20 ms lag) amplifier 15 ms late: fed the force
    the manager estimates acts, the EKF's velocity errors are at most 0.6 of those with the
    command as sent (measured: 0.31 / 0.38 and 0.45 / 0.47 of them)."""
    x_acting, theta_acting, _ = _velocity_errors('acting', 8.0, **changes)
    x_command, theta_command, _ = _velocity_errors('command', 8.0, **changes)
    assert x_acting < 0.6 * x_command and theta_acting < 0.6 * theta_command
