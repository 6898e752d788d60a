"""The model (4.17)/(4.18), energies (7.3)/(7.11), linearisation (8.13)/(8.14), parameters.

Pure tests: no rclpy.
"""
import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg

from cartpole_core.model import (CartPoleParameters, accelerations, cart_friction, dynamics,
                                force_for_acceleration, input_gain, linearise_upright,
                                pendulum_energy, pendulum_friction, system_energy, wrap_angle)
from cartpole_sim.plant import Plant, Scenario

NOMINAL = CartPoleParameters()
FRICTIONLESS = NOMINAL.replace(c_c_right=0.0, c_c_left=0.0, v_c=0.0, c_p=0.0, v_p=0.0)


def mass_matrix(theta, p):
    """M(theta) of (4.17)."""
    return np.array([[p.m_c + p.m_p, -p.m_p * p.l * math.cos(theta)],
                     [-p.m_p * p.l * math.cos(theta), p.m_p * p.l ** 2]])


# -- energy (7.11) and free oscillation --------------------------------------------------
def test_frictionless_unforced_motion_conserves_total_energy():
    # 10 s from 2.5 rad off hanging, cart mid-rail so the end stops are never reached
    # (the free cart moves at most 2 m_p l / (m_c + m_p) = 34 mm). Zero command gives
    # exactly zero actuator current, so (7.11) must be constant. RK4's global error is
    # about (h w)^4 w T E with h = 1 ms, w ~ 6 rad/s, T = 10 s: ~1e-8 E; measured ~1e-11 J.
    # A tolerance of 1e-7 E (0.15 uJ) passes that and still fails on any modelling
    # error (a wrong term in (4.18) drifts the energy by percent within a swing).
    plant = Plant(FRICTIONLESS, Scenario(x0=FRICTIONLESS.x_middle, theta0=math.pi - 2.5))
    e0 = system_energy(plant.true_state(), FRICTIONLESS)
    assert e0 > 1.0
    deviation = 0.0
    for _ in range(2000):  # 2000 x Ts = 10 s
        plant.step(0.0)
        deviation = max(deviation, abs(system_energy(plant.true_state(), FRICTIONLESS) - e0))
    assert plant.t == pytest.approx(10.0)
    assert not plant.end_stop_contact
    assert deviation < 1e-7 * e0
    # And the motion was not trivial: the pendulum swung through hanging.
    assert abs(plant.state[1] - math.pi) < 2.6


def test_friction_dissipates_energy():
    plant = Plant(NOMINAL, Scenario(x0=NOMINAL.x_middle, theta0=math.pi - 1.0))
    energies = []
    for _ in range(400):
        plant.step(0.0)
        energies.append(system_energy(plant.true_state(), NOMINAL))
    assert energies[-1] < 0.9 * energies[0]
    assert all(b <= a + 1e-9 for a, b in zip(energies, energies[1:]))


def test_small_oscillation_period_matches_hanging_linearisation():
    # Linearising (4.18) about theta = pi with F = 0 and a free cart:
    # theta_ddot = -(m_c + m_p) g / (m_c l) (theta - pi), so
    # w = sqrt((m_c + m_p) g / (m_c l)) (the cart recoils, making it faster than sqrt(g/l)).
    p = FRICTIONLESS
    omega = math.sqrt((p.m_c + p.m_p) * p.g / (p.m_c * p.l))
    expected = 2.0 * math.pi / omega
    plant = Plant(p, Scenario(x0=p.x_middle, theta0=math.pi + 0.01))
    t, phi = [], []
    for _ in range(2000):
        plant.step(0.0)
        t.append(plant.t)
        phi.append(plant.state[1] - math.pi)
    t, phi = np.array(t), np.array(phi)
    down = np.where((phi[:-1] > 0.0) & (phi[1:] <= 0.0))[0]
    crossings = t[down] + (t[down + 1] - t[down]) * phi[down] / (phi[down] - phi[down + 1])
    assert len(crossings) >= 7
    measured = float(np.mean(np.diff(crossings)))
    assert measured == pytest.approx(expected, rel=0.01)
    # The pendulum-only formula 2 pi sqrt(l/g) is 2.6 % longer: the test tells them apart.
    assert abs(measured - 2.0 * math.pi * math.sqrt(p.l / p.g)) > 0.01 * expected


