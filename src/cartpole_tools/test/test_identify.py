"""Identification of the plant parameters from open-loop tests (thesis (4.22)-(4.26), 4.3.2).

The tests are synthesised on the simulated plant at known "true" parameters
that differ from the thesis values, and fitted starting from the thesis
values. The plant model is exact, so what is left between the fit and the
truth is the encoder quantisation (88 um cart ticks, pi/1000 rad pendulum
ticks; an RMS error of tick / sqrt(12)), the initial state estimated from
quantised samples, and the fit's coarser integration step (2.5 ms, for speed;
the data come from the default 1 ms plant).
"""
from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from cartpole_bringup import cli
from cartpole_tools.identification.bag_input import load_recording, recording_from_messages
from cartpole_tools.identification.fit import identify, parse_free
from cartpole_tools.identification.recording import IdentificationError, Recording
from cartpole_tools.identification.synthetic import pulse_forces, simulate_test
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Scenario

TRUE = {'m_c': 4.2, 'c_c_right': 3.0, 'c_c_left': 2.8, 'c_p': 0.005, 'v_p': 0.001}
THESIS = CartPoleParameters()
TS = THESIS.sample_time
FIT_STEP = 0.0025
# Section 4.3.1: a pulse from the left stop to the right, the cart coasts to a stop,
# then a pulse back to the left; the cart never reaches the far stop (0.43 m, 0.18 m).
PULSES = [(0.1, 0.25, 15.0), (1.8, 0.25, -12.0)]
CART_TICK = THESIS.cart_resolution
PEND_TICK = THESIS.pendulum_resolution


def _true_params() -> CartPoleParameters:
    return THESIS.replace(**TRUE)


def pulse_test(duration: float = 3.6) -> Recording:
    t = np.arange(int(round(duration / TS))) * TS
    return simulate_test(_true_params(), pulse_forces(t, PULSES), label='pulses')


def free_swing(duration: float = 4.0, amplitude: float = 1.5) -> Recording:
    """Appendix E / section 4.6 "Oscillation": released at rest `amplitude` rad off hanging."""
    n = int(round(duration / TS))
    return simulate_test(_true_params(), np.zeros(n),
                         Scenario(x0=0.38, theta0=math.pi - amplitude), label='swing')


@pytest.fixture(scope='module')
def recordings():
    return [pulse_test(), free_swing()]


@pytest.fixture(scope='module')
def fit(recordings):
    return identify(recordings, THESIS, integration_step=FIT_STEP)


def test_the_synthetic_tests_are_safe_and_informative(recordings):
    pulses, swing = recordings
    # Never near the far stop; both directions of travel (c_c,R and c_c,L) are excited.
    assert pulses.x.max() < THESIS.travel - 0.25 and pulses.x.max() > 0.3
    assert pulses.x[-1] > 0.1 and pulses.x[-1] < pulses.x.max() - 0.2
    # The swing decays: friction torque is visible in the data.
    first = np.max(np.abs(swing.theta[:250] - math.pi))
    last = np.max(np.abs(swing.theta[-250:] - math.pi))
    assert first > 1.45 and last < first - 0.1


def test_fit_recovers_the_true_parameters(fit):
    """m_c, c_c within 1 %; c_p, v_p within 5 %.

    The cart parameters are pinned by the accelerations during and after each
    pulse, hundreds of ticks of motion. c_p and v_p are small torques seen only
    through the swing's decay (a few ticks of amplitude per period) and trade
    off against each other (Coulomb and viscous losses differ only in their
    amplitude dependence), so they get the looser tolerance.
    """
    assert fit.success
    for name in ('m_c', 'c_c_right', 'c_c_left'):
        assert fit.values[name] == pytest.approx(TRUE[name], rel=0.01), name
    for name in ('c_p', 'v_p'):
        assert fit.values[name] == pytest.approx(TRUE[name], rel=0.05), name
    # And away from where it started (the thesis values are 12-33 % off).
    assert fit.initial_values == {k: getattr(THESIS, k) for k in TRUE}
    assert fit.at_bound == ()


