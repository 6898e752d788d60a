"""The pendulum's natural frequency estimated from the encoders, and the swing-up that fits it."""
import math

import pytest

from cartpole_control.natural_frequency import NaturalFrequencyEstimator
from cartpole_core.model import CartPoleParameters, accelerations, pendulum_energy
from manager_test_support import THESIS_INTEGRAL

P = CartPoleParameters()


def swinging(params, seconds=3.0, ts=0.005, theta0=math.pi - 0.4):
    """Samples (t, x, theta) of a pendulum swinging freely on a cart pushed to and fro."""
    h = 0.0005
    x, th, xd, thd = 0.38, theta0, 0.0, 0.0
    out = []
    per = int(round(ts / h))
    for k in range(int(seconds / h) + 1):
        if k % per == 0:
            out.append((k * h, x, th))
        force = 15.0 * math.sin(2.0 * math.pi * 0.7 * k * h)
        xdd, thdd = accelerations(x, th, xd, thd, force, params)
        x, th, xd, thd = x + h * xd, th + h * thd, xd + h * xdd, thd + h * thdd
    return out


@pytest.mark.parametrize('scale', [0.75, 1.0, 1.25])
def test_the_estimate_finds_g_over_l_of_the_pendulum_it_sees(scale):
    est = NaturalFrequencyEstimator(P)
    for t, x, theta in swinging(P.replace(l=P.l * scale)):
        est.update(t, x, theta)
    assert est.omega_sq == pytest.approx(P.g / (P.l * scale), rel=0.01)
    assert est.windows > 50


def test_at_the_nominal_estimate_energy_and_target_are_the_thesis_ones():
    est = NaturalFrequencyEstimator(P)
    assert est.upright_energy == pytest.approx(P.upright_energy)
    assert est.energy(2.0, 3.0) == pytest.approx(pendulum_energy(2.0, 3.0, P))


def test_a_hanging_pendulum_at_rest_changes_nothing_and_gaps_restart_the_window():
    est = NaturalFrequencyEstimator(P)
    for k in range(400):
        est.update(0.005 * k, 0.0, math.pi)
    assert est.omega_sq == pytest.approx(est.nominal)
    est.update(10.0, 0.0, math.pi + 0.1)             # after a gap: a new window
    assert est.omega_sq == pytest.approx(est.nominal)


@pytest.mark.slow
@pytest.mark.parametrize('scenario_changes', [
    {'parameter_scales': (('l', 0.75),)},  # fell until the offset's gate (2026-12-05)
    {'parameter_scales': (('l', 1.25),)},
    {'tip_mass': 1.25 * P.m_p},
], ids=['length-25%', 'length+25%', 'tip-mass+25%'])
def test_the_adaptive_swing_up_catches_the_pendulum_it_has(scenario_changes):
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario

    scenario = Scenario(noise=True, seed=0, **scenario_changes)
    run = run_closed_loop(P, scenario, duration=25.0, stop_on_failure=True)
    s = run.summary
    assert s['success'] and not s['end_stop_contact'], s
    assert not any('fall' in e for _, e in run.events)
    true = run.upright_energy / (2 * scenario.plant_parameters(P).m_p
                                 * scenario.plant_parameters(P).l ** 2)
    assert s['omega0_sq'] == pytest.approx(true, rel=0.02)


@pytest.mark.slow
def test_the_thesis_fixed_target_loses_the_longer_pendulum_the_adaptive_one_keeps():
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario

    # the cart term of the thesis (k_v = 0): the damped one brings the cart back to x* while
    # the pendulum circles, which rescues this run even with the fixed target. 15 % longer:
    # at 10 % the fixed target holds too since the EKF learns the encoder offset only near
    # an equilibrium (2026-12-05). And the thesis's energy integral (at every energy, k_i
    # 0.02): the one confined near E* (2026-12-06) brings even the fixed target's pendulum
    # over (caught at 2.87 s)
    thesis = {'pendulum_energy.k_v': 0.0, **THESIS_INTEGRAL}
    scenario = Scenario(noise=True, seed=0, parameter_scales=(('l', 1.15),))
    fixed = run_closed_loop(P, scenario, duration=25.0,
                            manager_parameters={'pendulum_energy.adaptive_target': False,
                                                **thesis})
    adaptive = run_closed_loop(P, scenario, duration=25.0, manager_parameters=thesis)
    assert not fixed.summary['success'] and fixed.summary['theta_amp_deg'] > 90.0
    assert adaptive.summary['success']


@pytest.mark.slow
def test_ten_minutes_hanging_idle_leave_the_estimates_where_they_were():
    """Noise on, the pendulum encoder zeroed one tick off: 10 minutes of a hanging pendulum
    at rest teach nothing, so omega_0^2 and the actuator gain stay within 5 % (the plant is
    the real one; the estimates are checked every 10 s)."""
    from cartpole_control.manager import ControllerManager
    from cartpole_sim.plant import Plant, Scenario

    p = CartPoleParameters()
    manager = ControllerManager(p, enabled=False)
    plant = Plant(p, Scenario(noise=True, seed=3, x0=0.38,
                              encoder_offset=p.pendulum_resolution), integration_step=0.005)
    estimate = manager.plant_estimate
    for k in range(int(600.0 / p.sample_time)):
        meas = plant.measure()
        for source, applied in plant.applied_commands():
            manager.command_applied(source, applied)
        manager.measured(meas.t, meas.x, meas.theta)
        out = manager.update_values(meas.t, meas.x, meas.theta, 0.0, 0.0)
        assert out.force == 0.0
        plant.step(out.force)
        if k % 2000 == 0:
            assert estimate.natural_frequency.omega_sq == pytest.approx(p.g / p.l, rel=0.05)
            assert estimate.actuator.gain == pytest.approx(1.0, rel=0.05)
    assert estimate.natural_frequency.omega_sq == pytest.approx(p.g / p.l, rel=0.05)
    assert estimate.actuator.gain == pytest.approx(1.0, rel=0.05)
