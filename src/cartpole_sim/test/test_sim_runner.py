"""The simulator's sampling logic without ROS: stamps, zero-order hold, watchdog, reset."""
import math

import pytest

from cartpole_sim.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario
from cartpole_sim.sim_runner import SimRunner, force_from_command

NOMINAL = CartPoleParameters()
MIDDLE = Scenario(x0=NOMINAL.x_middle)


@pytest.mark.parametrize('names,efforts,expected', [
    (['cart'], [3.5], 3.5),
    (['pendulum', 'cart'], [0.0, -2.0], -2.0),
    (['cart'], [], None),
    (['cart'], [float('nan')], None),
    (['cart'], [float('inf')], None),
    (['pendulum'], [1.0], None),
    ([], [1.0], None),
])
def test_force_from_command(names, efforts, expected):
    assert force_from_command(names, efforts) == expected


def test_stamps_are_whole_sample_periods():
    runner = SimRunner(NOMINAL, MIDDLE)
    assert runner.sample.stamp_ns == 0
    for k in range(1, 1001):
        sample = runner.advance()
        assert sample.index == k
        assert sample.stamp_ns == k * 5_000_000
    # Exact, even where the plant's float time has accumulated rounding.
    assert runner.stamp_ns == 5_000_000_000


def test_held_command_is_applied_like_the_bare_plant():
    # The runner adds nothing numerical: same inputs, same trajectory as Plant.step.
    runner = SimRunner(NOMINAL, MIDDLE)
    plant = Plant(NOMINAL, MIDDLE)
    for k in range(40):
        force = 8.0 * math.sin(0.3 * k)
        runner.command(force)
        runner.advance()
        plant.step(force)
        assert runner.plant.state == plant.state
    assert runner.sample.actuator_force == pytest.approx(plant.force)


def test_watchdog_zeroes_force_after_command_timeout():
    runner = SimRunner(NOMINAL, MIDDLE, command_timeout=0.05)
    assert runner.held_force() == 0.0  # no command yet
    runner.command(10.0)
    forces = []
    for _ in range(15):
        forces.append(runner.held_force())
        runner.advance()
    # Held for 50 ms of simulated time (ages 0..50 ms = 11 periods), then zero.
    assert forces[:11] == [10.0] * 11
    assert forces[11:] == [0.0] * 4
    assert runner.watchdog_tripped and runner.watchdog_trips == 1
    # The actuator follows: the cart is pushed, then friction stops it.
    assert runner.sample.actuator_force == pytest.approx(0.0, abs=1e-6)
    runner.command(-4.0)
    assert runner.held_force() == -4.0 and not runner.watchdog_tripped


def test_reset_restores_state_and_keeps_the_clock_going():
    runner = SimRunner(NOMINAL, Scenario(x0=0.2, theta0=3.0))
    runner.command(20.0)
    for _ in range(50):
        runner.advance()
    assert runner.plant.state[0] > 0.21  # pushed for 50 ms, then the watchdog
    sample = runner.reset()
    assert sample.index == 51 and sample.stamp_ns == 51 * 5_000_000
    assert sample.true_state == (0.2, 3.0, 0.0, 0.0)
    assert runner.held_force() == 0.0
    new = runner.reset(scenario=Scenario(x0=0.4), integration_step=0.0005)
    assert new.true_state == (0.4, math.pi, 0.0, 0.0)
    assert runner.plant.integration_step == 0.0005
    with pytest.raises(ValueError, match='sample_time'):
        runner.reset(params=NOMINAL.replace(sample_time=0.01))
