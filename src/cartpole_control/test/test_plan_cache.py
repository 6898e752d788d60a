"""The plan cache: round trip, one solver a plan, stale locks never block, failures say why."""
import json
import logging
import subprocess
import sys

import numpy as np
import pytest

from cartpole_control import plan_cache
from cartpole_control import trajectory_optimization as to
from cartpole_control.plan_cache import PlanBusy, PlanError, TrajectoryCache, solve_cached
from cartpole_core.model import CartPoleParameters

P = CartPoleParameters()
PROBLEM = to.bound_problem('middle', P)
TS = 0.005


def fake_plan(problem=PROBLEM):
    return to.Trajectory(dt=TS, states=np.zeros((3, 4)), forces=np.array([1.0, -2.0]),
                         success=True, solve_time=1.5, key=problem.key(TS))


@pytest.fixture
def fake_solver(monkeypatch):
    """solve_minimum_time replaced by an instant one; the list of its calls."""
    calls = []
    monkeypatch.setattr(plan_cache, 'solve_minimum_time',
                        lambda problem, **options: calls.append(options) or fake_plan(problem))
    return calls


def test_cache_round_trip_and_a_repeated_start_costs_no_solve(tmp_path, fake_solver):
    cache = TrajectoryCache(tmp_path)
    first = solve_cached(PROBLEM, TS, cache, n_intervals=70)
    second = solve_cached(PROBLEM, TS, cache, n_intervals=70)
    assert fake_solver == [{'grid': TS, 'n_intervals': 70}]
    assert first.solved and not second.solved and second.path == cache.path(PROBLEM.key(TS))
    np.testing.assert_array_equal(second.plan.forces, [1.0, -2.0])
    assert second.plan.success and second.plan.final_time == pytest.approx(0.01)
    assert not cache.lock(PROBLEM.key(TS)).path.exists()  # released and removed
    # A damaged file counts as missing.
    cache.path(PROBLEM.key(TS)).write_bytes(b'not a plan')
    assert cache.get(PROBLEM.key(TS)) is None


def test_default_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv('CARTPOLE_CACHE_DIR', str(tmp_path))
    assert plan_cache.default_cache_dir() == tmp_path
    monkeypatch.delenv('CARTPOLE_CACHE_DIR')
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path))
    assert plan_cache.default_cache_dir() == tmp_path / 'cartpole' / 'trajectories'


def dead_pid() -> int:
    done = subprocess.run([sys.executable, '-c', 'import os; print(os.getpid())'],
                          capture_output=True, text=True, check=True)
    return int(done.stdout)


def test_a_lock_left_by_a_dead_process_never_blocks(tmp_path, fake_solver):
    cache = TrajectoryCache(tmp_path)
    lock = cache.lock(PROBLEM.key(TS))
    for content in (json.dumps({'pid': dead_pid(), 'since': 0.0}), ''):  # '' : older versions
        lock.path.write_text(content)
        assert lock.holder() is None  # stale: nobody holds it
        result = solve_cached(PROBLEM, TS, cache, wait=False)  # PlanBusy if it blocked
        assert result.solved and not lock.path.exists()
        cache.path(PROBLEM.key(TS)).unlink()
    assert len(fake_solver) == 2


HOLDER = '''
import sys
from cartpole_control.plan_cache import PlanLock
lock = PlanLock(sys.argv[1])
assert lock.acquire()
print('locked', flush=True)
sys.stdin.read()
'''


def test_a_live_holder_blocks_until_it_is_killed(tmp_path, fake_solver):
    cache = TrajectoryCache(tmp_path)
    lock = cache.lock(PROBLEM.key(TS))
    holder = subprocess.Popen([sys.executable, '-c', HOLDER, str(lock.path)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == 'locked'
        assert lock.holder() == holder.pid
        with pytest.raises(PlanBusy) as busy:
            solve_cached(PROBLEM, TS, cache, wait=False)
        assert busy.value.pid == holder.pid and fake_solver == []
    finally:
        holder.kill()  # SIGKILL: no clean-up; the file stays with its PID in it
        holder.wait(timeout=30)
    assert json.loads(lock.path.read_text())['pid'] == holder.pid
    assert lock.holder() is None
    assert solve_cached(PROBLEM, TS, cache, wait=False).solved


def test_a_failed_solve_is_logged_with_its_reason(tmp_path, monkeypatch, caplog):
    def broken(problem, **options):
        raise RuntimeError('IPOPT exploded')
    monkeypatch.setattr(plan_cache, 'solve_minimum_time', broken)
    cache = TrajectoryCache(tmp_path)
    with caplog.at_level(logging.ERROR), pytest.raises(PlanError, match='IPOPT exploded'):
        solve_cached(PROBLEM, TS, cache)
    assert 'IPOPT exploded' in caplog.text
    assert 'IPOPT exploded' in cache.failure(PROBLEM.key(TS))
    assert not cache.lock(PROBLEM.key(TS)).path.exists()
    # The next stored plan clears the record.
    cache.put(PROBLEM.key(TS), fake_plan())
    assert cache.failure(PROBLEM.key(TS)) is None


def test_the_background_worker_is_a_process_that_logs_why_a_solve_failed(tmp_path):
    cache = TrajectoryCache(tmp_path)
    key = PROBLEM.key(TS)
    worker = plan_cache.start_background_solve(PROBLEM, TS, cache, n_intervals=2)
    assert worker is not None
    assert worker.wait(timeout=120) == 1
    assert 'n_intervals must be >= 5' in cache.log_path(key).read_text()
    assert 'n_intervals must be >= 5' in cache.failure(key)
    assert not cache.lock(key).path.exists() and not cache.has(key)


def test_no_background_solve_for_a_cached_plan_or_one_being_solved(tmp_path):
    cache = TrajectoryCache(tmp_path)
    key = PROBLEM.key(TS)
    lock = cache.lock(key)
    assert lock.acquire()  # this process is solving it
    try:
        assert plan_cache.start_background_solve(PROBLEM, TS, cache) is None
    finally:
        lock.release()
    cache.put(key, fake_plan())
    assert plan_cache.start_background_solve(PROBLEM, TS, cache) is None


def test_tracking_gains_are_cached_with_the_plan_and_go_with_it(tmp_path, monkeypatch):
    built = []
    monkeypatch.setattr(plan_cache, 'tracking_gains',
                        lambda problem, plan, q, r: built.append(r) or np.full((2, 4), r))
    cache, key = TrajectoryCache(tmp_path), PROBLEM.key(TS)
    cache.put(key, fake_plan())
    q = (300.0, 300.0, 10.0, 10.0)
    first = plan_cache.cached_tracking_gains(PROBLEM, fake_plan(), key, q, 0.02, cache)
    again = plan_cache.cached_tracking_gains(PROBLEM, fake_plan(), key, q, 0.02, cache)
    other = plan_cache.cached_tracking_gains(PROBLEM, fake_plan(), key, q, 0.5, cache)
    assert built == [0.02, 0.5]  # read back, not built again; other weights, other gains
    np.testing.assert_array_equal(first, again)
    assert other[0, 0] == 0.5
    cache.put(key, fake_plan())  # a new plan for the key: its old gains are gone
    plan_cache.cached_tracking_gains(PROBLEM, fake_plan(), key, q, 0.02, cache)
    assert built == [0.02, 0.5, 0.02]


def test_an_unwritable_cache_is_a_plan_error_with_the_reason(tmp_path, fake_solver):
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    with pytest.raises(PlanError, match='cannot use the plan cache'):
        solve_cached(PROBLEM, TS, TrajectoryCache(blocker / 'cache'))