def test_fit_leaves_only_quantisation_error(fit):
    """After the fit the RMS errors are about one tick / sqrt(12), the quantisation floor."""
    for r in fit.recordings:
        assert r.rmse_x_after_m < 2.0 * CART_TICK / math.sqrt(12), r
        assert r.rmse_theta_after_rad < 2.0 * PEND_TICK / math.sqrt(12), r
    pulses = fit.recordings[0]
    assert pulses.rmse_x_before_m > 0.05  # the thesis parameters miss the stop by centimetres
    assert fit.cost_after < 0.01 * fit.cost_before
    assert fit.cost_after == pytest.approx(sum(r.rmse_x_after_m for r in fit.recordings))


def test_standard_errors_are_small_and_finite(fit):
    for name in TRUE:
        se = fit.std_errors[name]
        assert 0.0 < se < 0.02 * TRUE[name], (name, se)
    corr = np.array(fit.correlation)
    np.testing.assert_allclose(np.diag(corr), 1.0, atol=1e-9)
    np.testing.assert_allclose(corr, corr.T, atol=1e-9)


def test_fitted_parameters_reproduce_a_test_they_did_not_see(fit):
    """Section 4.6 "Input" test: two opposite pulses from mid-rail, other amplitudes."""
    t = np.arange(int(round(2.5 / TS))) * TS
    check = simulate_test(_true_params(), pulse_forces(t, [(0.1, 0.2, -14.0), (1.2, 0.2, 13.0)]),
                          Scenario(x0=0.6))
    from cartpole_tools.identification.replay import simulate
    x_fit, _ = simulate(check, fit.params, (0.6, math.pi, 0.0, 0.0), FIT_STEP)
    x_thesis, _ = simulate(check, THESIS, (0.6, math.pi, 0.0, 0.0), FIT_STEP)
    assert np.max(np.abs(x_fit - check.x)) < 1e-3
    assert np.max(np.abs(x_thesis - check.x)) > 0.02


def test_a_swing_recorded_in_motion_needs_the_joint_initial_state(recordings):
    """No quiet lead-in (the recording starts mid-swing): the initial state is fitted too.

    The quadratic start estimate of a fast swing is off by a fraction of a tick
    and the phase error it leaves is absorbed into c_p/v_p (c_p twice the truth,
    v_p zero); fitting the initial state jointly brings the fit down to the
    quantisation floor. 10 % here: 3.7 s of swing barely separate Coulomb from
    viscous loss.
    """
    swing = recordings[1].window(t_start=0.3)
    start = THESIS.replace(**{k: TRUE[k] for k in ('m_c', 'c_c_right', 'c_c_left')})
    plain = identify([swing], start, free=['c_p', 'v_p'], integration_step=FIT_STEP)
    res = identify([swing], start, free=['c_p', 'v_p'], refine_initial_state=True,
                   integration_step=FIT_STEP)
    for name in ('c_p', 'v_p'):
        assert res.values[name] == pytest.approx(TRUE[name], rel=0.10), name
    fit = res.recordings[0]
    assert fit.rmse_theta_after_rad < 2.0 * PEND_TICK / math.sqrt(12)
    assert plain.recordings[0].rmse_theta_after_rad > 1.2 * fit.rmse_theta_after_rad
    assert abs(fit.initial_state[3]) > 3.0  # released 0.3 s earlier: swinging fast


def test_only_the_free_parameters_change(recordings):
    res = identify(recordings[:1], THESIS, free=['m_c'], integration_step=FIT_STEP, passes=1)
    assert res.free == ('m_c',)
    changed = {k for k, v in res.params.to_dict().items() if v != getattr(THESIS, k)}
    assert changed == {'m_c'}
    # With the friction held at the wrong values, m_c is off and the error stays large.
    assert res.recordings[0].rmse_x_after_m > 10 * CART_TICK


