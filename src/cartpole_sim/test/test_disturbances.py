"""The scenario's disturbances on the plant: each does what it says, seeded and deterministic.

Pure tests: no rclpy.
"""
import math

import numpy as np
import pytest

from cartpole_sim.disturbance import CommandDelayLine, lag_factors
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Push, Scenario, parse_push
from cartpole_sim.sim_runner import SimRunner

NOMINAL = CartPoleParameters()
FRICTIONLESS = NOMINAL.replace(c_c_right=0.0, c_c_left=0.0, v_c=0.0, c_p=0.0, v_p=0.0)
MIDDLE = NOMINAL.x_middle
DC_GAIN = NOMINAL.actuator_gain / NOMINAL.actuator_pole
COMMANDS = [3.0 + 5.0 * math.sin(0.1 * k) + (4.0 if k % 7 == 0 else 0.0) for k in range(120)]


def forces_of(plant, commands, duration=None):
    out = []
    for command in commands:
        plant.step(command, duration)
        out.append(plant.force)
    return out


def cart_momentum(plant):
    """dL/dx_dot = (m_c + m_p) x_dot - m_p l cos(theta) theta_dot (4.17)."""
    p = plant.true_params
    _, theta, x_dot, theta_dot = plant.state
    return (p.m_c + p.m_p) * x_dot - p.m_p * p.l * math.cos(theta) * theta_dot


def pendulum_momentum(plant):
    """dL/dtheta_dot = m_p l^2 theta_dot - m_p l cos(theta) x_dot (4.17)."""
    p = plant.true_params
    _, theta, x_dot, theta_dot = plant.state
    return p.m_p * p.l * p.l * theta_dot - p.m_p * p.l * math.cos(theta) * x_dot


# -- delay and jitter -------------------------------------------------------------------------
def test_a_delay_of_two_samples_shifts_the_force_by_exactly_10_ms():
    nominal = forces_of(Plant(NOMINAL, Scenario(x0=MIDDLE)), COMMANDS)
    delayed = forces_of(Plant(NOMINAL, Scenario(x0=MIDDLE, delay=0.010)), COMMANDS)
    assert delayed[:2] == [0.0, 0.0]
    assert delayed[2:] == nominal[:-2]  # bit for bit


def test_a_fractional_delay_splits_the_hold():
    # 2.5 ms: each 5 ms hold is the previous command for 2.5 ms, then the new one.
    delayed = Plant(NOMINAL, Scenario(x0=MIDDLE, theta0=2.5, delay=0.0025))
    split = Plant(NOMINAL, Scenario(x0=MIDDLE, theta0=2.5))
    previous = 0.0
    for command in COMMANDS:
        delayed.step(command)
        split.step(previous, duration=0.0025)
        split.step(command, duration=0.0025)
        previous = command
        assert (delayed.state, delayed.current, delayed.t) == (split.state, split.current, split.t)
    # and it differs from no delay at all
    assert Plant(NOMINAL, Scenario(x0=MIDDLE, theta0=2.5)).state != delayed.state


def test_jitter_delays_each_command_uniformly_and_keeps_the_order():
    line = CommandDelayLine(delay=0.004, jitter=0.006, seed=3)
    arrivals = [line.send(k * 5_000_000, float(k)) for k in range(4000)]
    lags = np.array(arrivals) - 5_000_000 * np.arange(4000)
    assert lags.min() >= 4_000_000 and lags.max() <= 10_000_000 + 5_000_000
    assert all(b >= a for a, b in zip(arrivals, arrivals[1:]))  # FIFO: no overtaking
    # Mostly uniform in [4, 10] ms (a few are held back behind a later predecessor).
    assert np.mean(lags) == pytest.approx(7.0e6, rel=0.05)
    assert CommandDelayLine(0.004, 0.006, 3).send(0, 1.0) == arrivals[0]  # seeded
    assert [CommandDelayLine(0.004, 0.006, s).send(0, 1.0) for s in (4, 5)] != [arrivals[0]] * 2


def test_jitter_changes_the_run_and_the_seed_reproduces_it():
    def run(seed):
        return forces_of(Plant(NOMINAL, Scenario(x0=MIDDLE, delay=0.002, jitter=0.004,
                                                 seed=seed)), COMMANDS)
    assert run(1) == run(1)
    assert run(1) != run(2)


