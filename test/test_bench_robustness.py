"""`cartpole bench robustness`: the scoring against hand-computed scores, the grid's scenarios,
and the same results serially, on a process pool and on Dask."""
import dataclasses
import json
import math
import subprocess
import sys

import pytest

from cartpole_tools.bench import robustness as br
from cartpole_tools.bench import robustness_report as rr
from cartpole_sim.plant import Push, Scenario


def sweep(category, name, levels, unit='ms', after_catch=False):
    return br.Sweep(category, name, unit, tuple(levels), lambda v: {'delay': v * 1e-3},
                    after_catch=after_catch)


SYNTHETIC = [sweep('A', 'a -', [0, 1, 2], 'kg'), sweep('A', 'a +', [0, 5, 10], 'kg'),
             sweep('B', 'b', [0, 2.5, 5, 7.5])]


def synthetic_grid(pair, seeds, outcome):
    """Cells of every sweep, level and seed of SYNTHETIC, with outcome(sweep, level, seed)."""
    cells, ok = [], []
    for s in SYNTHETIC:
        for i in range(len(s.levels)):
            for seed in range(seeds):
                cells.append(br.Cell(*pair, s.name, i, seed))
                ok.append(outcome(s.name, i, seed))
    return cells, ok


def test_scores_of_a_synthetic_grid_are_the_hand_computed_ones():
    # Pair P, 3 seeds. Successes per level (of 3):
    #   a -: 3, 2, 1 -> counts T T F  (survived up to level 1: 1 kg)
    #   a +: 3, 0, 3 -> counts T F T  (survived: nominal only; level 2 counts all the same)
    #   b  : 2, 3, 1, 0 -> counts T T F F (survived up to 2.5 ms)
    # A = 4 counting of 6 cells = 0.667; B = 2 / 4 = 0.5; overall = (0.667 + 0.5) / 2 = 0.583.
    wins = {'a -': [3, 2, 1], 'a +': [3, 0, 3], 'b': [2, 3, 1, 0]}
    cells, ok = synthetic_grid(('su', 'P'), 3, lambda name, i, seed: seed < wins[name][i])
    # Pair Q, 4 seeds: exactly half is not more than half.
    wins_q = {'a -': [4, 2, 3], 'a +': [3, 3, 3], 'b': [4, 4, 4, 4]}
    more, ok_q = synthetic_grid(('su', 'Q'), 4, lambda name, i, seed: seed < wins_q[name][i])
    scores = br.score(cells + more, ok + ok_q, SYNTHETIC)
    p, q = scores[('su', 'P')], scores[('su', 'Q')]
    assert p['sweeps']['a -']['rates'] == pytest.approx([1.0, 2 / 3, 1 / 3])
    assert [p['sweeps'][n]['counts'] for n in ('a -', 'a +', 'b')] == [
        [True, True, False], [True, False, True], [True, True, False, False]]
    assert [p['sweeps'][n]['survived'] for n in ('a -', 'a +', 'b')] == [1, 0, 1]
    assert p['categories']['A']['score'] == pytest.approx(4 / 6)
    assert p['categories']['B']['score'] == pytest.approx(0.5)
    assert p['overall'] == pytest.approx((4 / 6 + 0.5) / 2)
    # Q: a - = T F T (2/4 does not count), a + all, b all: A = 5/6, B = 1, overall 11/12.
    assert q['sweeps']['a -']['counts'] == [True, False, True]
    assert q['overall'] == pytest.approx((5 / 6 + 1.0) / 2)
    # The report reads the survived levels in physical units, both directions joined.
    assert rr.survived_ranges(p, SYNTHETIC, 'A') == ['a 1 to 0 kg']
    assert rr.survived_ranges(p, SYNTHETIC, 'B') == ['b 2.5 ms']
    report = rr.markdown_report(scores, SYNTHETIC, 3)
    assert '| su + P | 0.67 | 0.50 | **0.58** |' in report
    assert '| A | 0.67 | 4 / 6 | a 1 to 0 kg |' in report


def test_a_nominal_level_that_does_not_count_survives_nothing():
    cells, ok = synthetic_grid(('su', 'P'), 3, lambda name, i, seed: name != 'b' or i > 0)
    sc = br.score(cells, ok, SYNTHETIC)[('su', 'P')]
    assert sc['sweeps']['b']['survived'] is None
    assert rr.survived_ranges(sc, SYNTHETIC, 'B') == ['b: fails at nominal']
    assert sc['categories']['B']['score'] == pytest.approx(0.75)


def test_a_run_that_falls_after_the_catch_does_not_succeed_in_any_sweep():
    push, other = sweep('push', 'p', [0, 1], after_catch=True), sweep('x', 'x', [0, 1])
    summary = {'success': True, 'falls_after_catch': 1, 'faults': []}
    assert not br.succeeded(push, summary) and not br.succeeded(other, summary)
    assert br.succeeded(push, {'success': True, 'falls_after_catch': 0, 'faults': []})
    assert not br.succeeded(other, {'success': True, 'falls_after_catch': 0,
                                    'faults': ['fault:rail guard']})


