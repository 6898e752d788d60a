"""Scenarios of the combined benchmark (docs/robustness.md, "Every disturbance at once") that
failed, replayed in the offline closed loop with the default pair: each reproduces one kind
of failure that a change of the control stack removed."""
import numpy as np
import pytest

from cartpole_sim.scenario_ranges import RangeTable, sample
from manager_test_support import THESIS_INTEGRAL


def replay(index, seed=0, duration=30.0, manager_parameters=None, **options):
    """The run summary of scenario ``index`` of ``cartpole bench robustness --combined N
    --seed seed`` (the published ranges), stopped at its first failure as the benchmark does;
    ``options`` go to ``run_closed_loop`` (``ekf_config``, ``observer``)."""
    from cartpole_bringup.offline.closed_loop import run_closed_loop

    scenario = sample(RangeTable(), np.random.default_rng([seed, index]))
    return run_closed_loop(scenario=scenario, duration=duration, stop_on_failure=True,
                           manager_parameters=manager_parameters, **options).summary


@pytest.mark.slow
@pytest.mark.parametrize('index', [35, 176])
def test_the_first_stroke_on_an_unmeasured_lagging_amplifier_no_longer_trips_the_guard(index):
    """35: gain 0.96 on a cart 14 % light, 26 ms of lag; 176: gain 1.28, 25 ms of lag. The
    swing-up's first stroke ran to 1.8-2 m/s before the actuator estimate was ready, and the
    guard, taking its brake as acting at once, limited too late and tripped at 0.5-0.8 s.
    With the dead-time prior (``rail.actuator_dead_time``) the limiter bends it in time."""
    summary = replay(index)
    assert summary['fault'] is None
    assert summary['success'], summary


@pytest.mark.slow
@pytest.mark.parametrize('index', [13, 71])
def test_a_catch_that_would_run_the_cart_to_the_limiter_waits_and_holds(index):
    """13: gain 1.13 with 19 ms of lag; 71: gain 0.89 with 29 ms of lag, a heavy cart. Caught
    where the simulated catch (nominal plant, no dead time, the stops' margin) held, the real
    catch ran the cart into the guard's limiter band, and the pendulum fell 1-3 s later. The
    region of the guard's band and its unmeasured dead time waits for a catch that holds."""
    summary = replay(index)
    assert summary['falls_after_catch'] == 0
    assert summary['success'], summary


@pytest.mark.slow
def test_a_cart_at_rest_near_a_stop_may_still_catch_its_pendulum():
    """Seed 2, draw 120, ``mpc``: caught at 33 deg, the catch's transient left the cart at rest
    2.9 cm from the left stop with the pendulum leaning towards it. With 1 cm of the guard's
    reserve at rest (before 2026-12-06, afternoon) every push towards that stop was withheld
    and the pendulum fell 1.9 s after the catch; with none, a push whose stopping position
    stays outside the margin passes, and the draw holds."""
    summary = replay(120, seed=2, manager_parameters={'stabilizer': 'mpc'})
    assert summary['falls_after_catch'] == 0 and summary['impacts'] == 0
    assert summary['success'], summary


@pytest.mark.slow
def test_lost_samples_no_longer_starve_the_actuator_estimate():
    """Seed 0, draw 28: amplifier gain 1.20 on a cart 25 % heavy, 4.7 % of the samples lost.
    A window of the estimate needs 41 samples in a row; it began afresh at every loss, so
    the gain stayed at the nominal 1.00, the catch came at 37 deg and the pendulum fell. Lost
    samples are filled in: the estimate (G over the mass ratio, 0.92) is learnt, the catch
    holds. (Measured with the EKF fed the command as sent, as when it was found: 0.94; fed the
    force as it acts, a run whose swing-up excites the estimate less, 0.98, and it holds.)"""
    from cartpole_estimation.ekf_config import EkfConfig

    summary = replay(28, ekf_config=EkfConfig(force_input='command'))
    assert summary['actuator_gain'] < 0.97
    assert summary['falls_after_catch'] == 0
    assert summary['success'], summary
    assert replay(28)['success']


@pytest.mark.slow
def test_a_rig_with_more_friction_balances_within_target():
    """Seed 0, draw 88: cart friction x1.6. With the model's friction feedforward the balanced
    cart ran a stick-slip limit cycle beyond 10 cm (the pendulum fell); the estimated friction
    scale sizes it. Since the actuator's windows are computed after the command and the
    encoder offset is learnt only near an equilibrium, the unscaled run of this draw holds
    too, with a wider cycle (5.4 cm against 4.7 cm; 6.0 against 3.6 cm before the offset's
    gate)."""
    summary = replay(88)
    assert summary['friction_scale'] > 1.3
    assert summary['success'], summary
    unscaled = replay(88, manager_parameters={'actuator.friction': 1.0})
    assert not unscaled['success'] or unscaled['x_err_max_m'] > summary['x_err_max_m']