# -- the amplifier: gain error and extra lag ----------------------------------------------------
@pytest.mark.parametrize('gain', [0.7, 1.3])
def test_an_actuator_gain_scales_the_force(gain):
    scaled = forces_of(Plant(NOMINAL, Scenario(x0=MIDDLE, actuator_gain=gain)), COMMANDS)
    nominal = forces_of(Plant(NOMINAL, Scenario(x0=MIDDLE)), COMMANDS)
    np.testing.assert_allclose(scaled, gain * np.array(nominal), rtol=1e-12, atol=1e-12)


def test_the_amplifier_saturates_after_the_gain_error():
    plant = Plant(NOMINAL, Scenario(x0=MIDDLE, actuator_gain=2.0))
    plant.step(20.0)  # 2 x 20 N > 34.25 N
    assert plant.force == pytest.approx(NOMINAL.force_max, rel=1e-9)


def test_an_extra_actuator_lag_is_the_exact_two_pole_step_response():
    # Step of 10 N through 1 / (tau s + 1) then (4.4): i(t) = c (1 - e^{-at}
    # - a/(a - 1/tau) (e^{-t/tau} - e^{-at})), sampled at 0.1 ms steps.
    tau, a = 0.01, NOMINAL.actuator_pole
    c = 10.0 * DC_GAIN
    plant = Plant(NOMINAL, Scenario(x0=MIDDLE, actuator_tau=tau), integration_step=1e-4)
    k = a / (a - 1.0 / tau)
    for n in range(1, 60):
        plant.step(10.0, duration=5e-4)
        t = n * 5e-4
        expected = c * (1.0 - math.exp(-a * t) - k * (math.exp(-t / tau) - math.exp(-a * t)))
        assert plant.force == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert plant.force < 0.96 * c  # 3 tau: still rising
    for _ in range(40):
        plant.step(10.0)
    assert plant.force == pytest.approx(c, rel=1e-6)  # the DC gain is unchanged


def test_lag_factors_at_the_degenerate_time_constant_are_the_limit():
    a, h = NOMINAL.actuator_pole, 1e-4
    near = lag_factors(a, 1.0 / (a * (1.0 + 1e-6)), h)
    exact = lag_factors(a, 1.0 / a, h)
    np.testing.assert_allclose(near, exact, rtol=1e-5)


# -- force noise and pushes --------------------------------------------------------------------------
def test_force_noise_adds_a_gaussian_force_per_sample_of_that_std():
    # Frictionless, hanging, no command: the cart momentum changes by noise x Ts each sample.
    plant = Plant(FRICTIONLESS, Scenario(x0=MIDDLE, force_noise=2.0, seed=4))
    ts = NOMINAL.sample_time
    kicks = []
    for _ in range(4000):
        p0 = cart_momentum(plant)
        plant.step(0.0)
        kicks.append((cart_momentum(plant) - p0) / ts)
        plant.state[0] = MIDDLE  # keep it off the stops
    kicks = np.array(kicks)
    assert np.std(kicks) == pytest.approx(2.0, rel=0.05)
    assert abs(np.mean(kicks)) < 0.1
    assert plant.force == 0.0  # the actuator's own force is untouched


@pytest.mark.parametrize('amplitude,width', [(10.0, 0.1), (-40.0, 0.0123)])
def test_a_cart_push_changes_the_momentum_by_amplitude_times_width(amplitude, width):
    # The push starts and ends inside a sample period (the hold is split there).
    plant = Plant(FRICTIONLESS, Scenario(x0=MIDDLE, pushes=(Push(0.0123, 'cart', amplitude,
                                                                  width),)))
    for _ in range(2):  # up to 10 ms
        plant.step(0.0)
    assert cart_momentum(plant) == pytest.approx(0.0, abs=1e-12)
    for _ in range(40):
        plant.step(0.0)
    assert cart_momentum(plant) == pytest.approx(amplitude * width, rel=1e-9)


def test_a_pendulum_push_changes_its_momentum_by_amplitude_times_width():
    # Hanging at rest, a 0.5 N m push for 10 ms: the pendulum's generalised momentum gains
    # 5 mN m s (gravity takes back a little as it swings); the cart's is a no-push zero.
    push = Push(0.0123, 'pendulum', 0.5, 0.01)
    plant = Plant(FRICTIONLESS, Scenario(x0=MIDDLE, pushes=(push,)))
    plant.step(0.0, duration=0.0123)
    assert pendulum_momentum(plant) == pytest.approx(0.0, abs=1e-12)
    plant.step(0.0, duration=0.01)
    assert pendulum_momentum(plant) == pytest.approx(push.impulse, rel=2e-3)
    assert cart_momentum(plant) == pytest.approx(0.0, abs=1e-12)
    assert plant.state[3] > 0.0  # towards increasing theta


