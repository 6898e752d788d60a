"""`cartpole bench robustness --combined N`: the strict rule, the failure kinds, the Wilson
interval, the draws, the bounds of the options, and a failure file that replays exactly."""
import json
import subprocess
import sys

import pytest

from cartpole_sim.scenario_ranges import RangeTable
from cartpole_tools.bench import combined as cb
from cartpole_tools.bench import combined_report as cr
from cartpole_tools.bench import robustness as br

CLI = [sys.executable, '-m', 'cartpole_bringup.cli']
GOOD = {'success': True, 'faults': [], 'falls_after_catch': 0, 'impacts': 0,
        'end_stop_contact': False, 'fault': None, 'catch_time_s': 2.9}


def test_wilson_interval_matches_hand_computed_values():
    # 68 of 200: p = 0.34, centre (0.34 + 1.96^2/400) / (1 + 1.96^2/200) = 0.3430, half
    # width 1.96 / 1.0192 sqrt(0.34 x 0.66 / 200 + 1.96^2 / 160000) = 0.0651.
    low, high = cb.wilson_interval(68, 200)
    assert (low, high) == pytest.approx((0.2779, 0.4081), abs=5e-4)
    # No failures in 200 still leaves 1.9 % unexcluded; none in 0 runs says nothing.
    assert cb.wilson_interval(200, 200) == pytest.approx((0.9812, 1.0), abs=5e-4)
    assert cb.wilson_interval(0, 10) == pytest.approx((0.0, 0.2775), abs=5e-4)
    assert cb.wilson_interval(0, 0) == (0.0, 1.0)


@pytest.mark.parametrize('change, kind', [
    ({}, None),
    ({'success': False, 'impacts': 1, 'end_stop_contact': True}, 'impact'),
    ({'success': False, 'faults': ['fault:rail guard'], 'fault': 'rail guard'}, 'fault'),
    ({'success': False, 'falls_after_catch': 2}, 'fall'),
    ({'success': False, 'catch_time_s': None}, 'never caught'),
    ({'success': False}, 'off target'),
    # A summary that says success but carries a fall, a fault event or an impact is no
    # strict success, and one without the strict keys (a bag's) cannot pass for one.
    ({'falls_after_catch': 1}, 'fall'),
    ({'faults': ['fault:stale state']}, 'fault'),
    ({'impacts': 1}, 'impact'),
    ({'falls_after_catch': None}, 'off target'),
])
def test_every_run_is_a_strict_success_or_exactly_one_kind_of_failure(change, kind):
    summary = {**GOOD, **change}
    assert cb.failure_kind(summary) == kind
    assert br.strict_success(summary) is (kind is None)
    assert br.succeeded(br.SWEEPS[0], summary) is (kind is None)


def test_the_draws_are_seeded_per_run_and_a_longer_run_keeps_the_first_scenarios():
    table = RangeTable()
    ten = cb.scenarios(table, 10, seed=3)
    assert cb.scenarios(table, 4, seed=3) == ten[:4]
    assert cb.scenarios(table, 4, seed=4) != ten[:4]
    assert len(set(ten)) == 10
    runs = cb.make_runs([('a', 'b'), ('a', 'c')], ten[:3], 12.0)
    assert [(r.stabilizer, r.scenario) for r in runs] == [('b', s) for s in ten[:3]] + \
        [('c', s) for s in ten[:3]]


def test_tally_counts_successes_kinds_and_the_interval_per_pair():
    drawn = cb.scenarios(RangeTable(), 4)
    fall = {**GOOD, 'success': False, 'falls_after_catch': 1}
    results = [GOOD, GOOD, fall, GOOD] + [GOOD] * 4
    t = cb.tally([('s', 'x'), ('s', 'y')], drawn, results)
    assert t[('s', 'x')]['successes'] == 3 and t[('s', 'x')]['kinds'][2] == 'fall'
    assert t[('s', 'x')]['failures'] == {'impact': 0, 'fault': 0, 'fall': 1, 'never caught': 0,
                                        'off target': 0}
    assert t[('s', 'y')]['rate'] == 1.0
    assert t[('s', 'x')]['interval'] == pytest.approx(list(cb.wilson_interval(3, 4)))


def test_sign_test_matches_the_binomial_by_hand():
    # 4 against 1: P(X <= 1 | 5, 1/2) = 6/32, doubled; 6 against 0: 2/64; 5 against 0 is
    # not below 0.05 (2/32); a tie or no discordant draw says nothing.
    assert cb.sign_test(4, 1) == pytest.approx(0.375)
    assert cb.sign_test(0, 6) == pytest.approx(0.03125)
    assert cb.sign_test(5, 0) == pytest.approx(0.0625)
    assert cb.sign_test(3, 3) == 1.0 and cb.sign_test(0, 0) == 1.0


def test_paired_comparison_counts_the_draws_each_pair_alone_holds():
    drawn = cb.scenarios(RangeTable(), 8)
    fall = {**GOOD, 'success': False, 'falls_after_catch': 1}
    # x loses draws 0-5 and 7; y loses draw 7 only: 6 draws only y holds, none only x.
    results = [fall] * 6 + [GOOD, fall] + [GOOD] * 7 + [fall]
    pairs = [('s', 'x'), ('s', 'y')]
    rows = cb.paired_comparison(cb.tally(pairs, drawn, results))
    assert len(rows) == 1
    row = rows[0]
    assert (row['first_only'], row['second_only'], row['both'], row['neither']) == (0, 6, 1, 1)
    assert row['p'] == pytest.approx(0.03125) and row['better'] == ['s', 'y']
    # One draw fewer apart (5 against 0) is no longer shown.
    results[5] = GOOD
    row = cb.paired_comparison(cb.tally(pairs, drawn, results))[0]
    assert row['second_only'] == 5 and row['better'] is None
    text = cr.markdown_report(cb.tally(pairs, drawn, results), RangeTable(), [], 8, 0, 30.0,
                              'the published range table', [row])
    assert '| s + x | s + y | 0 | 5 | 2 | 1 | 0.0625 | not shown |' in text


