"""The simulated rig: friction, end stops, actuator (4.4), saturation, encoders (2.3)/(2.4).

Pure tests: no rclpy.
"""
import math

import numpy as np
import pytest

from cartpole_core.model import CartPoleParameters
from cartpole_core.model import wrap_counter
from cartpole_sim.plant import END_STOP_TOLERANCE, Plant, Scenario

NOMINAL = CartPoleParameters()
FRICTIONLESS = NOMINAL.replace(c_c_right=0.0, c_c_left=0.0, v_c=0.0, c_p=0.0, v_p=0.0)


def generalised_cart_momentum(plant):
    """dL/dx_dot = (m_c + m_p) x_dot - m_p l cos(theta) theta_dot; its rate is F - B_c (4.17)."""
    p = plant.true_params
    x, theta, x_dot, theta_dot = plant.state
    return (p.m_c + p.m_p) * x_dot - p.m_p * p.l * math.cos(theta) * theta_dot


@pytest.mark.parametrize('x_dot0,friction', [(0.3, -3.4), (-0.3, 2.45)])
def test_cart_friction_removes_momentum_at_its_directional_level(x_dot0, friction):
    # Unforced, the cart's generalised momentum changes only by the friction force:
    # over 50 ms moving right it loses 3.4 N x T, moving left it gains 2.45 N x T (4.27).
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle, x_dot0=x_dot0))
    p0 = generalised_cart_momentum(plant)
    plant.step(0.0, duration=0.05)
    assert math.copysign(1.0, plant.state[2]) == math.copysign(1.0, x_dot0)  # still moving
    rate = (generalised_cart_momentum(plant) - p0) / 0.05
    assert rate == pytest.approx(friction, rel=1e-3)


def test_pendulum_friction_brakes_the_swing():
    # Pendulum Coulomb + viscous friction (4.21): the swing decays, frictionless it does not.
    def amplitude_after(params, seconds):
        plant = Plant(params, Scenario(x0=params.x_middle, theta0=math.pi - 0.5))
        peak = 0.0
        for k in range(int(seconds / params.sample_time)):
            plant.step(0.0)
            if k * params.sample_time > seconds - 1.5:
                peak = max(peak, abs(plant.state[1] - math.pi))
        return peak
    assert amplitude_after(FRICTIONLESS, 5.0) == pytest.approx(0.5, abs=0.01)
    pendulum_only = FRICTIONLESS.replace(c_p=NOMINAL.c_p, v_p=NOMINAL.v_p)
    assert amplitude_after(pendulum_only, 5.0) < 0.45


@pytest.mark.parametrize('command,x0,side', [(1000.0, 0.0, 'right'), (-1000.0, 0.769, 'left')])
def test_full_force_into_an_end_stop_stays_at_the_stop(command, x0, side):
    # Full force from one stop into the other: the cart hits at ~2 m/s. The stiff
    # spring-damper end stop (1e6 N/m, 1e3 N s/m) lets it in by v sqrt(m/k) ~ 4.5 mm at the
    # impact and holds it within F/k = 0.04 mm after it settles.
    plant = Plant(NOMINAL, Scenario(x0=x0))
    travel = NOMINAL.travel
    depth = []
    for _ in range(400):  # 2 s
        plant.step(command)
        x = plant.state[0]
        depth.append(x - travel if side == 'right' else -x)
    assert plant.end_stop_contact
    assert max(depth) > 0.0
    assert max(depth) < 0.006
    assert abs(depth[-1]) < 0.0001
    assert abs(plant.state[2]) < 1e-3
    expected_force = NOMINAL.force_max if command > 0 else NOMINAL.force_min
    assert plant.force == pytest.approx(expected_force, rel=1e-9)


def test_no_end_stop_contact_in_the_middle():
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle))
    for _ in range(100):
        plant.step(2.0)
    assert not plant.end_stop_contact


def test_current_saturation_limits_force():
    # +11 A / -12 A times 3.1133 N/A (Appendix C): +34.25 N / -37.36 N at most.
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle))
    plant.step(500.0, duration=0.002)
    assert plant.force == pytest.approx(34.2463, abs=1e-3)
    plant.step(-500.0, duration=0.002)
    assert plant.force == pytest.approx(-37.3596, abs=1e-3)
    plant.step(20.0, duration=0.002)
    assert plant.force == pytest.approx(20.0 * 1.065e4 / 1.058e4, rel=1e-6)  # DC gain of (4.4)


def test_actuator_lag_is_first_order_and_settles_within_a_millisecond():
    # H(s) = 1.065e4 / (s + 1.058e4) (4.4): time constant 94.5 us.
    a, dc = 1.058e4, 1.065e4 / 1.058e4
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle), integration_step=1e-4)
    plant.step(10.0, duration=1e-4)
    assert plant.force == pytest.approx(10.0 * dc * (1.0 - math.exp(-a * 1e-4)), rel=1e-9)
    assert plant.force < 0.7 * 10.0 * dc  # not instantaneous
    plant.step(10.0, duration=9e-4)
    assert plant.force == pytest.approx(10.0 * dc, rel=1e-4)  # settled after 1 ms


