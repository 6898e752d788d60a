"""Analysis of bags with a known trajectory: the run summary, sources, plots, the CLI."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location('bag_synth', Path(__file__).with_name('bag_synth.py'))
bag_synth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bag_synth)

from cartpole_bringup import cli  # noqa: E402
from cartpole_analysis.analysis.analyze import analyze_bag  # noqa: E402
from cartpole_analysis.analysis.plots import heteroclinic_orbit  # noqa: E402

PNG_MAGIC = b'\x89PNG\r\n\x1a\n'


@pytest.fixture(scope='module')
def known_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'known' / 'bag'
    bag_synth.write_run(path, custom_data={'x_ref': repr(bag_synth.X_REF), 'lockstep': 'true'})
    return path


def test_known_trajectory_gives_the_known_summary(known_bag):
    a = analyze_bag(known_bag)
    s = a.summary
    assert a.source == '/cartpole/true_state'
    assert a.controllers == {'swingup': 'pendulum_energy', 'stabilizer': 'lqg'}
    assert s['catch_time_s'] == pytest.approx(bag_synth.CATCH_TIME, abs=1e-9)
    # pi (1 - t/6) <= 10 deg first at t = 5.6667 s, the sample at 5.670 s (Ts 10 ms).
    assert s['upright_time_s'] == pytest.approx(5.670, abs=1e-9)
    assert s['theta_amp_deg'] == pytest.approx(math.degrees(0.01), rel=1e-9)
    assert s['x_err_max_m'] == pytest.approx(0.05, rel=1e-9)
    # Mean of sin^2 over whole periods, 1001 samples in [10, 20] s (the two ends are zeros).
    assert s['mse_x'] == pytest.approx(0.05 ** 2 / 2 * 1000 / 1001, rel=1e-6)
    assert s['mse_theta'] == pytest.approx(0.01 ** 2 / 2 * 1000 / 1001, rel=1e-6)
    assert s['end_stop_contact'] is False
    assert s['success'] is True
    assert s['swingup_law'] is None  # not recorded: not guessed
    # The force commands, 2 sin(t), over the last 10 s (the summary's force_rms_n, force_p2p_n).
    t, *_, force = bag_synth.trajectory()
    last = force[t >= t[-1] - 10.0]
    assert s['force_rms_n'] == pytest.approx(float(np.sqrt(np.mean(last ** 2))), rel=1e-9)
    assert s['force_p2p_n'] == pytest.approx(float(last.max() - last.min()), rel=1e-9)
    assert a.topics['/cartpole/true_state'] == 2001
    assert a.series.t[0] == 0.0 and a.series.t[-1] == pytest.approx(20.0)


def test_the_scoring_window_comes_from_the_bag_or_the_caller(tmp_path, known_bag):
    """``cartpole run --window 3`` stores ``window_s``; the analysis scores the last 3 s."""
    path = tmp_path / 'run' / 'bag'
    bag_synth.write_run(path, custom_data={'x_ref': repr(bag_synth.X_REF), 'lockstep': 'true',
                                           'window_s': '3.0'})
    t, *_, force = bag_synth.trajectory()
    for s in (analyze_bag(path).summary, analyze_bag(known_bag, window=3.0).summary):
        last = force[t >= t[-1] - 3.0]
        assert s['force_rms_n'] == pytest.approx(float(np.sqrt(np.mean(last ** 2))), rel=1e-9)
        assert s['success'] is True
    assert analyze_bag(path, window=10.0).summary == analyze_bag(known_bag).summary


def test_summary_names_the_swingup_law_of_the_catch(tmp_path):
    # The status at the catch names the law that swung up; what the swing-up plugin
    # reports later (here: after the catch, a fall-back reason) does not change it.
    path = tmp_path / 'bag'
    bag_synth.write_run(path, swingup_laws=('time_optimal:plan',
                                            'time_optimal:fallback(not at hanging rest)'))
    assert analyze_bag(path).summary['swingup_law'] == 'time_optimal:plan'
    bag_synth.write_run(tmp_path / 'bag2', swingup_laws=('time_optimal:fallback(no plan)',
                                                         'time_optimal:fallback(no plan)'))
    assert analyze_bag(tmp_path / 'bag2').summary['swingup_law'] == 'time_optimal:fallback(no plan)'


def test_series_builder_takes_the_law_at_the_catch_from_a_status_series():
    from cartpole_analysis.analysis.analyze import SeriesBuilder
    b = SeriesBuilder()
    statuses = [('swingup', '', 'time_optimal'), ('swingup', '', 'time_optimal:plan'),
                ('stabilizing', 'catch', 'time_optimal:plan'),
                ('swingup', 'fall', 'time_optimal:fallback(not at hanging rest)')]
    for k, (mode, event, law) in enumerate(statuses):
        b.status(k, {'mode': mode, 'event': event, 'swingup_law': law,
                     'state_stamp': repr(k * 0.005)})
    assert b.swingup_law == 'time_optimal:plan'
    never = SeriesBuilder()
    never.status(0, {'mode': 'swingup', 'event': '', 'swingup_law': 'pendulum_energy'})
    assert never.swingup_law == 'pendulum_energy'


def test_real_time_origin_is_the_start_of_control_not_the_first_recorded_sample():
    """With one process a node, the plant can run before the controller manager's first
    cycle, or a subscription can match seconds late: t = 0 is the first status with a
    controller running, so the catch time is the swing-up's (here 2.8 s, recorded
    samples from 1.5 s after the swing-up began)."""
    from cartpole_analysis.analysis.analyze import SeriesBuilder
    from cartpole_core.model import CartPoleParameters
    p = CartPoleParameters()
    start, ts = 1_000_000_000_000, 5_000_000
    b = SeriesBuilder()
    for k in range(0, 4000):              # 20 s of control from `start`
        t = start + k * ts
        mode = 'swingup' if k < 560 else 'stabilizing'
        b.status(t, {'mode': mode, 'event': 'catch' if k == 560 else '',
                     'swingup': 'pendulum_energy', 'stabilizer': 'lqg',
                     'state_stamp': repr(t * 1e-9)})
        if k >= 300:                      # the truth matched 1.5 s late
            b.joint_state('/cartpole/true_state', t, [p.x_middle, 0.0], [0.0, 0.0], [0.0, 0.0])
    series, summary = b.summarize(params=p, x_ref=p.x_middle, lockstep=False)
    assert summary['catch_time_s'] == pytest.approx(2.8, abs=1e-9)
    assert summary['controllers'][0]['start_s'] == 0.0
    assert series.t[0] == pytest.approx(1.5, abs=1e-9)
    # without any status the first sample stays the origin
    bare = SeriesBuilder()
    for k in range(300, 4000):
        bare.joint_state('/cartpole/true_state', start + k * ts, [p.x_middle, 0.0],
                         [0.0, 0.0], [0.0, 0.0])
    assert bare.summarize(params=p, x_ref=p.x_middle, lockstep=False)[0].t[0] == 0.0


def test_x_ref_option_overrides_the_bag(known_bag):
    s = analyze_bag(known_bag, x_ref=bag_synth.X_REF + 0.2).summary
    assert s['x_err_max_m'] == pytest.approx(0.25, rel=1e-9)
    assert s['success'] is False


def test_truth_outside_the_travel_is_end_stop_contact(tmp_path):
    path = tmp_path / 'bag'
    bag_synth.write_run(path, x_offset=0.36)  # x reaches x* + 0.41 > 0.769 m
    s = analyze_bag(path, x_ref=bag_synth.X_REF).summary
    assert s['end_stop_contact'] is True and s['success'] is False


def test_hardware_bag_uses_the_estimate_and_the_limit_flags(tmp_path):
    quiet, hit = tmp_path / 'quiet', tmp_path / 'hit'
    # Real-time stamps (an epoch): t = 0 is the first sample.
    bag_synth.write_run(quiet, truth=False, hw_limits=False, t_origin=1.7e9, clock=False)
    bag_synth.write_run(hit, truth=False, hw_limits=True, t_origin=1.7e9, clock=False)
    a = analyze_bag(quiet)
    assert a.source == '/cartpole/state'
    assert a.summary['catch_time_s'] == pytest.approx(bag_synth.CATCH_TIME, abs=1e-6)
    assert a.summary['end_stop_contact'] is False and a.summary['success'] is True
    assert analyze_bag(hit).summary['end_stop_contact'] is True


def test_limit_switch_contact_is_a_switch_closing_after_it_opened():
    from cartpole_analysis.analysis.analyze import SeriesBuilder
    b = SeriesBuilder()
    for flags in [('true', 'false')] * 3:  # resting on the left switch at the start
        b.hw_health(0, dict(zip(('limit_left', 'limit_right'), flags)))
    assert not b.limit_flag
    b.hw_health(0, {'limit_left': 'false', 'limit_right': 'false'})
    assert not b.limit_flag
    b.hw_health(0, {'limit_left': 'true', 'limit_right': 'false'})
    assert b.limit_flag


def test_a_bag_without_states_is_refused(tmp_path):
    from cartpole_analysis.bags.writer import BagWriter
    path = tmp_path / 'empty'
    BagWriter(path).close()
    with pytest.raises(ValueError, match='nothing to analyse'):
        analyze_bag(path)


@pytest.mark.parametrize('little_endian', [True, False])
def test_joint_state_parser_matches_the_generic_deserialiser(little_endian):
    from rosbags.typesys import Stores, get_typestore
    from cartpole_analysis.analysis.analyze import parse_joint_state
    ts = get_typestore(Stores.ROS2_JAZZY)
    js, header, time = (ts.types[n] for n in ('sensor_msgs/msg/JointState', 'std_msgs/msg/Header',
                                              'builtin_interfaces/msg/Time'))
    for names, pos, vel, eff in [(['cart', 'pendulum'], [0.1, 3.1], [0.2, -4.0], []),
                                 (['cart'], [], [], [-12.5]), ([], [], [], []),
                                 (['a', 'bcdefgh', 'ij'], [1.0, 2.0, 3.0], [], [4.0, 5.0, 6.0])]:
        msg = js(header=header(stamp=time(sec=12, nanosec=345), frame_id='odd'), name=names,
                 position=np.array(pos), velocity=np.array(vel), effort=np.array(eff))
        raw = ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState', little_endian=little_endian)
        stamp, n, p, v, e = parse_joint_state(raw)
        assert stamp == 12_000_000_345 and n == names
        np.testing.assert_array_equal(p, pos)
        np.testing.assert_array_equal(v, vel)
        np.testing.assert_array_equal(e, eff)


def test_heteroclinic_orbit_is_the_energy_level_of_upright():
    # (6.10): zero upright, 2 sqrt(g / l) hanging; E_p = E* all along.
    g, l = 9.81, 0.3345
    assert heteroclinic_orbit(0.0, l, g) == 0.0
    assert heteroclinic_orbit(math.pi, l, g) == pytest.approx(2 * math.sqrt(g / l))
    from cartpole_core.model import CartPoleParameters, pendulum_energy
    p = CartPoleParameters()
    for theta in (0.3, 1.0, 2.5, -2.0):
        e = pendulum_energy(theta, float(heteroclinic_orbit(theta, p.l, p.g)), p)
        assert e == pytest.approx(p.upright_energy, rel=1e-12)


def test_cli_json_and_plots(known_bag, tmp_path, capsys):
    other = tmp_path / 'other' / 'bag'
    bag_synth.write_run(other, x_offset=0.2)
    plots = tmp_path / 'plots'
    assert cli.main(['analyze', str(known_bag), str(other), '--json', '--plots', str(plots)]) == 0
    out = json.loads(capsys.readouterr().out)
    first, second = out['runs']
    assert first['success'] is True and first['catch_time_s'] == pytest.approx(5.0)
    assert first['bag'] == str(known_bag) and first['stabilizer'] == 'lqg'
    assert second['success'] is False and second['x_err_max_m'] == pytest.approx(0.25)
    names = sorted(Path(p).name for p in out['plots'])
    assert names == ['comparison.png', 'known_phase.png', 'known_timeseries.png',
                     'other_phase.png', 'other_timeseries.png']
    for p in out['plots']:
        data = Path(p).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000
    # Text: one table per bag, then the side-by-side comparison.
    assert cli.main(['analyze', str(known_bag), str(other)]) == 0
    text = capsys.readouterr().out
    assert text.count('catch_time_s') == 3
    table = text.split('== comparison')[1].splitlines()
    assert table[1].split() == ['known', 'other']
    row = next(line for line in table if line.startswith('success '))
    assert row.split()[1:] == ['True', 'False']


def test_cli_single_bag_json_is_the_flat_summary(known_bag, capsys):
    assert cli.main(['analyze', str(known_bag), '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['success'] is True and out['plots'] == []
    assert out['source'] == '/cartpole/true_state'


def test_cli_reports_a_missing_bag(tmp_path, capsys):
    assert cli.main(['analyze', str(tmp_path / 'nope')]) == 2
    assert 'not a rosbag2 bag' in capsys.readouterr().err


def test_summary_lists_every_controller_that_ran_and_the_plot_marks_the_switch(tmp_path, capsys):
    """`ros2 param set /controller_manager stabilizer smc` at 12 s: lqg, then smc."""
    path = tmp_path / 'switched' / 'bag'
    bag_synth.write_run(path, switch=(12.0, 'smc'), custom_data={'lockstep': 'true'})
    s = analyze_bag(path).summary
    assert s['controllers'] == [
        {'kind': 'swingup', 'name': 'pendulum_energy', 'start_s': 0.0,
         'end_s': pytest.approx(bag_synth.CATCH_TIME)},
        {'kind': 'stabilizer', 'name': 'lqg', 'start_s': pytest.approx(bag_synth.CATCH_TIME),
         'end_s': pytest.approx(12.0)},
        {'kind': 'stabilizer', 'name': 'smc', 'start_s': pytest.approx(12.0),
         'end_s': pytest.approx(20.0)}]
    assert s['fault'] is None and s['longest_cycle_gap_s'] is None and s['success'] is True
    assert cli.main(['analyze', str(path), '--json', '--plots', str(tmp_path / 'fig')]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['stabilizer'] == 'lqg -> smc' and out['swingup'] == 'pendulum_energy'


def test_the_plot_marks_each_controller_start_and_names_it():
    from matplotlib.figure import Figure

    from cartpole_analysis.analysis.plots import _mark_controllers, run_title
    spans = [{'kind': 'swingup', 'name': 'pendulum_energy', 'start_s': 0.0, 'end_s': 5.0},
             {'kind': 'stabilizer', 'name': 'lqg', 'start_s': 5.0, 'end_s': 12.0},
             {'kind': 'stabilizer', 'name': 'smc', 'start_s': 12.0, 'end_s': 20.0}]
    axes = Figure().subplots(2, 1)
    _mark_controllers(axes, spans)
    assert [t.get_text() for t in axes[0].texts] == ['pendulum_energy', 'lqg', 'smc']
    assert sorted(line.get_xdata()[0] for line in axes[1].lines) == [0.0, 5.0, 12.0]
    assert run_title(spans) == 'pendulum_energy + lqg -> smc'


def test_fault_and_longest_cycle_gap_come_from_the_controller_status(tmp_path):
    path = tmp_path / 'faulted'
    bag_synth.write_run(path, events={8.0: 'fault:stale state', 9.0: 'fault:rail guard'},
                        cycle_gap=lambda t: 0.005 + 0.001 * min(t, 14.0))
    s = analyze_bag(path).summary
    assert s['fault'] == 'stale state'  # the first one
    assert s['longest_cycle_gap_s'] == pytest.approx(0.019)
    assert s['success'] is False  # balanced, but a run with a fault is no success


def test_a_fall_after_the_catch_fails_the_run_by_the_strict_rule(tmp_path, known_bag):
    """The manager's `fall` events after the first catch are counted (one before it is not)."""
    assert analyze_bag(known_bag).summary['falls_after_catch'] == 0
    path = tmp_path / 'fell'
    bag_synth.write_run(path, events={0.5: 'fall', 9.0: 'fall', 9.6: 'catch'})
    s = analyze_bag(path).summary
    assert s['falls_after_catch'] == 1
    assert s['success'] is False  # balanced at the end, but it fell once on the way


