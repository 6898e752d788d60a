"""`time_optimal` in the node graph: what runs when the plan is missing, and what the run says.

- lockstep, one process a node, cold plan cache: `cartpole run` solves the plan
  before the graph starts (the manager's own process then finds it), and the
  run tracks it from the first swing-up, as `cartpole offline` does;
- real time, cold cache: the loop does not wait; the fall-back is announced
  and named in the summary, the plan is solved by a background process that
  outlives nothing it needs, and the next real-time run tracks it.
"""
import json
import os
import subprocess
import sys
import time

import pytest

from cartpole_control.controllers.time_optimal import TimeOptimalSwingUp, plan_problem
from cartpole_control.plan_cache import TrajectoryCache
from cartpole_core.model import CartPoleParameters

pytestmark = [pytest.mark.ros, pytest.mark.slow]

P = CartPoleParameters()


def cartpole_run(cache, *argv, timeout=600):
    run = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                          '--swingup', 'time_optimal', '--json', *argv],
                         capture_output=True, text=True, timeout=timeout,
                         env=dict(os.environ, CARTPOLE_CACHE_DIR=str(cache)))
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1]), run.stderr


def default_plan_key() -> str:
    problem = plan_problem(P, P.x_middle, 0.0, TimeOptimalSwingUp.defaults())
    return problem.key(P.sample_time)


def test_lockstep_processes_run_solves_the_missing_plan_before_it_starts(tmp_path, cold_plan_run):
    summary, err = cartpole_run(tmp_path, '--lockstep', '--processes', '--duration', '4')
    assert 'solving the minimum-time plan from hanging rest at x = 0.00 m' in err
    assert summary['swingup_law'] == 'time_optimal:plan', err[-3000:]
    offline = json.loads(cold_plan_run[1].stdout)
    assert summary['catch_time_s'] == pytest.approx(offline['catch_time_s'], abs=1e-9)


def test_real_time_run_without_a_plan_falls_back_announced_then_the_next_one_tracks_it(tmp_path):
    summary, err = cartpole_run(tmp_path, '--duration', '10', '--window', '3')
    # The loop did not wait: energy_saturated swung up, said so, and the run succeeded.
    assert summary['swingup_law'] == 'time_optimal:fallback(no plan)', summary
    assert summary['success'] is True, (summary, err[-3000:])
    assert 'solving it in background process' in err and 'falls back to energy_saturated' in err
    # The background solve finishes on its own (the run's processes are gone) ...
    cache, key = TrajectoryCache(tmp_path), default_plan_key()
    deadline = time.monotonic() + 600.0
    while not (cache.has(key) and cache.lock(key).holder() is None):
        assert time.monotonic() < deadline, cache.log_path(key).read_text()[-3000:]
        time.sleep(0.5)
    assert cache.get(key).success, cache.log_path(key).read_text()[-3000:]
    # ... and the next real-time run loads it on configure and tracks it.
    again, err = cartpole_run(tmp_path, '--duration', '4')
    assert again['swingup_law'] == 'time_optimal:plan', err[-3000:]
    assert again['catch_time_s'] < 1.6, again