def test_majority_decides_levels_with_the_fewest_seeds():
    # 3 seeds: the first two decide a level when they agree; the third runs otherwise.
    sweeps = [sweep('B', 'b', [0, 2.5, 5])]
    cells, runs = br.make_grid([('pendulum_energy', 'lqg')], sweeps, seeds=3)
    fake = {}

    def fake_grid(batch, **_):
        out = []
        for r in batch:
            delay_ms = round(r.scenario.delay * 1e3, 6)
            seed = r.scenario.seed
            ok = delay_ms == 0 or (delay_ms == 2.5 and seed != 0)  # level 1: 2 of 3
            fake.setdefault(r, 0)
            fake[r] += 1
            out.append({'success': ok, 'falls_after_catch': 0, 'faults': []})
        return out

    import unittest.mock
    with unittest.mock.patch.object(br, 'run_grid', fake_grid):
        ran, results = br.run_by_majority(cells, runs, sweeps, seeds=3)
    assert [(c.level_index, c.seed) for c in ran] == [(0, 0), (0, 1), (1, 0), (1, 1), (1, 2),
                                                      (2, 0), (2, 1)]
    assert max(fake.values()) == 1  # no run twice
    sc = br.score(ran, [r['success'] for r in results], sweeps)[('pendulum_energy', 'lqg')]
    assert sc['sweeps']['b']['counts'] == [True, True, False]


def test_the_default_grid_sweeps_every_category_from_nominal_over_ten_levels():
    assert br.CATEGORIES == ('model', 'measurement noise', 'force noise', 'actuator gain',
                             'actuator lag', 'delay', 'lost samples', 'encoder offset', 'push')
    nominal = Scenario(noise=True, seed=2)
    for category in br.CATEGORIES:
        sweeps = br.sweeps_of([category])
        assert sum(len(s.levels) for s in sweeps) >= 10, category
        for s in sweeps:
            assert br.scenario_of(s, s.levels[0], 2) == nominal, s.name  # level 0 is nominal
            assert len(set(br.scenario_of(s, v, 2) for v in s.levels)) == len(s.levels)
    model = {s.name for s in br.sweeps_of(['model'])}
    assert {'cart mass -', 'cart mass +', 'tip mass -', 'pendulum length +', 'cart friction +',
            'pendulum Coulomb friction +', 'pendulum viscous friction +'} <= model
    with pytest.raises(ValueError, match='known'):
        br.sweeps_of(['gravity'])


def test_levels_become_the_scenarios_they_name():
    by = {s.name: s for s in br.SWEEPS}
    assert br.scenario_of(by['delay'], 10.0, 0).delay == pytest.approx(0.010)
    assert br.scenario_of(by['delay'], 10.0, 0).jitter == pytest.approx(0.002)
    assert br.scenario_of(by['lost samples'], 10.0, 0).drop == pytest.approx(0.1)
    assert br.scenario_of(by['cart mass -'], 3.8, 0).cart_mass == 3.8
    assert br.scenario_of(by['cart push'], 1.0, 0).pushes == (Push(12.0, 'cart', 10.0, 0.1),)
    offset = br.scenario_of(by['encoder offset -'], -20.0, 0)
    assert (offset.encoder_offset, offset.theta0) == pytest.approx((-0.02, math.pi - 0.02))
    length = br.scenario_of(by['pendulum length +'], 401.4, 0).plant_parameters(br.NOMINAL)
    assert length.l == pytest.approx(0.4014)
    noisy = br.scenario_of(by['measurement noise'], 4.5, 0)
    assert (noisy.noise_std_pendulum, noisy.noise_std_cart) == pytest.approx((4.5e-3, 3e-4))


@pytest.mark.slow
def test_a_short_grid_gives_the_same_results_serially_on_a_pool_and_on_dask(three_ways):
    sweeps = [dataclasses.replace(s, levels=s.levels[:2])
              for s in br.sweeps_of(['lost samples', 'force noise'])]
    cells, runs = br.make_grid([('sign_based', 'smc')], sweeps, seeds=2, duration=6.0)
    assert len(cells) == 8 and len(set(runs)) == 6  # the nominal level is run once per seed
    serial, pool, dask = three_ways(br.run_grid, runs)
    assert serial == pool == dask
    assert serial[0] == serial[4]  # the same nominal run, shared by both sweeps
    assert serial[0]['mse_x'] != serial[1]['mse_x']  # seeds differ, so equality means something
    assert 'lost_samples' in serial[6] and 'lost_samples' not in serial[2]


@pytest.mark.slow
def test_bench_robustness_writes_tables_heat_map_and_json(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'bench', 'robustness',
                          '--pairs', 'sign_based:smc', '--categories', 'delay', 'push',
                          '--max-levels', '2', '--seeds', '1', '--duration', '6',
                          '--workers', '2', '--out', str(tmp_path)],
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    report = (tmp_path / 'robustness.md').read_text()
    assert '| pair | delay | push | overall |' in report
    assert '### sign_based + smc: overall' in report
    raw = json.loads((tmp_path / 'robustness.json').read_text())
    assert len(raw['runs']) == 6 and raw['distinct_runs'] == 4  # nominal once
    assert {r['sweep'] for r in raw['runs']} == {'delay', 'cart push', 'pendulum push'}
    assert set(raw['scores']) == {'sign_based + smc'}
    assert (tmp_path / 'robustness_heatmap.png').read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    bad = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'bench', 'robustness',
                          '--pairs', 'sign_based:lqr'], capture_output=True, text=True,
                         timeout=300)
    assert bad.returncode != 0 and 'lqr' in bad.stderr and 'Traceback' not in bad.stderr