def test_the_summary_ends_where_the_run_ended_and_keeps_its_fault(tmp_path):
    """cartpole run writes run_end_ns and fault into the bag: analyze reports the same."""
    from cartpole_analysis.bags.writer import bag_custom_data, update_custom_data

    path = tmp_path / 'cut'
    bag_synth.write_run(path, custom_data={'lockstep': 'true', 'x_ref': repr(bag_synth.X_REF)})
    update_custom_data(path, {'run_end_ns': str(16_000_000_000),
                              'fault': 'controller_manager died (SIGKILL)'})
    assert bag_custom_data(path)['x_ref'] == repr(bag_synth.X_REF)  # the rest is kept
    a = analyze_bag(path)
    assert a.series.t[-1] == pytest.approx(16.0)
    assert a.summary['controllers'][-1]['end_s'] == pytest.approx(16.0)
    assert a.summary['fault'] == 'controller_manager died (SIGKILL)'
    assert a.summary['success'] is False
    # The window is [6, 16] s: theta = 0.01 sin(2 pi t) there, its peak 0.01 rad.
    assert a.summary['theta_amp_deg'] == pytest.approx(math.degrees(0.01), rel=1e-6)


@pytest.mark.parametrize('little_endian', [True, False])
def test_diagnostic_parser_matches_the_generic_deserialiser(little_endian):
    from rosbags.typesys import Stores, get_typestore

    from cartpole_analysis.bags.cdr_parse import parse_diagnostic_array
    ts = get_typestore(Stores.ROS2_JAZZY)
    raw = bag_synth.diagnostic(ts, 1.25, 'controller_manager',
                               {'mode': 'swingup', 'event': 'fault:stale state', 'é': 'ü'}, 'x')
    if not little_endian:
        msg = ts.deserialize_cdr(raw, 'diagnostic_msgs/msg/DiagnosticArray')
        raw = ts.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray', little_endian=False)
    stamp, statuses = parse_diagnostic_array(raw)
    assert stamp == 1_250_000_000
    assert statuses == [('controller_manager', {'mode': 'swingup', 'event': 'fault:stale state',
                                                'é': 'ü'})]