@pytest.mark.slow
@pytest.mark.parametrize('index', [27, 166])
def test_a_rig_with_more_friction_and_dead_time_balances_in_a_stiff_enough_loop(index):
    """Seed 4, draws 27 and 166: friction x1.48 / x1.59, 25 / 23 ms of delay, 14 / 19 ms of
    lag. With R weighed by the dead time up to 5 R at the catch the cart loop was too soft for
    that friction: a cycle of about 4 s, 1.8-1.9 deg and 10.6-10.8 cm, off target. At most 2 R
    (``lqg.dead_time_weight_max``) it balances within 1.6 deg and 8.8 cm (draw 27's catch
    transient ends 3.6 cm from the left stop: 7.7 cm with the guard's 1 cm reserve at rest,
    before 2026-12-06, afternoon)."""
    summary = replay(index, seed=4)
    assert summary['falls_after_catch'] == 0
    assert summary['success'], summary
    soft = replay(index, seed=4, manager_parameters={'lqg.dead_time_weight_max': 5.0})
    assert not soft['success'], soft
    assert soft['x_err_max_m'] > summary['x_err_max_m'] + 0.015, (soft, summary)


@pytest.mark.slow
@pytest.mark.parametrize('seed, index, catch_by', [(0, 172, 12.5), (0, 34, 10.0)])
def test_a_cart_parked_off_centre_comes_back_and_the_pendulum_is_caught(seed, index, catch_by):
    """Seed 0, draw 172: a short pendulum on a heavy cart and a slow amplifier; seed 1, draw
    164 (until 2026-12-06; since, it is caught at 3.0 s with or without k_v and falls 0.8 s
    later) and seed 0, draw 34 (from 2026-12-06). Without the damped cart term the pendulum
    circled at E* with the cart parked far off x* (0.61-0.69 m on draw 164), held by friction
    against the undamped P-term of (7.32), and the catch region refused every pass for 30 s;
    k_v brings it back and the catch comes. (Draw 172's run without k_v is caught at 3.8 s
    since the offset's gate judges the encoders' angle; draw 34 still shows it, with the
    thesis's energy integral: the one confined near E* (2026-12-06) catches it at 2.7 s
    without k_v too.) Since that integral draw 172 is caught at 11.8 s (3.7 s before): its
    cart parked 27-30 cm off x* with the pendulum 4-6 % above E* until 11 s."""
    summary = replay(index, seed)
    assert summary['catch_time_s'] is not None and summary['catch_time_s'] < catch_by
    assert summary['success'], summary
    if index == 34:
        thesis = replay(index, seed, manager_parameters={'pendulum_energy.k_v': 0.0,
                                                         **THESIS_INTEGRAL})
        assert thesis['catch_time_s'] is None


@pytest.mark.slow
def test_a_swing_on_a_plant_unlike_the_model_is_not_taken_for_an_encoder_offset():
    """Seed 0, draw 134: a pendulum 49 % heavier and 11 % longer, 22 ms of delay, 15 ms of
    lag, an encoder offset of 39 mrad. The filter's offset state took up the model's error
    of the swing-up (off by up to 50 mrad), the catch region, fed an angle that far off,
    refused every pass until 21 s, and the run ended off target. Corrected only near an
    equilibrium (``EkfConfig.offset_gate_*``), the offset is learnt at the hanging start
    and kept within 5 mrad through the swing-up, and the catch comes at 3 s. With the
    thesis's energy integral, the swing-up it was found with (with the one confined near E*
    the gated offset is kept as well and the catch comes at 5.3 s, the ungated at 7.5 s)."""
    import math

    from cartpole_estimation.ekf_config import EkfConfig

    def offset_error_in_the_swing_up(config):
        truth = sample(RangeTable(), np.random.default_rng([0, 134])).encoder_offset
        worst = [0.0]

        def observer(measurement, estimate, output, true_state):
            if output.mode == 'swingup' and estimate.t >= 0.3:
                worst[0] = max(worst[0], abs(estimate.angle_offset - truth))
        return replay(134, manager_parameters=THESIS_INTEGRAL, ekf_config=config,
                      observer=observer), worst[0]

    # The EKF fed the command as sent, as when it was found (fed the force as it acts the
    # offset is kept as well; the catch comes at 14.8 s and the run succeeds).
    summary, error = offset_error_in_the_swing_up(EkfConfig(force_input='command'))
    assert error < 0.005
    assert summary['catch_time_s'] < 4.0 and summary['success'], summary
    summary, error = offset_error_in_the_swing_up(EkfConfig())
    assert error < 0.005 and summary['success'], summary
    always = EkfConfig(offset_gate_rate=math.inf, offset_gate_force=math.inf,
                       offset_gate_angle=math.pi / 2, force_input='command')
    summary, error = offset_error_in_the_swing_up(always)
    assert error > 0.03, error
    assert summary['catch_time_s'] is None or summary['catch_time_s'] > 10.0