def test_energies_at_rest():
    p = NOMINAL
    assert pendulum_energy(math.pi, 0.0, p) == pytest.approx(0.0, abs=1e-15)
    assert pendulum_energy(0.0, 0.0, p) == pytest.approx(p.upright_energy)
    assert p.upright_energy == pytest.approx(2 * 0.251 * 9.81 * 0.3345)
    state = np.array([0.3, 0.0, 0.0, 0.0])
    assert system_energy(state, p) == pytest.approx(p.upright_energy)
    # (7.11) with the cart still reduces to (7.3).
    assert system_energy(np.array([0.1, 2.0, 0.0, 1.5]), p) == pytest.approx(
        pendulum_energy(2.0, 1.5, p))


# -- equations of motion --------------------------------------------------------------------
@pytest.mark.parametrize('state,force', [
    ((0.2, 0.3, 0.5, -1.0), 4.0),
    ((0.5, 2.8, -0.4, 3.0), -12.0),
    ((0.4, -1.2, 0.0, 0.0), 0.0),
])
def test_accelerations_solve_lagrange_equations(state, force):
    # (4.17): M q_ddot + C + G = [F, 0] - B, checked with the matrices as printed.
    p = NOMINAL
    x, theta, x_dot, theta_dot = state
    acc = np.array(accelerations(x, theta, x_dot, theta_dot, force, p))
    c = np.array([p.m_p * p.l * math.sin(theta) * theta_dot ** 2, 0.0])
    g = np.array([0.0, -p.m_p * p.g * p.l * math.sin(theta)])
    b = np.array([cart_friction(x_dot, p), pendulum_friction(theta_dot, p)])
    np.testing.assert_allclose(mass_matrix(theta, p) @ acc + c + g,
                               np.array([force, 0.0]) - b, atol=1e-12)
    # f(x) + g(x) u (4.40) is the same system.
    s = np.array(state)
    np.testing.assert_allclose(dynamics(0.0, s, force, p),
                               dynamics(0.0, s, 0.0, p) + input_gain(s, p) * force, atol=1e-12)
    # (7.10) inverts the first row.
    assert force_for_acceleration(acc[0], theta, theta_dot, acc[1], p) == pytest.approx(
        force - b[0], abs=1e-9)


@pytest.mark.parametrize('x_dot,expected', [(0.2, 3.4), (-0.2, -2.45)])
def test_cart_friction_opposes_motion_with_directional_level(x_dot, expected):
    # (4.27): c_c,R = 3.4 N moving right, c_c,L = 2.45 N moving left (Table 4.1).
    assert cart_friction(x_dot, NOMINAL) == pytest.approx(expected, rel=1e-6)
    # In the dynamics: the generalised force it removes, M (a_friction - a_free) = -B.
    theta, theta_dot = 2.5, 0.0
    a_f = np.array(accelerations(0.3, theta, x_dot, theta_dot, 0.0, NOMINAL))
    a_0 = np.array(accelerations(0.3, theta, x_dot, theta_dot, 0.0, NOMINAL, friction=False))
    np.testing.assert_allclose(mass_matrix(theta, NOMINAL) @ (a_f - a_0), [-expected, 0.0],
                               atol=1e-9)


@pytest.mark.parametrize('theta_dot', [2.0, -2.0, 0.5])
def test_pendulum_friction_is_coulomb_plus_viscous(theta_dot):
    # (4.21)/(4.30): B_p = c_p sgn(theta_dot) + v_p theta_dot, c_p = 0.0038 N m, v_p = 0.00067.
    expected = 0.0038 * math.copysign(1.0, theta_dot) + 0.00067 * theta_dot
    assert pendulum_friction(theta_dot, NOMINAL) == pytest.approx(expected, rel=1e-6)
    theta = 2.0
    a_f = np.array(accelerations(0.3, theta, 0.0, theta_dot, 0.0, NOMINAL))
    a_0 = np.array(accelerations(0.3, theta, 0.0, theta_dot, 0.0, NOMINAL, friction=False))
    np.testing.assert_allclose(mass_matrix(theta, NOMINAL) @ (a_f - a_0), [0.0, -expected],
                               atol=1e-12)