def test_bounds_hold_like_fmincon(recordings):
    """(4.23) bounded the search; a bound below the truth stops the fit at the bound."""
    res = identify(recordings[:1], THESIS, free=['m_c', 'c_c_right', 'c_c_left'],
                   bounds={'m_c': (4.5, 5.0)}, integration_step=FIT_STEP, passes=1, max_nfev=8)
    assert res.values['m_c'] == pytest.approx(4.5, abs=1e-9)
    assert res.at_bound == ('m_c',)


def test_bad_free_parameters_are_refused():
    with pytest.raises(IdentificationError, match='unknown parameter'):
        parse_free('m_c,mass')
    with pytest.raises(IdentificationError, match='cannot be fitted'):
        parse_free('sample_time')
    with pytest.raises(IdentificationError, match='repeat'):
        parse_free('m_c,m_c')


def test_too_few_samples_are_refused():
    with pytest.raises(IdentificationError, match='at least 20'):
        Recording(np.arange(5) * TS, np.zeros(5), np.full(5, math.pi), np.zeros(5), 'short')


# -- from messages: timing, hold, watchdog ------------------------------------------------------
def _ns(t: float) -> int:
    return int(round(t * 1e9))


def test_messages_become_a_zoh_recording_on_the_sample_grid():
    t0 = 1.7e9  # a wall-clock epoch, as the hw bridge stamps
    jitter = [0.0, 0.0004, -0.0006, 0.0011, 0.0, -0.0002]
    samples = []
    for k in range(80):
        samples.append((_ns(t0 + k * TS + jitter[k % 6]), 0.001 * k, math.pi))
    samples.append(samples[7])  # a duplicate sample is dropped
    del samples[20]  # a lost sample leaves a 10 ms gap
    # Commands answer samples 5..9 with their stamps, then stop.
    commands = [(samples[k][0], 10.0 + k) for k in range(5, 10)]
    rec = recording_from_messages(samples, commands)
    assert rec.t.size == 79
    assert rec.t[0] == 0.0
    np.testing.assert_allclose(np.diff(rec.t)[:18], TS, atol=1e-12)
    assert rec.t[20] - rec.t[19] == pytest.approx(2 * TS)
    np.testing.assert_array_equal(rec.force[:5], 0.0)
    np.testing.assert_array_equal(rec.force[5:10], [15.0, 16.0, 17.0, 18.0, 19.0])
    # The last command is held until the watchdog (50 ms) zeroes the current.
    np.testing.assert_array_equal(rec.force[10:19], 19.0)
    np.testing.assert_array_equal(rec.force[20:], 0.0)


def test_bursty_receipt_stamps_keep_the_sample_count():
    """USB serial delivers samples in bursts: pairs 10 ms apart, a 30 ms stall, one loss."""
    from cartpole_tools.identification.bag_input import sample_indices
    true_k = np.array([k for k in range(200) if k != 120])  # sample 120 lost
    latency = np.where(true_k % 2 == 0, TS - 0.0001, 0.0003)  # an even one waits for the next
    t = true_k * TS + latency
    late = (true_k >= 60) & (true_k < 66)
    t[late] = 66 * TS + 0.0002 + 1e-5 * np.arange(late.sum())  # a 30 ms stall
    assert np.all(t >= true_k * TS) and np.all(np.diff(t) > 0)
    np.testing.assert_array_equal(sample_indices(t, TS), true_k)
    # Snapping each stamp to the nearest 5 ms would have got them wrong.
    assert np.any(np.round((t - t[0]) / TS) != true_k)


def test_commands_without_times_are_refused():
    samples = [(_ns(1.0 + k * TS), 0.0, math.pi) for k in range(30)]
    with pytest.raises(IdentificationError, match='same time'):
        recording_from_messages(samples, [(0, 5.0), (0, 5.0), (0, 0.0)])
    with pytest.raises(IdentificationError, match='--zero-force'):
        recording_from_messages(samples, [])
    rec = recording_from_messages(samples, [], zero_force=True)
    np.testing.assert_array_equal(rec.force, 0.0)