# -- lost samples --------------------------------------------------------------------------------------
def test_the_simulator_flags_lost_samples_in_the_same_sequence():
    a = SimRunner(NOMINAL, Scenario(drop=0.3, seed=2))
    b = Plant(NOMINAL, Scenario(drop=0.3, seed=2))
    flags = [a.sample.lost] + [a.advance().lost for _ in range(300)]
    assert flags == [b.sample_lost() for _ in range(301)]
    assert 0.2 < sum(flags) / len(flags) < 0.4
    assert not any(SimRunner(NOMINAL, Scenario()).advance().lost for _ in range(50))


# -- scenario: validation, model errors, determinism ------------------------------------------------
@pytest.mark.parametrize('changes,word', [
    ({'delay': 0.05}, 'delay'), ({'delay': -0.001}, 'delay'), ({'jitter': 0.1}, 'jitter'),
    ({'drop': 1.0}, 'drop'), ({'force_noise': -1.0}, 'force_noise'),
    ({'actuator_gain': 0.0}, 'actuator_gain'), ({'actuator_tau': -0.01}, 'actuator_tau'),
    ({'cart_mass': 0.0}, 'cart_mass'), ({'parameter_scales': (('pendulum_ticks_per_rev', 2.0),)},
                                        'float plant parameter'),
    ({'pushes': ('1:hand:1:1',)}, 'target'), ({'pushes': (Push(1.0, 'cart', 1.0, 0.1),
                                                          '1:cart:1')}, 'T:TARGET'),
    ({'delay': float('nan')}, 'delay'), ({'seed': -1}, 'seed'),
])
def test_bad_scenarios_are_refused_naming_the_field(changes, word):
    with pytest.raises(ValueError, match=word):
        Scenario(**changes)


def test_push_text_round_trips():
    push = parse_push('12.5:Cart:-3.25:0.1')
    assert push == Push(12.5, 'cart', -3.25, 0.1) and push.impulse == pytest.approx(-0.325)
    assert parse_push(str(Push(1 / 3, 'pendulum', 0.1, 0.07))) == Push(1 / 3, 'pendulum', 0.1, 0.07)


def test_cart_mass_and_parameter_scales_change_the_true_plant_only():
    scenario = Scenario(cart_mass=5.7, tip_mass=0.2, parameter_scales=(('l', 1.1), ('c_p', 3.0)))
    plant = Plant(NOMINAL, scenario)
    tp = plant.true_params
    assert (tp.m_c, tp.m_p) == (5.7, 0.2)
    assert tp.l == pytest.approx(1.1 * NOMINAL.l) and tp.c_p == pytest.approx(3.0 * NOMINAL.c_p)
    assert plant.params == NOMINAL


def test_no_disturbance_keeps_the_fast_path():
    assert not Plant(NOMINAL, Scenario(noise=True, drop=0.1, actuator_gain=0.8,
                                       cart_mass=5.0))._disturbed
    for changes in ({'delay': 0.001}, {'jitter': 0.001}, {'force_noise': 0.1},
                    {'actuator_tau': 0.001}, {'pushes': (Push(1.0, 'cart', 1.0, 0.1),)}):
        assert Plant(NOMINAL, Scenario(**changes))._disturbed, changes


ALL_ON = dict(x0=0.2, theta0=math.pi - 0.4, noise=True, delay=0.0063, jitter=0.003, drop=0.1,
              force_noise=0.5, actuator_gain=0.9, actuator_tau=0.004, cart_mass=5.0,
              pushes=(Push(0.3, 'cart', 8.0, 0.05), Push(0.61, 'pendulum', -0.2, 0.02)))


def run_all_on(seed):
    plant = Plant(NOMINAL, Scenario(seed=seed, **ALL_ON))
    out = []
    for command in COMMANDS:
        m = plant.measure()
        out.append((m, plant.sample_lost(), tuple(plant.state), plant.force))
        plant.step(command - 20.0 * (m.x - 0.2))
    return out


def test_the_same_seed_reproduces_a_disturbed_run_bit_for_bit():
    assert run_all_on(5) == run_all_on(5)
    assert run_all_on(5) != run_all_on(6)


def test_reset_replays_the_disturbances():
    plant = Plant(NOMINAL, Scenario(seed=5, **ALL_ON))
    first = [(plant.measure(), plant.sample_lost(), forces_of(plant, [c])[0]) for c in COMMANDS]
    plant.reset()
    again = [(plant.measure(), plant.sample_lost(), forces_of(plant, [c])[0]) for c in COMMANDS]
    assert first == again and plant.lost_samples == sum(lost for _, lost, _ in again)
