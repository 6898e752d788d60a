"""`cartpole soak`: its judgments on made-up inputs, and a 2-minute soak of the real graph."""
import json
import math
import subprocess
import sys

import numpy as np
import pytest

from cartpole_tools.soak.judge import FALL_RAD, UprightJudge, bag_verdict, memory_growth

S = 1_000_000_000


def _balanced_run(judge, start_ns, catch_after_ns, end_ns, theta_up=0.01):
    """Samples every 5 ms from hanging, a catch after ``catch_after_ns``, upright after."""
    for stamp in range(start_ns, end_ns, 5_000_000):
        caught = stamp >= start_ns + catch_after_ns
        judge.status(1 if caught else 0, 0, stamp)
        judge.sample(stamp, theta_up if caught else math.pi)


def test_a_caught_and_held_pendulum_is_up_and_a_fall_is_not():
    judge = UprightJudge(catch_timeout=30.0)
    judge.restart(0.0, from_stamp_ns=0)
    _balanced_run(judge, 0, 5 * S, 60 * S)
    judge.restart(60.0)
    judge.plant_reset(60 * S)
    _balanced_run(judge, 60 * S, 4 * S, 100 * S)
    judge.sample(100 * S, FALL_RAD + 0.1)  # fell after its catch
    result = judge.verdict(100.0)
    assert [s['ok'] for s in result['segments']] == [True, False]
    assert result['segments'][0]['catch_after_s'] == pytest.approx(5.0)
    assert result['segments'][1]['samples_fallen'] == 1
    assert result['up_ok'] is False


def test_statuses_before_the_reset_do_not_count_for_the_new_swing_up():
    judge = UprightJudge()
    judge.restart(0.0, from_stamp_ns=0)
    _balanced_run(judge, 0, 5 * S, 60 * S)
    judge.restart(60.0)
    judge.status(1, 0, 59 * S)   # the old run's status, late: no catch of the new one
    judge.plant_reset(60 * S)
    judge.status(1, 0, 59 * S + 1)
    assert judge.segments[1].catch_stamp_ns is None
    judge.plant_reset(10 * S)    # an older reset kept for late joiners changes nothing
    assert judge.segments[1].from_stamp_ns == 60 * S


def test_a_swing_up_not_caught_in_time_fails_unless_the_end_cut_it():
    judge = UprightJudge(catch_timeout=30.0)
    judge.restart(0.0, from_stamp_ns=0)
    for stamp in range(0, 20 * S, 5_000_000):
        judge.sample(stamp, math.pi)
    assert judge.verdict(20.0)['up_ok'] is True          # 20 s < 30 s: cut by the end
    assert judge.verdict(20.0)['segments'][0]['cut_by_end'] is True
    assert judge.verdict(31.0)['up_ok'] is False


def test_the_stop_after_the_end_is_not_judged():
    judge = UprightJudge()
    judge.restart(0.0, from_stamp_ns=0)
    _balanced_run(judge, 0, 5 * S, 30 * S)
    judge.ended = True
    judge.sample(31 * S, math.pi)  # zero force at the stop: the pendulum falls
    assert judge.verdict(30.0)['up_ok'] is True


def test_a_manager_reported_fall_fails_its_segment():
    judge = UprightJudge()
    judge.restart(0.0, from_stamp_ns=0)
    _balanced_run(judge, 0, 5 * S, 30 * S)
    judge.status(1, 1, 30 * S)
    assert judge.verdict(30.0)['segments'][0]['falls'] == 1
    assert judge.verdict(30.0)['up_ok'] is False


def test_memory_growth_is_the_slope_after_settling_in_mb_per_hour():
    t = np.arange(0.0, 3600.0, 5.0)
    rss = 80e6 + np.where(t < 300.0, t * 1e4, 3e6 + (t - 300.0) * (2e6 / 3600.0))
    assert memory_growth(t, rss, 300.0) == pytest.approx(2.0, rel=1e-6)
    assert memory_growth(t, rss, 0.0) > 2.0   # the start-up step counted
    assert memory_growth(t[:2], rss[:2], 0.0) is None