# -- bags and the command ---------------------------------------------------------------------------
def write_bag(path, rec, *, t_origin: float = 1.7e9, topics=('/joint_states',
                                                                          '/cartpole/force_command'),
              zero_command_stamps: bool = False):
    """A rosbag2 (MCAP, ROS2_JAZZY types) as the recorder writes it from the rig.

    With ``zero_command_stamps`` the commands carry no stamp (``ros2 topic pub``)
    and the bag is logged with receive times, 1 ms after each sample.
    """
    from rosbags.typesys import Stores, get_typestore

    from cartpole_analysis.bags.writer import BagWriter

    ts = get_typestore(Stores.ROS2_JAZZY)
    js = ts.types['sensor_msgs/msg/JointState']
    header = ts.types['std_msgs/msg/Header']
    time = ts.types['builtin_interfaces/msg/Time']

    def msg(t, names, position=(), effort=()):
        ns = _ns(t)
        m = js(header=header(stamp=time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=''),
               name=list(names), position=np.array(position, dtype=float),
               velocity=np.array([], dtype=float), effort=np.array(effort, dtype=float))
        return ts.serialize_cdr(m, 'sensor_msgs/msg/JointState')

    log_time = 'receive' if zero_command_stamps else 'stamp'
    with BagWriter(path, log_time=log_time) as bag:
        for k in range(rec.t.size):
            t = t_origin + rec.t[k]
            if '/joint_states' in topics:
                bag.write('/joint_states', msg(t, ('cart', 'pendulum'),
                                               (rec.x[k], rec.theta[k])), _ns(t))
            if '/cartpole/force_command' in topics:
                if zero_command_stamps:
                    if rec.force[k] != 0.0:  # only the pulses are published
                        bag.write('/cartpole/force_command',
                                  msg(0.0, ('cart',), effort=(rec.force[k],)), _ns(t + 0.001))
                else:
                    bag.write('/cartpole/force_command',
                              msg(t, ('cart',), effort=(rec.force[k],)), _ns(t))
            if not topics:
                clock = ts.types['rosgraph_msgs/msg/Clock'](clock=time(sec=int(t), nanosec=0))
                bag.write('/clock', ts.serialize_cdr(clock, 'rosgraph_msgs/msg/Clock'), 0)


def test_bag_loader_reads_back_the_recording(tmp_path, recordings):
    rec = recordings[0]
    write_bag(tmp_path / 'pulses', rec)
    back = load_recording(tmp_path / 'pulses')
    assert back.label == 'pulses'
    np.testing.assert_allclose(back.t, rec.t, atol=1e-9)
    np.testing.assert_array_equal(back.x, rec.x)
    np.testing.assert_array_equal(back.theta, rec.theta)
    np.testing.assert_array_equal(back.force, rec.force)
    window = load_recording(tmp_path / 'pulses', t_start=1.0, t_end=2.0)
    assert window.t.size == 201 and window.t[0] == pytest.approx(1.0)


def test_unstamped_commands_use_the_receive_time(tmp_path, recordings):
    """``ros2 topic pub`` pulses (zero stamps) recorded with ``log_time:=receive``."""
    rec = recordings[0]
    write_bag(tmp_path / 'pub', rec, zero_command_stamps=True)
    back = load_recording(tmp_path / 'pub')
    # Pulses land on their samples; after the last command of a pulse the device keeps the
    # setpoint until the 50 ms watchdog zeroes it: 9 more samples (45 ms) of the pulse's force.
    t = rec.t
    expected = pulse_forces(t, [(start, length + 9 * TS, f) for start, length, f in PULSES])
    np.testing.assert_array_equal(back.force, expected)