def test_non_finite_command_gives_zero_force():
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle))
    plant.step(10.0)
    plant.step(float('nan'))
    assert plant.force == pytest.approx(0.0, abs=1e-6)
    assert plant.force_command == 0.0


# -- encoders (2.3), (2.4) ----------------------------------------------------------------------
def test_quantisation_steps_are_one_tick():
    plant = Plant(NOMINAL)
    dx, dtheta = 0.769 / 8737, 2.0 * math.pi / 2000
    rng = np.random.default_rng(1)
    for _ in range(50):
        x, theta = rng.uniform(0.0, 0.769), rng.uniform(-math.pi, 3 * math.pi)
        plant.reset()
        plant.state = [x, theta, 0.0, 0.0]
        m = plant.measure()
        assert abs(m.x - x) <= dx / 2 + 1e-12
        assert abs(m.theta - theta) <= dtheta / 2 + 1e-12
        # x and theta are whole numbers of ticks.
        assert m.x / dx == pytest.approx(round(m.x / dx), abs=1e-6)
        assert (m.theta - math.pi) / dtheta == pytest.approx(round((m.theta - math.pi) / dtheta),
                                                             abs=1e-6)
    # Moving by exactly one tick moves the measurement by exactly one step.
    plant.reset()
    plant.state = [0.3, math.pi, 0.0, 0.0]
    m0 = plant.measure()
    plant.state = [0.3 + dx, math.pi + dtheta, 0.0, 0.0]
    m1 = plant.measure()
    assert m1.x - m0.x == pytest.approx(dx, rel=1e-9)
    assert m1.theta - m0.theta == pytest.approx(dtheta, rel=1e-9)
    assert m1.cart_ticks - m0.cart_ticks == 1
    assert m1.pendulum_ticks - m0.pendulum_ticks == 1


def test_hanging_rest_reads_pi_and_zero():
    m = Plant(NOMINAL).measure()
    assert (m.x, m.theta, m.cart_ticks, m.pendulum_ticks) == (0.0, math.pi, 0, 0)


def test_encoder_offset_biases_the_angle():
    # Encoders reset with the pendulum at pi + offset (Appendix H): reads pi - offset when hanging.
    offset = 0.05
    m = Plant(NOMINAL, Scenario(encoder_offset=offset)).measure()
    assert m.theta == pytest.approx(math.pi - offset, abs=NOMINAL.pendulum_resolution / 2)


def test_wrap_counter_is_16_bit_twos_complement():
    assert wrap_counter(32767) == 32767
    assert wrap_counter(32768) == -32768
    assert wrap_counter(-32769) == 32767
    assert wrap_counter(65536 + 5) == 5
    assert wrap_counter(300, bits=8) == 44


def test_spinning_pendulum_wraps_the_counter_and_is_unwrapped():
    # ~35 rad/s for 4 s is ~20 revolutions = 40,000 ticks > 32,767: the raw counter wraps.
    # The cart starts with the opposite momentum so that it stays mid-rail.
    p = FRICTIONLESS
    x_dot0 = -p.m_p * p.l * 40.0 / (p.m_c + p.m_p)
    plant = Plant(p, Scenario(x0=p.x_middle, theta_dot0=40.0, x_dot0=x_dot0))
    wrapped = False
    previous = plant.measure().pendulum_ticks
    for _ in range(800):
        plant.step(0.0)
        m = plant.measure()
        assert -32768 <= m.pendulum_ticks <= 32767
        if m.pendulum_ticks < previous - 30_000:
            wrapped = True
        previous = m.pendulum_ticks
        assert abs(m.theta - plant.state[1]) <= FRICTIONLESS.pendulum_resolution / 2 + 1e-12
    assert wrapped
    assert not plant.end_stop_contact
    assert (plant.state[1] - math.pi) / (2 * math.pi) > 16.4


# -- scenario and determinism ------------------------------------------------------------------
def test_scenario_changes_the_true_parameters():
    scenario = Scenario(tip_mass=0.201, friction_scale=1.2)
    plant = Plant(NOMINAL, scenario)
    assert plant.true_params.m_p == 0.201
    assert plant.true_params.c_c_right == pytest.approx(3.4 * 1.2)
    assert plant.true_params.c_p == pytest.approx(0.0038 * 1.2)
    assert plant.params == NOMINAL


def run_noisy(seed):
    plant = Plant(NOMINAL, Scenario(x0=0.2, theta0=math.pi - 0.3, noise=True, seed=seed))
    measurements, states = [], []
    for k in range(200):
        plant.step(5.0 * math.sin(0.05 * k))
        measurements.append(plant.measure())
        states.append(tuple(plant.state))
    return measurements, states