def test_wrap_angle_range():
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(4 * math.pi + 0.1) == pytest.approx(0.1)


# -- linearisation (8.13)/(8.14) and LQR (8.24) -----------------------------------------------
def test_linearisation_matches_thesis_entries_with_corrected_a44():
    p = NOMINAL
    a, b = linearise_upright(p)
    m_p, l, m_c, g, v_p = p.m_p, p.l, p.m_c, p.g, p.v_p
    thesis_a = np.array([
        [0, 0, 1, 0],
        [0, 0, 0, 1],
        [0, m_p * g / m_c, 0, -v_p / (l * m_c)],
        [0, (m_c + m_p) * g / (l * m_c), 0, -(m_c + m_p) * v_p / (l ** 2 * m_p * m_c)],
    ])
    np.testing.assert_allclose(a, thesis_a, rtol=1e-12, atol=0)
    np.testing.assert_allclose(b.ravel(), [0, 0, 1 / m_c, 1 / (l * m_c)], rtol=1e-12)
    # The thesis prints A44 without the 1/m_c; that is m_c = 4.75 times too large.
    assert a[3, 3] == pytest.approx(-(m_c + m_p) * v_p / (l ** 2 * m_p) / m_c)


def numerical_jacobian(p, friction):
    def f(z, u):
        xdd, tdd = accelerations(z[0], z[1], z[2], z[3], u, p, friction=friction)
        return np.array([z[2], z[3], xdd, tdd])
    z0, eps = np.zeros(4), 1e-6
    a = np.column_stack([(f(z0 + eps * e, 0.0) - f(z0 - eps * e, 0.0)) / (2 * eps)
                         for e in np.eye(4)])
    b = (f(z0, eps) - f(z0, -eps)) / (2 * eps)
    return a, b