def test_identify_command_on_a_bag(tmp_path, recordings, capsys):
    """Cart parameters from a pulse bag, the pendulum's known (``--plant-params``)."""
    bag = tmp_path / 'rig' / 'pulses'
    write_bag(bag, recordings[0])
    start = tmp_path / 'start.yaml'
    THESIS.replace(c_p=TRUE['c_p'], v_p=TRUE['v_p']).to_yaml(start)
    out_yaml = tmp_path / 'rig.yaml'
    code = cli.main(['identify', str(bag), '--json', '--output', str(out_yaml),
                     '--plant-params', str(start), '--free', 'm_c,c_c_right,c_c_left',
                     '--integration-step', str(FIT_STEP)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    report = json.loads(captured.out)
    assert report['success'] is True and report['output'] == str(out_yaml)
    assert report['free'] == ['m_c', 'c_c_right', 'c_c_left']
    assert report['recordings'][0]['samples'] == recordings[0].t.size
    assert report['recordings'][0]['rmse_x_after_m'] < 2 * CART_TICK / math.sqrt(12)
    fitted = CartPoleParameters.from_yaml(out_yaml)
    for name in ('m_c', 'c_c_right', 'c_c_left'):
        assert getattr(fitted, name) == pytest.approx(TRUE[name], rel=0.01)
        assert report['fitted'][name] == pytest.approx(getattr(fitted, name), rel=1e-12)
    # The pendulum friction was not free: the file keeps the starting values.
    assert fitted.c_p == TRUE['c_p'] and fitted.v_p == TRUE['v_p']
    assert fitted.m_p == THESIS.m_p and fitted.l == THESIS.l
    assert out_yaml.read_text().startswith('# Plant parameters fitted by `cartpole identify`')


def test_identify_command_prints_a_table(tmp_path, recordings, capsys):
    bag = tmp_path / 'pulses'
    write_bag(bag, recordings[0])
    plot = tmp_path / 'fit.png'
    code = cli.main(['identify', str(bag), '--free', 'm_c', '--integration-step', '0.005',
                     '--max-nfev', '3', '--plot', str(plot)])
    out = capsys.readouterr().out
    assert code == 0
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert f'wrote: {plot}' in out
    assert out.splitlines()[0].split() == ['parameter', 'initial', 'fitted', 'std.', 'error',
                                           'change']
    assert 'cost (4.22)' in out and 'pulses' in out


@pytest.mark.parametrize('case, message', [
    ('no_topics', 'no /joint_states samples'),
    ('no_force', 'no /cartpole/force_command messages'),
    ('short', 'at least 20'),
    ('missing', 'no such bag'),
    ('not_a_bag', 'not a rosbag2 bag'),
])
def test_bad_bags_give_a_clear_error(tmp_path, recordings, capsys, case, message):
    bag = tmp_path / case
    if case == 'no_topics':
        write_bag(bag, recordings[0], topics=())
    elif case == 'no_force':
        write_bag(bag, recordings[0], topics=('/joint_states',))
    elif case == 'short':
        r = recordings[0]
        write_bag(bag, SimpleNamespace(t=r.t[:10], x=r.x[:10], theta=r.theta[:10],
                                       force=r.force[:10]))
    elif case == 'not_a_bag':
        bag.mkdir()
    code = cli.main(['identify', str(bag), '--output', str(tmp_path / 'out.yaml')])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and 'Traceback' not in err
    assert not (tmp_path / 'out.yaml').exists()


@pytest.mark.parametrize('argv, message', [
    (['--free', 'm_c,bogus'], 'unknown parameter'),
    (['--bound', 'm_c=5'], 'NAME=LO:HI'),
    (['--bound', 'c_p=1:5'], 'not free'),
    (['--bound', 'm_c=5:1'], 'low < high'),
    (['--output', '/nonexistent/dir/x.yaml'], 'does not exist'),
])
def test_bad_options_give_a_clear_error(tmp_path, recordings, capsys, argv, message):
    bag = tmp_path / 'pulses'
    write_bag(bag, recordings[0])
    code = cli.main(['identify', str(bag), '--free', 'm_c', '--max-nfev', '1', *argv]
                    if '--free' not in argv else ['identify', str(bag), '--max-nfev', '1', *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and 'Traceback' not in err