def test_offline_spans_follow_modes_and_switch_events():
    from cartpole_analysis.analysis.timeline import spans_from_modes
    t = [0.0, 0.005, 0.01, 0.015, 0.02, 0.025]
    modes = ['swingup', 'swingup', 'stabilizing', 'stabilizing', 'fault', 'fault']
    events = [(0.0, 'switch:stabilizer=smc'), (0.01, 'catch'), (0.02, 'fault:rail guard')]
    assert spans_from_modes(t, modes, events, 'pendulum_energy', 'lqg') == [
        {'kind': 'swingup', 'name': 'pendulum_energy', 'start_s': 0.0, 'end_s': 0.01},
        {'kind': 'stabilizer', 'name': 'smc', 'start_s': 0.01, 'end_s': 0.02}]


def test_force_keys_are_null_without_commands_and_a_length_mismatch_is_refused():
    from cartpole_analysis.analysis import metrics
    t = np.arange(0.0, 20.0, 0.01)
    common = dict(x_ref=0.0, catch_time=1.0, end_stop_contact=False)
    s = metrics.summarize(t, 0.0 * t, 0.0 * t, **common)
    assert s['force_rms_n'] is None and s['force_p2p_n'] is None
    s = metrics.summarize(t, 0.0 * t, 0.0 * t, force=np.full(5, 3.0), t_force=np.arange(5.0),
                          **common)                      # no command in the last 10 s
    assert s['force_rms_n'] is None
    s = metrics.summarize(t, 0.0 * t, 0.0 * t, force=np.where(t < 15.0, -3.0, 1.0), **common)
    assert s['force_rms_n'] == pytest.approx(np.sqrt(0.5 * 9 + 0.5 * 1), rel=1e-2)
    assert s['force_p2p_n'] == 4.0
    with pytest.raises(ValueError, match='length'):
        metrics.summarize(t, 0.0 * t, 0.0 * t, force=np.zeros(3), **common)