def test_same_seed_and_inputs_give_bit_identical_runs():
    m1, s1 = run_noisy(7)
    m2, s2 = run_noisy(7)
    assert m1 == m2
    assert s1 == s2
    m3, s3 = run_noisy(8)
    assert s3 == s1  # noise is on the measurement only
    assert [m.theta for m in m3] != [m.theta for m in m1]


def test_reset_restores_initial_state_and_noise_sequence():
    plant = Plant(NOMINAL, Scenario(x0=0.1, noise=True, seed=3))
    first = [plant.measure() for _ in range(3)]
    plant.step(10.0)
    plant.reset()
    assert plant.state == [0.1, math.pi, 0.0, 0.0]
    assert plant.t == 0.0 and plant.force == 0.0 and not plant.end_stop_contact
    assert [plant.measure() for _ in range(3)] == first


def test_integration_step_longer_than_sample_time_refused():
    with pytest.raises(ValueError, match='integration_step'):
        Plant(NOMINAL, integration_step=0.01)


def test_unrolled_rk4_matches_the_reference_stages_bit_for_bit():
    # Plant._rk4 is the unrolled inner loop; Plant._derivative is its readable reference.
    plant = Plant(NOMINAL, Scenario(x0=0.01, theta0=2.0, x_dot0=-0.5, theta_dot0=3.0))
    h, force = 0.001, 12.5
    s = list(plant.state)
    k1 = plant._derivative(s, force)
    k2 = plant._derivative([s[i] + 0.5 * h * k1[i] for i in range(4)], force)
    k3 = plant._derivative([s[i] + 0.5 * h * k2[i] for i in range(4)], force)
    k4 = plant._derivative([s[i] + h * k3[i] for i in range(4)], force)
    expected = [s[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(4)]
    plant._rk4(h, force)
    assert plant.state == expected


def test_step_equals_the_rk4_substeps_on_the_plant_bit_for_bit():
    """step() runs its substeps on local variables; the same numbers as the substep loop on
    the plant's attributes (current loop (4.4), RK4, clock, end-stop flag), in and out of
    an end stop, with the default and an explicit hold."""
    scenario = Scenario(x0=0.004, x_dot0=-0.3, theta0=2.0, theta_dot0=4.0)
    a, b = Plant(NOMINAL, scenario), Plant(NOMINAL, scenario)
    p = b.true_params
    for k, command in enumerate([30.0, -45.0, 5.0, 0.0, 12.0, -3.0] * 5):
        duration = None if k % 2 else 0.0035
        a.step(command, duration)
        hold = NOMINAL.sample_time if duration is None else duration
        n = max(1, int(round(hold / b.integration_step)))
        h = hold / n
        i_ss = p.actuator_gain / p.actuator_pole * (command / p.force_per_ampere)
        i_target = min(max(i_ss, p.current_min), p.current_max)
        decay = math.exp(-p.actuator_pole * h)
        mean_factor = (1.0 - decay) / (p.actuator_pole * h)
        for _ in range(n):
            i0 = b.current
            b._rk4(h, (i_target + (i0 - i_target) * mean_factor) * p.force_per_ampere)
            b.current = i_target + (i0 - i_target) * decay
            if not b.end_stop_contact and b.in_end_stop():
                b.end_stop_contact = True
        b.t = round((b.t + n * h) * 1e9) / 1e9  # whole nanoseconds
        assert (a.state, a.current, a.t, a.end_stop_contact) == \
            (b.state, b.current, b.t, b.end_stop_contact)
        assert a.measure() == b.measure()
    assert a.end_stop_contact




def test_sample_times_are_whole_nanoseconds_without_drift():
    plant = Plant(NOMINAL, Scenario())
    for k in range(1, 2001):
        plant.step(0.0)
        assert plant.t == round(k * 5_000_000) / 1e9
    assert plant.measure().t == 10.0


def test_resting_at_the_left_stop_is_not_a_contact():
    # The default start: cart against the left stop, no force. Round-off may leave x a
    # hair below 0 (-1.7e-22 m was seen); contact means the stop was pressed in (> 1 um).
    plant = Plant(NOMINAL, Scenario())
    for _ in range(400):
        plant.step(0.0)
        assert plant.end_stop_force == 0.0
    assert not plant.end_stop_contact and not plant.in_end_stop()
    plant.state[0] = -0.5 * END_STOP_TOLERANCE
    assert not plant.in_end_stop()


@pytest.mark.parametrize('command,x0,sign', [(1000.0, 0.0, -1.0), (-1000.0, 0.769, 1.0)])
def test_end_stop_force_pushes_the_cart_back(command, x0, sign):
    # Driven into the right stop the stop pushes left (negative), into the left one right.
    plant = Plant(NOMINAL, Scenario(x0=x0))
    peak = 0.0
    for _ in range(200):
        plant.step(command)
        if abs(plant.end_stop_force) > abs(peak):
            peak = plant.end_stop_force
    assert plant.end_stop_contact
    # The 2 m/s impact presses the stop in by ~4.5 mm: ~4.5 kN of spring force.
    assert sign * peak > 1000.0
