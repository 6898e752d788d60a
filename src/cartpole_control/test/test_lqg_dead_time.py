"""The LQR solved again at the catch for the loop's dead time: R weighed, the pendulum's weights
cut back (lost samples count as dead time), and with none the configured, precise gain."""
from __future__ import annotations

import random
from dataclasses import replace

import numpy as np
import pytest

from cartpole_control.controller import ControlContext, ControllerState
from cartpole_control.controllers.lqg import (DEAD_TIME_WEIGHT_MAX, PENDULUM_WEIGHT_MIN,
                                              LqgStabilizer, dead_time_pendulum_share,
                                              dead_time_weight, lqi_gain)
from cartpole_control.latency import LATENCY_MAX, SampleAge
from cartpole_control.plant_estimate import PlantEstimate
from cartpole_core.model import CartPoleParameters, linearise_upright

PARAMS = CartPoleParameters()
CONTEXT = ControlContext(plant=PARAMS, x_ref=PARAMS.x_middle, sample_time=PARAMS.sample_time)
TS = PARAMS.sample_time
UPRIGHT = ControllerState(0.0, PARAMS.x_middle, 0.0, 0.0, 0.0)
ROBUST_Q = (10.0, 10000.0, 10.0, 1.0, 400.0)
"""The weights the default q becomes under a long dead time: lqg's default before the precise
one, the gain every combined-benchmark figure up to 2026-12-05 was measured with."""


def expected_gain(weights, r):
    a, b = linearise_upright(PARAMS)
    return lqi_gain(a, b, np.diag(weights[:4]), np.array([[r]]), weights[4])[0][:4]


def manager_controller():
    estimate = PlantEstimate(PARAMS, TS)
    controller = LqgStabilizer()
    controller.configure({}, replace(CONTEXT, plant_estimate=estimate))
    return estimate, controller


def test_the_weights_of_r_and_of_the_pendulum_by_dead_time():
    assert dead_time_weight(0.01, 0.0) == 0.01
    assert dead_time_weight(0.01, 0.005) == pytest.approx(0.0125)
    assert dead_time_weight(0.01, 0.05) == pytest.approx(0.01 * DEAD_TIME_WEIGHT_MAX)
    assert dead_time_weight(0.01, 0.05, 1.0) == 0.01
    assert dead_time_pendulum_share(0.0) == 1.0
    assert dead_time_pendulum_share(0.005) == pytest.approx(0.5)
    assert dead_time_pendulum_share(0.02) == pytest.approx(PENDULUM_WEIGHT_MIN)
    assert dead_time_pendulum_share(0.02, 1.0) == 1.0


def test_at_the_catch_a_20_ms_dead_time_gives_the_robust_gain_and_none_the_precise_one():
    """With no dead time the configured gain stays (q's pendulum weights three times the robust
    ones: the nominal precision); with the 20 ms the manager measured, R weighs its most
    (``DEAD_TIME_WEIGHT_MAX`` R; 5 R uncapped) and the pendulum's weights are cut to a third:
    exactly the robust weights' gain at that R."""
    estimate, controller = manager_controller()
    precise = controller.gain.copy()
    weights = controller.gains['q']
    assert tuple(weights) == (ROBUST_Q[0], 3 * ROBUST_Q[1], ROBUST_Q[2], 3 * ROBUST_Q[3],
                              ROBUST_Q[4])
    controller.activate(UPRIGHT)
    assert np.array_equal(controller.gain, precise)
    for source in range(50):  # commands act 20 ms after the sample they were computed from
        estimate.latency.report(source * TS, source * TS + 0.02)
    assert estimate.dead_time == pytest.approx(0.02)
    controller.activate(UPRIGHT)
    r = controller.gains['r']
    assert controller.gain == pytest.approx(expected_gain(ROBUST_Q, DEAD_TIME_WEIGHT_MAX * r))
    assert abs(controller.gain[1]) < 0.6 * abs(precise[1])


def test_lost_samples_count_as_dead_time_at_the_catch():
    """80 % of the samples lost (mean age 4 Ts = 20 ms): the pendulum's weights are cut as for
    a 20 ms dead time; R stays (the latency is zero)."""
    estimate, controller = manager_controller()
    rng = random.Random(3)
    for k in range(2000):
        if rng.random() >= 0.8:
            estimate.measured(k * TS, PARAMS.x_middle, 0.0)
    assert 0.012 < estimate.sample_age.age < 0.025
    assert estimate.dead_time == 0.0
    controller.activate(UPRIGHT)
    assert controller.gain == pytest.approx(expected_gain(ROBUST_Q, controller.gains['r']))


def test_sample_age_of_lost_samples():
    """Every other sample lost: ages 0 and Ts, mean Ts / 2; none lost: 0; a gap beyond the
    loop's possible latency (a pause) or time going back is not a loss."""
    age = SampleAge(TS)
    assert age.age == 0.0
    for k in range(0, 400, 2):
        age.sample(k * TS)
    assert age.age == pytest.approx(TS / 2)
    age.reset()
    for k in range(100):
        age.sample(k * TS)
    age.sample(99 * TS + 2 * LATENCY_MAX)   # a pause
    age.sample(0.0)                          # a new run
    age.sample(TS)
    assert age.age == 0.0


@pytest.mark.parametrize('offset, precise_share', [
    ((0.02, 0.01, 0.05, 0.1), 1.0),               # inside the band: the precise gain
    ((0.0, 0.01, 0.15, 0.0), 0.5),                # 1.5 bands of cart speed: half each
    ((0.0, -0.08, 0.0, 0.0), 0.0),                # 4.6 deg: the robust gain
    ((0.0, 0.0, 0.0, 0.6), 0.0),                  # a catch's pendulum rate: the robust gain
])
def test_precise_gain_near_upright_rest_robust_beyond_twice_the_band(offset, precise_share):
    controller = LqgStabilizer()
    controller.configure({'q': (10.0, 30000.0, 10.0, 3.0)}, CONTEXT)  # no integral: u is K s
    assert tuple(controller.gains['precise_band']) == pytest.approx((0.03, 0.0349, 0.1, 0.25),
                                                                     rel=1e-3)
    s = np.array(offset)
    state = ControllerState(0.0, PARAMS.x_middle + s[0], s[1], s[2], s[3])
    controller.activate(state)
    precise, robust = -controller.gain @ s, -controller.robust_gain @ s
    assert controller.robust_gain == pytest.approx(expected_gain(ROBUST_Q[:4] + (0.0,), 0.01))
    assert controller.update(state) == pytest.approx(
        precise_share * precise + (1.0 - precise_share) * robust)
    assert abs(precise - robust) > 0.1 * abs(robust)   # the two gains differ here


def test_one_gain_when_the_least_share_is_one():
    controller = LqgStabilizer()
    controller.configure({'pendulum_weight_min': 1.0}, CONTEXT)
    assert np.array_equal(controller.gain, controller.robust_gain)
