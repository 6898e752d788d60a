"""The benchmarks run end to end at a tiny size and write their reports (no timing asserted),
and the controller sweep gives the same numbers serially, on a process pool and on Dask."""
import json
import math
import subprocess
import sys

import pytest

from cartpole_tools.bench import control as bc
def cartpole(*argv, timeout=600):
    out = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', *argv],
                         capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr[-3000:]
    return out


@pytest.mark.slow
def test_sweep_is_identical_serially_on_a_pool_and_on_dask(three_ways):
    cases = bc.make_cases(['sign_based'], ['smc'], ['nominal', 'mass-10%'], seeds=2, duration=6.0)
    serial, pool, dask = three_ways(bc.run_sweep, cases)
    assert serial == pool == dask
    # Different seeds really are different runs (noise is on), so equality means something.
    assert serial[0]['mse_x'] != serial[1]['mse_x']
    assert [r['scenario'] for r in serial] == [c.scenario for c in cases]


def test_the_grid_has_the_appendix_h_offsets_friction_x1_5_and_the_lighter_tip_with_offset():
    for b in (0.01, 0.02, 0.05, 0.1):
        for sign, name in ((1, f'offset +{b:g}'), (-1, f'offset -{b:g}')):
            assert bc.SCENARIOS[name]['encoder_offset'] == sign * b
            assert bc.SCENARIOS[name]['theta0'] - math.pi == pytest.approx(sign * b)
    assert bc.SCENARIOS['friction x1.5'] == {'friction_scale': 1.5}
    both = bc.SCENARIOS['offset +0.05 mass-20%']
    assert both['encoder_offset'] == 0.05 and both['tip_mass'] == pytest.approx(0.8 * 0.251)


def test_unknown_scenario_is_refused_with_the_list():
    with pytest.raises(ValueError, match='nominal'):
        bc.make_cases(['sign_based'], ['smc'], ['mass-50%'], seeds=1)


@pytest.mark.slow
def test_bench_control_writes_table_json_and_figures(tmp_path):
    out = cartpole('bench', 'control', '--seeds', '1', '--duration', '12', '--swingups', 'sign_based',
                   '--stabilizers', 'smc', 'pid', '--scenarios', 'nominal', 'offset +0.02',
                   '--workers', '2', '--no-bound', '--out', str(tmp_path))
    report = (tmp_path / 'control.md').read_text()
    assert '| swing-up | stabiliser | runs | success |' in report
    assert 'sign_based | smc | offset +0.02 | 1 |' in report
    assert 'force rms / p2p (nominal) [N]' in report and '### Encoder offsets' in report
    results = json.loads((tmp_path / 'control.json').read_text())
    assert len(results) == 4
    assert {r['stabilizer'] for r in results} == {'smc', 'pid'}
    for r in results:
        assert r['force_rms_n'] > 0.0 and r['force_p2p_n'] > 0.0 and r['x_err_mean_m'] >= 0.0
    for png in ('success_heatmap.png', 'catch_times.png'):
        assert (tmp_path / png).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert 'control.md' in out.stdout or 'written to' in out.stdout


def test_bench_offline_reports_speed_and_stage_costs(tmp_path):
    cartpole('bench', 'offline', '--duration', '3', '--repeat', '1', '--out', str(tmp_path))
    report = (tmp_path / 'offline.md').read_text()
    assert 'simulated seconds per wall second' in report
    result = json.loads((tmp_path / 'offline.json').read_text())
    assert result['speed_x_real_time'] > 0
    assert set(result['per_step_us']) == {'plant', 'ekf', 'controller'}


@pytest.mark.ros
@pytest.mark.slow
def test_bench_loop_measures_graph_and_floor(tmp_path):
    cartpole('bench', 'loop', '--duration', '1', '--warmup', '0.25', '--modes', 'single',
             '--executors', 'events', '--view', '1', '--out', str(tmp_path))
    report = (tmp_path / 'loop.md').read_text()
    assert '1 s measured per row after 0.25 s warm-up' in report
    assert 'our graph' in report and 'bare rclpy floor' in report and 'ratio graph / floor' in report
    result = json.loads((tmp_path / 'loop.json').read_text())
    assert set(result['single']) == {'events'}  # --executors: the graph against a floor on it
    run = result['single']['events']
    assert run['graph']['commands'] > 0 and run['bare']['commands'] > 0
    assert set(run['graph']['cpu_percent']) == {'cartpole run'}
    # --view: on the first executor, a pair without and with the viewer, whose client
    # really got the scene.
    assert "The viewer's cost" in report and '| single | events | median ratio |' in report
    pair, = result['single']['events']['view_rounds']
    assert pair['graph']['commands'] > 0 and pair['graph_view']['commands'] > 0
    assert pair['graph_view']['viewer_messages']['/cartpole/view/scene'] > 0
    assert set(pair['graph_view']['cpu_percent']) == {'cartpole run', 'viewer'}
