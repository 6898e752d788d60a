"""The loop's latency from the plant's reports, the commands in flight, and the prediction over them."""
import math

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