def test_failure_rates_bin_each_factor_and_pushes_by_impulse_over_the_pushed_runs():
    centres, rates, counts = cr.failure_rates([0.0, 0.1, 0.2, 0.3, 0.4, 1.0],
                                              [True, False, False, True, True, True])
    # Bins of 0.2 from 0 to 1: {0, 0.1}, {0.2, 0.3}, {0.4}, none, {1.0}.
    assert counts == [2, 2, 1, 1] and rates == [0.5, 0.5, 1.0, 1.0]
    assert centres[0] == pytest.approx(0.1)
    # Pushes: the unpushed runs (0) are left out, either sign counts by its size.
    centres, rates, counts = cr.failure_rates([0.0, -2.0, 2.0, 0.0], [True, False, True, True],
                                              push=True)
    assert (centres, rates, counts) == ([2.0], [0.5], [2])


@pytest.mark.parametrize('args, words', [
    (['--combined', '0'], ['--combined', '>= 1']),
    (['--combined', '1001'], ['--combined', '<= 1000']),
    (['--combined', '5', '--duration', '121'], ['--duration', '<= 120']),
    (['--combined', '1000', '--duration', '60', '--pairs', 'pendulum_energy:lqg',
      'pendulum_energy:smc'], ['120000', 'at most 100000']),
    (['--combined', '5', '--seed', '-1'], ['--seed', '>= 0']),
    (['--ranges', 'x.yaml'], ['--ranges', 'with --combined']),
    (['--combined', '5', '--ranges', 'BAD'], ['--ranges', 'delays', 'unknown factor']),
])
def test_options_that_size_the_work_are_bounded_and_the_error_says_the_bound(tmp_path, args,
                                                                             words):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('delays: [0, 0.01]\n')
    args = [str(bad) if a == 'BAD' else a for a in args]
    out = subprocess.run(CLI + ['bench', 'robustness', *args, '--out', str(tmp_path / 'o')],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode != 0 and 'Traceback' not in out.stderr, out.stderr[-2000:]
    for word in words:
        assert word in out.stderr
    assert not (tmp_path / 'o').exists()  # refused before anything is written


def test_offline_scenario_takes_the_whole_scenario_or_says_why_not(tmp_path):
    path = tmp_path / 's.json'
    path.write_text(json.dumps({'delay': 0.01, 'noise': True}))
    both = subprocess.run(CLI + ['offline', '--scenario', str(path), '--delay', '0.02'],
                          capture_output=True, text=True, timeout=120)
    assert both.returncode != 0 and '--delay' in both.stderr and 'whole scenario' in both.stderr
    path.write_text(json.dumps({'delay': 0.5}))
    bad = subprocess.run(CLI + ['offline', '--scenario', str(path)], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode != 0 and str(path) in bad.stderr and 'delay' in bad.stderr
    assert 'Traceback' not in bad.stderr


@pytest.mark.slow
def test_combined_writes_the_report_and_every_failure_replays_to_the_same_summary(tmp_path):
    # 8 s runs cannot succeed (the last-10-s window needs 10 s): every run fails, so every
    # one writes a failure file; the drawn plants differ in every factor, pushes (at 5-7 s,
    # a range table of the user's) included.
    ranges = tmp_path / 'ranges.yaml'
    ranges.write_text('push_time: [5.0, 7.0]\npush_share: 1\n')
    out = subprocess.run(CLI + ['bench', 'robustness', '--combined', '3', '--seed', '5',
                                '--duration', '8', '--pairs', 'pendulum_energy:lqg',
                                '--ranges', str(ranges), '--workers', '2',
                                '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    report = (tmp_path / 'combined.md').read_text()
    assert '| pendulum_energy + lqg | 0 / 3 | **0.000** | 0.000-0.561 |' in report
    assert (tmp_path / 'combined_factors.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    raw = json.loads((tmp_path / 'combined.json').read_text())
    assert len(raw['runs']) == 3 and len(raw['failures']) == 3
    assert raw['paired'] == [] and 'Pair against pair' not in report  # one pair
    assert raw['ranges'] == RangeTable(push_time=(5.0, 7.0), push_share=1.0).to_dict()
    assert all(run['scenario']['pushes'] for run in raw['runs'])
    failure = raw['failures'][1]
    run = raw['runs'][failure['index']]
    assert failure['replay'].startswith('cartpole offline --scenario ')
    replay = subprocess.run(CLI + failure['replay'].split()[1:] + ['--json'],
                            capture_output=True, text=True, timeout=300)
    assert replay.returncode == 0, replay.stderr[-2000:]
    summary = json.loads(replay.stdout)
    assert summary == {k: v for k, v in run.items()
                       if k not in ('swingup', 'stabilizer', 'index', 'kind', 'scenario',
                                    'faults')}
    assert run['scenario'] == json.loads((tmp_path / 'failures' /
                                          'pendulum_energy-lqg-0001.json').read_text())
