"""`cartpole plan`: the bound and the plan's duration for a start, from the plan cache."""
import json
import os
import re
import subprocess
import sys

import pytest

from cartpole_control.trajectory_optimization import ISSUE_BOUNDS


def cartpole_plan(cache, *argv):
    return subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'plan', *argv],
                          capture_output=True, text=True, timeout=900,
                          env=dict(os.environ, CARTPOLE_CACHE_DIR=str(cache)))


@pytest.fixture
def cache(cold_plan_run):
    directory, run = cold_plan_run
    assert run.returncode == 0, run.stderr[-3000:]
    return directory


@pytest.mark.slow
def test_plan_prints_the_bound_and_the_cached_plan_of_the_default_start(cache):
    out = cartpole_plan(cache)
    assert out.returncode == 0, out.stderr[-3000:]
    bound = float(re.search(r'minimum-time bound \(full force, whole rail\): ([\d.]+) s',
                            out.stdout).group(1))
    assert bound == pytest.approx(ISSUE_BOUNDS['left_stop'], rel=0.03)  # the default start
    duration = float(re.search(r'plan duration: ([\d.]+) s', out.stdout).group(1))
    assert bound < duration <= 1.5 * bound
    assert 'from the cache' in out.stdout  # solved by the cold offline run, not again
    # JSON; the bound is cached too now.
    out = cartpole_plan(cache, '--json')
    data = json.loads(out.stdout)
    assert data['solved'] is False and data['plan_success'] is True and 'solving' not in out.stderr
    assert data['plan_duration_s'] == pytest.approx(duration, abs=1e-3)
    assert data['bound_s'] == pytest.approx(bound, abs=1e-3) and data['x0_m'] == 0.0
    assert os.path.isfile(data['file'])


def test_plan_refuses_a_start_off_the_rail_and_bad_gains(tmp_path):
    out = cartpole_plan(tmp_path, '--x0', '0.9', '--no-bound')
    assert out.returncode != 0 and 'outside the travel' in out.stderr
    params = tmp_path / 'p.yaml'
    params.write_text('controller_manager:\n  ros__parameters:\n    time_optimal:\n'
                      '      force_scale: 2.0\n')
    out = cartpole_plan(tmp_path, '--params', str(params), '--no-bound')
    assert out.returncode != 0 and 'force_scale' in out.stderr and 'Traceback' not in out.stderr
    assert not any(tmp_path.glob('*.npz'))  # nothing solved