def test_the_bag_is_complete_only_with_every_message_the_probe_saw():
    seen = {'/joint_states': {'count': 100, 'first_ns': 0, 'last_ns': 99},
            '/cartpole/state': {'count': 98, 'first_ns': 2, 'last_ns': 99}}
    ok = bag_verdict(seen, {'/joint_states': 100, '/cartpole/state': 98}, None, 0)
    assert ok['bag_ok'] is True
    short = bag_verdict(seen, {'/joint_states': 99, '/cartpole/state': 98}, None, 0)
    assert short['bag_ok'] is False and short['topics']['/joint_states']['missing'] == 1
    assert bag_verdict(seen, {'/joint_states': 100, '/cartpole/state': 98}, None, 3)[
        'bag_ok'] is False
    assert bag_verdict(seen, {'/joint_states': 100, '/cartpole/state': 98},
                       'is truncated', 0)['bag_ok'] is False


@pytest.mark.parametrize('argv, message', [
    (['--duration', 'nan'], '--duration must be a finite number'),
    (['--duration', '0'], '--duration must be > 0 s'),
    (['--duration', '1e9'], '--duration must be <= 28800 s'),
    (['--duration', '60', '--switch-every', '0.01'], '--switch-every must be >= 1 s'),
    (['--duration', '60', '--sample-every', '1e-6'], '--sample-every must be >= 0.5 s'),
    (['--duration', '60', '--stabilizers', 'nope'], '--stabilizers: unknown nope'),
])
def test_bad_options_are_refused_in_one_line(argv, message):
    run = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'soak', *argv],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stderr.startswith(f'cartpole soak: error: {message}'), run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


STALL_FAULT = ('stale', 'controller manager in fault for')
"""The faults a host stall makes: the manager's 50 ms stale-state check (docs/soak.md)."""


@pytest.mark.ros
@pytest.mark.slow
def test_two_minutes_of_soak_pass(tmp_path):
    """The suite's soak (`cartpole soak` runs the long ones): two minutes, switch every 10 s,
    restart at 60 s; the switches and the restart accepted, the bag whole, no process lost, up.

    ``make test`` runs it with the other graph tests, beside the worker that runs the rest
    at nice 10: since the UDP-only profiles and the held first sample, soaks of 10 and 60
    minutes beside benchmarks and the suite had no fault and lost nothing (docs/soak.md).
    A stall of the loop over 50 ms (a stolen vCPU on the shared VM) still makes the manager
    fault on a stale state and command zero force, its designed reaction: such a fault is
    accepted with the stall in the manager's longest cycle gap, and then the pendulum and the
    recorder's by-stamp count are not judged; any other fault fails."""
    out = tmp_path / 'soak'
    run = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'soak',
                          '--duration', '120', '--switch-every', '10', '--restart-every', '60',
                          '--settle', '10', '--out', str(out), '--json'],
                         capture_output=True, text=True, timeout=300)
    result = json.loads(run.stdout)
    assert result['ran_to_the_end'] is True, run.stderr[-3000:]
    assert result['switches'] == 11 and result['restarts'] == 1, result['events']
    # Nothing the probe received is missing from the bag, and the bag is whole.
    assert result['damage'] is None and all(t['missing'] == 0 for t in result['topics'].values()), \
        (result['damage'], result['topics'], run.stderr[-2000:])
    assert all(t['recorded'] > 3_000 for t in result['topics'].values())
    assert set(result['topics']) == {'/joint_states', '/cartpole/true_state', '/cartpole/state',
                                     '/cartpole/force_command', '/cartpole/force_acting',
                                     '/cartpole/controller_status'}
    assert set(result['processes']) == {'sim', 'ekf', 'controller_manager', 'recorder',
                                        'cartpole soak'}
    assert result['memory_ok'] is None  # 110 s after settling: too short to judge
    assert (out / 'soak.md').read_text().startswith('Soak of 12')
    if result['faults']:
        # A stall: the manager's zero force and status at its stale fault carry its clock,
        # a stamp no estimate has, which the recorder's ledger counts as missed (docs/soak.md).
        assert all(any(k in f for k in STALL_FAULT) for f in result['faults']), result['faults']
        assert result['longest_cycle_gap_s'] > 0.05, (result['faults'], run.stderr[-3000:])
        return
    assert result['bag_ok'] is True and result['recorder_missed'] == 0, run.stderr[-2000:]
    assert result['up_ok'] is True, result['segments']
    assert len(result['segments']) == 2 and all(s['catch_after_s'] for s in result['segments'])
    assert run.returncode == 0 and result['ok'] is True
