"""Catch trigger (6.4) and fall detector: exact thresholds, wrapping, validation."""
import math

import pytest

from cartpole_control.catch import CatchTrigger
from cartpole_core.model import CartPoleParameters, pendulum_energy

P = CartPoleParameters()
E_STAR = P.upright_energy  # 2 m_p g l = 1.6473 J
J = P.m_p * P.l ** 2


def theta_dot_for(theta, energy):
    """The angular rate at which the pendulum at ``theta`` has energy ``energy`` (7.3)."""
    potential = P.m_p * P.g * P.l * (math.cos(theta) + 1.0)
    return math.sqrt(2.0 * (energy - potential) / J)


def test_upright_energy_is_thesis_value():
    assert E_STAR == pytest.approx(2 * 0.251 * 9.81 * 0.3345)
    assert pendulum_energy(0.0, 0.0, P) == pytest.approx(E_STAR)


@pytest.mark.parametrize('fraction, expected', [
    (0.0, True), (0.049, True), (-0.049, True), (0.051, False), (-0.051, False)])
def test_energy_condition_is_five_percent_band(fraction, expected):
    trigger = CatchTrigger()
    theta = math.radians(28.0)  # potential 0.94 E*, so -5.1 % is reachable
    theta_dot = theta_dot_for(theta, E_STAR * (1.0 + fraction))
    assert trigger.should_catch(theta, theta_dot, P) is expected


@pytest.mark.parametrize('deg, expected', [(0.0, True), (29.9, True), (-29.9, True),
                                           (30.1, False), (-30.1, False), (90.0, False)])
def test_angle_condition_is_thirty_degrees(deg, expected):
    trigger = CatchTrigger()
    theta = math.radians(deg)
    # Exactly on the heteroclinic orbit (6.10): E_p = E*.
    theta_dot = -math.sqrt(2.0 * P.g / P.l * (1.0 - math.cos(theta)))
    assert pendulum_energy(theta, theta_dot, P) == pytest.approx(E_STAR)
    assert trigger.should_catch(theta, theta_dot, P) is expected


def test_angle_is_wrapped_after_full_revolutions():
    trigger = CatchTrigger()
    for turns in (-2, 1, 3):
        theta = math.radians(20.0) + 2.0 * math.pi * turns
        theta_dot = theta_dot_for(math.radians(20.0), E_STAR)
        assert trigger.should_catch(theta, theta_dot, P)
    assert not trigger.should_catch(math.pi, 0.0, P)  # hanging at rest: E_p = 0


def test_hanging_at_rest_is_never_caught_and_rest_upright_is():
    trigger = CatchTrigger()
    assert not trigger.should_catch(math.pi, 0.0, P)
    assert trigger.should_catch(0.0, 0.0, P)


def test_fall_detector_threshold_and_wrap():
    trigger = CatchTrigger(fall_angle=math.radians(45.0))
    assert not trigger.has_fallen(math.radians(44.9))
    assert trigger.has_fallen(math.radians(45.1))
    assert trigger.has_fallen(math.radians(-45.1))
    assert not trigger.has_fallen(math.radians(10.0) + 4.0 * math.pi)


def test_custom_thresholds():
    trigger = CatchTrigger(energy_tolerance=0.2, angle=math.radians(10.0),
                           fall_angle=math.radians(20.0))
    theta = math.radians(5.0)
    assert trigger.should_catch(theta, theta_dot_for(theta, 1.15 * E_STAR), P)
    assert not trigger.should_catch(math.radians(12.0), 0.0, P)


@pytest.mark.parametrize('kwargs', [dict(energy_tolerance=0.0), dict(angle=0.0),
                                    dict(angle=math.radians(30), fall_angle=math.radians(30)),
                                    dict(fall_angle=4.0)])
def test_invalid_thresholds_are_refused(kwargs):
    with pytest.raises(ValueError):
        CatchTrigger(**kwargs)
