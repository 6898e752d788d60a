"""Lost samples (scenario ``drop``) reach the EKF as gaps it bridges by prediction and reports.

Pure tests: no rclpy.
"""
import math

import pytest

from cartpole_estimation.ekf import ExtendedKalmanFilter
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

NOMINAL = CartPoleParameters()


def test_drops_lose_samples_at_the_rate_and_the_ekf_reports_the_gaps():
    plant = Plant(NOMINAL, Scenario(x0=0.38, theta0=math.pi - 0.4, drop=0.2, seed=9))
    ekf = ExtendedKalmanFilter(NOMINAL)
    lost_since, gaps, lost = 0, [], 0
    for k in range(2000):
        meas = plant.measure()
        if plant.sample_lost():
            lost_since += 1
            lost += 1
        else:
            est = ekf.update(meas.t, meas.x, meas.theta, 0.0)
            if k > 0 and not est.reset:
                gaps.append((est.missed_samples, lost_since))
            lost_since = 0
        plant.step(0.0)
    assert plant.lost_samples == lost
    assert lost / 2000 == pytest.approx(0.2, abs=0.03)
    assert all(reported == real for reported, real in gaps)
    assert sum(r for r, _ in gaps) > 300