def test_linearisation_matches_finite_difference_jacobian():
    # Coulomb terms are not differentiable at rest and are left out of (8.13): the
    # Jacobian of (4.18) with only the viscous terms (Coulomb levels zero) must match,
    # and without any friction it must match A with v_p = 0.
    viscous_only = NOMINAL.replace(c_c_right=0.0, c_c_left=0.0, c_p=0.0)
    a_num, b_num = numerical_jacobian(viscous_only, friction=True)
    a, b = linearise_upright(NOMINAL)
    np.testing.assert_allclose(a_num, a, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(b_num, b.ravel(), rtol=1e-6, atol=1e-8)
    a_free, _ = numerical_jacobian(NOMINAL, friction=False)
    a_no_visc, _ = linearise_upright(NOMINAL.replace(v_p=0.0))
    np.testing.assert_allclose(a_free, a_no_visc, rtol=1e-6, atol=1e-8)


def test_lqr_gain_and_poles_match_thesis():
    # Q = diag(100, 400, 100, 400), R = 0.01 -> (8.24) k = [-100, 1012, -172.1, 266.8],
    # u = -k x. Poles (8.25) corrected (docs/controllers.md, "lqg"): -127.9, -1.68 +/- 1.41j, -1.00.
    a, b = linearise_upright(NOMINAL)
    q, r = np.diag([100.0, 400.0, 100.0, 400.0]), np.array([[0.01]])
    p_are = scipy.linalg.solve_continuous_are(a, b, q, r)
    k = np.linalg.solve(r, b.T @ p_are).ravel()
    thesis_k = np.array([-100.0, 1012.0, -172.1, 266.8])
    np.testing.assert_allclose(k, thesis_k, rtol=0.05)
    poles = np.linalg.eigvals(a - b @ k[None, :])
    poles = poles[np.argsort(poles.real)]
    assert poles[0].real == pytest.approx(-127.9, abs=0.5)
    assert poles[0].imag == pytest.approx(0.0, abs=1e-9)
    complex_pair = poles[1:3]
    assert complex_pair.real == pytest.approx([-1.68, -1.68], abs=0.02)
    assert sorted(complex_pair.imag) == pytest.approx([-1.41, 1.41], abs=0.02)
    assert poles[3].real == pytest.approx(-1.00, abs=0.02)


# -- parameters ---------------------------------------------------------------------------------
def test_thesis_values_and_derived_quantities():
    p = NOMINAL
    assert (p.m_p, p.l, p.m_c, p.g) == (0.251, 0.3345, 4.75, 9.81)
    assert p.force_max == pytest.approx(34.25, abs=0.01)
    assert p.force_min == pytest.approx(-37.36, abs=0.01)
    assert p.cart_resolution == pytest.approx(88.016e-6, rel=1e-4)      # (2.4)
    assert p.pendulum_resolution == pytest.approx(math.pi * 1e-3)      # (2.3)
    assert p.sample_time == 0.005


def test_parameters_yaml_round_trip(tmp_path):
    original = NOMINAL.with_scenario(tip_mass=0.201, friction_scale=1.2)
    path = tmp_path / 'plant.yaml'
    original.to_yaml(path)
    loaded = CartPoleParameters.from_yaml(path)
    assert loaded == original
    assert isinstance(loaded.pendulum_ticks_per_rev, int)
    # A flat mapping with a subset of keys is accepted too.
    (tmp_path / 'flat.yaml').write_text('m_c: 5.0\nl: 0.3\n')
    assert CartPoleParameters.from_yaml(tmp_path / 'flat.yaml') == NOMINAL.replace(m_c=5.0, l=0.3)


@pytest.mark.parametrize('changes,word', [
    ({'m_p': -0.1}, 'm_p'),
    ({'m_c': 0.0}, 'm_c'),
    ({'c_p': -1.0}, 'c_p'),
    ({'l': float('nan')}, 'l'),
    ({'current_min': 1.0}, 'current_min'),
])
def test_invalid_parameters_refused_with_reason(changes, word):
    with pytest.raises(ValueError, match=word):
        NOMINAL.replace(**changes)


def test_unknown_and_non_numeric_keys_refused(tmp_path):
    with pytest.raises(ValueError, match='cart_mas'):
        CartPoleParameters.from_dict({'cart_mas': 4.0})
    with pytest.raises(ValueError, match='m_c'):
        CartPoleParameters.from_dict({'m_c': 'heavy'})
    path = tmp_path / 'bad.yaml'
    path.write_text('cartpole_plant:\n  m_p: -0.25\n')
    with pytest.raises(ValueError, match='m_p'):
        CartPoleParameters.from_yaml(path)


def test_parameters_are_immutable():
    with pytest.raises(dataclasses.FrozenInstanceError):
        NOMINAL.m_p = 0.2


@pytest.mark.parametrize('x_dot,theta_dot', [(0.3, -2.0), (-0.01, 0.004), (0.0, 0.0), (-1.5, 7.0)])
def test_accelerations_use_the_friction_laws(x_dot, theta_dot):
    # accelerations() inlines cart_friction/pendulum_friction; (4.17) with B from the
    # friction functions must give the same numbers.
    from cartpole_core.model import cart_friction, pendulum_friction
    p = CartPoleParameters()
    theta, force = 0.7, 3.0
    with_friction = accelerations(0.2, theta, x_dot, theta_dot, force, p)
    # Friction enters (4.17) exactly like an opposing force on the cart and torque on the pendulum.
    no_friction = accelerations(0.2, theta, x_dot, theta_dot, force - cart_friction(x_dot, p), p,
                                friction=False)
    det = p.m_p * p.l ** 2 * (p.m_c + p.m_p * math.sin(theta) ** 2)
    b_p = pendulum_friction(theta_dot, p)
    expected_x = no_friction[0] - p.m_p * p.l * math.cos(theta) * b_p / det
    expected_th = no_friction[1] - (p.m_c + p.m_p) * b_p / det
    assert with_friction[0] == pytest.approx(expected_x, rel=1e-12, abs=1e-12)
    assert with_friction[1] == pytest.approx(expected_th, rel=1e-12, abs=1e-12)


def test_acceleration_function_is_accelerations_to_the_last_bit():
    from cartpole_core.model import acceleration_function
    rng = np.random.default_rng(3)
    for p in (CartPoleParameters(), CartPoleParameters(m_p=0.2, v_c=0.3, c_c_left=1.0)):
        acc = acceleration_function(p)
        for x, th, xd, thd, f in rng.normal(0.0, 3.0, size=(200, 5)):
            assert acc(x, th, xd, thd, f) == accelerations(x, th, xd, thd, f, p)
