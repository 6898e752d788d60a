"""The simulator's sampling logic without ROS: stamps, zero-order hold, watchdog, reset."""
import math

import pytest

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario
from cartpole_sim.sim_runner import SampleClock, SimRunner, force_from_command

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


def first_zero_force_sample(runner, limit=100):
    """Advance until a sample shows zero actuator force; returns (that sample, the one before)."""
    before = runner.sample
    for _ in range(limit):
        sample = runner.advance()
        if abs(sample.actuator_force) < 1e-9:
            return sample, before
        before = sample
    raise AssertionError('the force never fell to zero')


@pytest.mark.parametrize('timeout', [0.05, 0.052, 0.0125, 0.1])
def test_watchdog_zero_force_sample_within_the_timeout_of_the_command(timeout):
    """The watchdog from the last command's arrival to the first zero-force sample, by stamps.

    The command arrives while sample k is out, i.e. at or after t_k; the first
    sample whose true actuator force is zero must be stamped at most
    ``timeout`` after t_k, and it is the last sample inside the deadline (no
    early trip: the one before it still shows the command).
    """
    runner = SimRunner(NOMINAL, MIDDLE, command_timeout=timeout)
    for _ in range(3):
        runner.advance()
    arrival_ns = runner.sample.stamp_ns          # the earliest the command can arrive
    runner.command(10.0)
    zero, before = first_zero_force_sample(runner)
    deadline_ns = round(timeout * 1e9)
    assert deadline_ns - runner.sample_period_ns < zero.stamp_ns - arrival_ns <= deadline_ns
    assert before.actuator_force == pytest.approx(10.0, rel=0.01)  # actuator DC gain 1.0066
    assert runner.watchdog_tripped and runner.watchdog_trips == 1


def test_watchdog_holds_then_zeroes_and_the_next_command_clears_it():
    runner = SimRunner(NOMINAL, MIDDLE, command_timeout=0.05)
    assert runner.held_force() == 0.0  # no command yet
    runner.command(10.0)
    forces = []
    for _ in range(15):
        forces.append(runner.held_force())
        runner.advance()
    # Held over 9 periods (the 10th sample, 50 ms after t_k, shows zero force), then zero.
    assert forces[:9] == [10.0] * 9
    assert forces[9:] == [0.0] * 6
    assert runner.watchdog_tripped and runner.watchdog_trips == 1
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


def test_sample_clock_is_the_plants_own_time_through_late_and_early_calls():
    """Real time: sample k is due at t0 + (k - k0) Ts and stamped on the same grid, so a
    late call (a stall) finds every sample it missed due, and a call a hair early still
    takes its own sample, never the next one."""
    ts = 5_000_000
    clock = SampleClock(ts)
    assert not clock.started
    clock.start(steady_ns=1_000_000_000, stamp_ns=7_000_000_000, index=4)
    assert clock.due(1_000_000_000) == 4
    assert clock.due(1_000_000_000 + ts - ts // 10 - 1) == 4      # 0.5 ms early: not yet 5
    assert clock.due(1_000_000_000 + ts - ts // 20) == 5           # 0.25 ms early: taken
    assert clock.due(1_000_000_000 + ts + ts // 2) == 5            # late by half a period
    assert clock.due(1_000_000_000 + 100_000_000 + 300_000) == 24  # a 0.1 s stall: 20 due
    assert [clock.stamp_ns(k) - 7_000_000_000 for k in (4, 5, 24)] == [0, ts, 20 * ts]
