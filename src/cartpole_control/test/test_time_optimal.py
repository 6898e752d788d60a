"""Time-optimal swing-up: plan, TV-LQR tracking, fall-back, switching by parameter.

The plan is solved once a session, by the cold-cache ``cartpole offline`` run of the
``cold_plan_run`` fixture (conftest.py), and reused from its cache by the other tests.
"""
import json
import math
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from cartpole_control.controller import ControlContext, ControllerState
from cartpole_control.controllers import time_optimal
from cartpole_control.controllers.time_optimal import FALLBACK, PLAN, TimeOptimalSwingUp
from cartpole_control import plan_cache
from cartpole_control.plan_cache import TrajectoryCache
from cartpole_control.registry import load_controllers
from cartpole_core.model import CartPoleParameters

P = CartPoleParameters()
TS = P.sample_time
LEFT_STOP_BOUND = 1.17
"""The reference minimum-time bound from the left stop [s] (ISSUE_BOUNDS)."""


@pytest.fixture(scope='module')
def cache_dir(cold_plan_run):
    """A cache holding the plan for the default start, solved this session (not a leftover)."""
    directory, run = cold_plan_run
    assert run.returncode == 0, run.stderr[-3000:]
    return directory


def configured(cache_dir, **gains):
    """An instance configured as the manager's live one (it loads the default start's plan)."""
    c = TimeOptimalSwingUp()
    c.configure({'cache_dir': str(cache_dir), 'plan_on_activation': False, **gains},
                ControlContext(P, P.x_middle, TS))
    return c


def offline_json(cache_dir, *argv):
    return subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'offline', '--swingup',
                           'time_optimal', '--json', *argv], capture_output=True, text=True,
                          timeout=900, env=dict(os.environ, CARTPOLE_CACHE_DIR=str(cache_dir)))


@pytest.mark.slow
def test_cold_cache_offline_run_solves_the_plan_first_and_tracks_it(cold_plan_run):
    directory, run = cold_plan_run
    assert run.returncode == 0, run.stderr[-3000:]  # and no abort at exit
    assert 'solving the minimum-time plan from hanging rest at x = 0.00 m' in run.stderr
    s = json.loads(run.stdout)
    assert s['swingup_law'] == 'time_optimal:plan', run.stderr
    assert s['catch_time_s'] <= 1.55 and s['success'], s  # the plan's catch, not 1.81 s
    # The plan and its TV-LQR gains stored; no lock, failure record or worker log left.
    key = time_optimal.plan_problem(P, P.x_middle, 0.0, TimeOptimalSwingUp.defaults()).key(TS)
    cache = TrajectoryCache(directory)
    assert cache.get(key).success and len(list(directory.glob(f'{key}.tvlqr-*.npy'))) == 1
    assert not [p for p in directory.iterdir() if p.suffix in ('.lock', '.failed', '.log')]


@pytest.mark.slow
def test_a_second_run_reuses_the_cached_plan(cold_plan_run):
    directory, first = cold_plan_run
    again = offline_json(directory)
    assert again.returncode == 0, again.stderr[-3000:]
    assert 'solving' not in again.stderr
    assert json.loads(again.stdout) == json.loads(first.stdout)


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_activation_only_looks_the_prepared_plan_up(cache_dir, monkeypatch):
    c = configured(cache_dir)  # configure read the plan and built its gains
    assert c.law == 'time_optimal'  # not activated yet: nothing decided

    def no_work(*args, **kwargs):
        raise AssertionError('slow work inside activate')
    monkeypatch.setattr(plan_cache, 'tracking_gains', no_work)
    for read in ('get', 'get_gains', 'has'):
        monkeypatch.setattr(TrajectoryCache, read, no_work)
    c.activate(ControllerState(0.0, 0.004, math.pi + 0.03, 0.0, 0.0))
    assert c.mode == PLAN and c.law == 'time_optimal:plan'
    c.activate(ControllerState(0.0, 0.30, math.pi, 0.0, 0.0))
    assert c.mode == FALLBACK and 'no plan' in c.fallback_reason
    assert c.law == 'time_optimal:fallback(no plan)'
    c.activate(ControllerState(0.0, 0.0, 2.0, 0.0, 4.0))
    assert c.mode == FALLBACK and c.law == 'time_optimal:fallback(not at hanging rest)'


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_a_start_without_a_loaded_plan_loads_it_off_the_cycle_for_the_next_swingup(cache_dir):
    c = configured(cache_dir, precompute=False, plan_on_activation=True)
    start = ControllerState(0.0, 0.0, math.pi, 0.0, 0.0)
    started_by, load = [], c._start_load

    def recorded(x0):
        started_by.append(threading.current_thread().name)
        load(x0)

    c._start_load = recorded
    c.activate(start)
    assert c.law == 'time_optimal:fallback(no plan)'  # this swing-up: the fall-back
    done = threading.Event()

    def loaded():
        while c._loading and not done.wait(0.01):
            pass
        done.set()

    watcher = threading.Thread(target=loaded)
    watcher.start()
    assert done.wait(60.0)
    watcher.join()
    for thread in threading.enumerate():
        if thread.name.startswith('time_optimal-load-'):
            thread.join(timeout=60.0)
    # The activation (in the cycle) only queued the load; the dispatcher started it.
    assert started_by == ['time_optimal-loads']
    c.deactivate()
    c.activate(start)
    assert c.law == 'time_optimal:plan'  # the next one from there: the plan


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_prepare_returns_the_gains_that_load_the_plan_and_solves_nothing_cached(
        cache_dir, monkeypatch):
    from cartpole_control.manager import ControllerManager
    monkeypatch.setattr(plan_cache, 'solve_minimum_time', lambda *a, **k: 1 / 0)
    m = ControllerManager(P, sample_time=TS)
    assert m.set_parameters({'swingup': 'time_optimal',
                             'time_optimal.cache_dir': str(cache_dir)}).successful
    said = []
    changes = m.prepare(ControllerState(0.0, 0.0, math.pi, 0.0, 0.0), said.append)
    assert changes == {'time_optimal.plan_x0': 0.0, 'time_optimal.plan_on_activation': False,
                       'time_optimal.precompute': True}
    assert said == []  # cached: nothing to say, nothing solved
    assert m.get_parameters()['time_optimal.plan_on_activation'] is False
    out = m.update_values(0.0, 0.0, math.pi, 0.0, 0.0)
    assert out.swingup_law == 'time_optimal:plan'


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_plan_is_on_the_control_grid_and_within_its_limits(cache_dir):
    c = configured(cache_dir)
    problem = c.problem_for(0.0)
    plan = c.cache.get(problem.key(TS))
    assert plan.dt == pytest.approx(TS)
    assert plan.final_time <= 1.5 * LEFT_STOP_BOUND
    scale = c.gains['force_scale']
    assert plan.forces.max() <= scale * P.force_max + 1e-6
    assert plan.forces.min() >= scale * P.force_min - 1e-6
    x = plan.states[:, 0]
    assert x.max() <= P.travel - c.gains['rail_margin'] + 1e-6
    assert abs(plan.states[-1, 0] - P.x_middle) <= c.gains['terminal_window'] + 1e-6
    assert problem.start == (0.0, math.pi, 0.0, 0.0)


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_tracking_error_invalidates_the_plan(cache_dir):
    c = configured(cache_dir)
    c.activate(ControllerState(1.0, 0.0, math.pi, 0.0, 0.0))
    assert c.mode == PLAN
    first = c.update(ControllerState(1.0, 0.0, math.pi, 0.0, 0.0))
    assert first > 0.0  # the plan's first push is to the right, off the stop
    # 0.3 s later the cart has not moved: far off the plan.
    c.update(ControllerState(1.3, 0.0, math.pi, 0.0, 0.0))
    assert c.mode == FALLBACK and 'tracking error' in c.fallback_reason
    assert c.law == 'time_optimal:fallback(tracking error)'
    c.deactivate()
    assert c.law == 'time_optimal:fallback(tracking error)'  # what ran, kept after the catch


@pytest.mark.slow  # cache_dir: the plan solved this session (~10 s of CPU)
def test_raw_force_leaves_room_for_the_manager_feedforward(cache_dir):
    """raw + B_ff(x_dot, raw) (6.12) is the plan's force at the plan's state."""
    c = configured(cache_dir)
    plan = c.cache.get(c.problem_for(0.0).key(TS))
    c.activate(ControllerState(0.0, 0.0, math.pi, 0.0, 0.0))
    k = 40
    s = plan.states[k]
    raw = c.update(ControllerState(k * TS, *s))
    ff = 3.3 * math.tanh(20.0 * raw) if s[2] >= 0 else 2.8 * math.tanh(20.0 * raw)
    assert raw + ff == pytest.approx(plan.forces[k], abs=0.05)


def test_registered():
    assert load_controllers('swingup')['time_optimal'] is TimeOptimalSwingUp


@pytest.mark.slow
@pytest.mark.parametrize('stabilizer', ['pid', 'lqg', 'smc'])
def test_offline_from_the_left_stop_catches_within_1_5x_the_bound(cache_dir, stabilizer):
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    run = run_closed_loop(duration=20.0, manager_parameters={  # 20 s: the LQI settles in ~4 s
        'swingup': 'time_optimal', 'stabilizer': stabilizer,
        'time_optimal.cache_dir': str(cache_dir)})
    s = run.summary
    assert s['success'], s
    assert s['catch_time_s'] <= 1.5 * LEFT_STOP_BOUND
    assert s['swingup_law'] == 'time_optimal:plan'


@pytest.mark.slow
def test_fall_back_engages_for_a_start_far_from_the_plan_and_still_catches(cache_dir):
    """From hanging rest at x = 0.25 m there is no plan: energy_saturated swings up.

    (From 0.3 m and beyond energy_saturated's catch comes at the edge of the window, the cart
    at 0.5 m moving right at 0.5 m/s with the pendulum 29 deg off and falling at 3 rad/s, and
    with the midpoint EKF the rail guard trips after it; from 0.35 m with either filter.
    20 s: the LQI takes about 4 s after a catch to bring the cart within 2 cm.)"""
    from cartpole_bringup.offline.closed_loop import run_closed_loop
    from cartpole_sim.plant import Scenario
    params = {'swingup': 'time_optimal', 'stabilizer': 'lqg',
              'time_optimal.cache_dir': str(cache_dir), 'time_optimal.plan_on_activation': False}
    # Not prepared (prepare=False): a real-time start with no plan for it.
    run = run_closed_loop(scenario=Scenario(x0=0.25), duration=20.0, manager_parameters=params,
                          prepare=False)
    assert run.summary['success'], run.summary
    assert run.summary['swingup_law'] == 'time_optimal:fallback(no plan)'
    # Up to the catch the commands are exactly those of energy_saturated alone.
    alone = run_closed_loop(scenario=Scenario(x0=0.25), duration=3.0, manager_parameters={
        'swingup': 'energy_saturated', 'stabilizer': 'lqg'})
    assert alone.summary['swingup_law'] == 'energy_saturated'
    assert alone.catch_time == run.catch_time
    n = int(round(run.catch_time / TS))
    np.testing.assert_array_equal(run.force[:n], alone.force[:n])


@pytest.mark.ros
@pytest.mark.parametrize('name', ['time_optimal', 'energy_saturated'])
def test_switching_by_parameter_set_like_any_swingup(ros_context, spin_until, tmp_path, name):
    """What `ros2 param set /controller_manager swingup <name>` sends: the SetParameters service."""
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from cartpole_control.manager_node import ControllerManagerNode

    node = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('time_optimal.cache_dir', value=str(tmp_path)),
        Parameter('time_optimal.precompute', value=False)])
    client_node = Node('param_client', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(client_node)
    try:
        client = client_node.create_client(SetParameters, '/controller_manager/set_parameters')
        assert spin_until(executor, client.service_is_ready, 20.0)

        def set_params(**values):
            msgs = []
            for key, value in values.items():
                if isinstance(value, str):
                    v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
                else:
                    v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
                msgs.append(ParameterMsg(name=key.replace('__', '.'), value=v))
            future = client.call_async(SetParameters.Request(parameters=msgs))
            assert spin_until(executor, future.done, 20.0)
            return future.result().results

        (ok,) = set_params(swingup=name)
        assert ok.successful, ok.reason
        assert node.get_parameter('swingup').value == name
        # The plugin's gains are parameters under its name, validated with a reason.
        gain = 'time_optimal__force_scale' if name == 'time_optimal' else 'energy_saturated__n'
        (bad,) = set_params(**{gain: 50.0})
        assert not bad.successful
        (good,) = set_params(**{gain: 0.5})
        assert good.successful, good.reason
        assert node.get_parameter(gain.replace('__', '.')).value == 0.5
    finally:
        executor.remove_node(node)
        executor.remove_node(client_node)
        client_node.destroy_node()
        node.destroy_node()


def test_validating_a_change_starts_no_background_solve(tmp_path, monkeypatch, caplog):
    # The manager checks gains on scratch instances (ControlContext.validation_only);
    # those must not start IPOPT, only the instance that will run may, and says so.
    import dataclasses as _dc
    monkeypatch.setenv('CARTPOLE_CACHE_DIR', str(tmp_path))
    context = ControlContext(plant=P, x_ref=P.x_middle, sample_time=TS)
    started = []

    class Worker:
        pid = 4242

        def poll(self):
            return None
    monkeypatch.setattr(time_optimal, 'start_background_solve',
                        lambda problem, *a, **k: started.append(problem.start) or Worker())
    TimeOptimalSwingUp().configure({}, _dc.replace(context, validation_only=True))
    assert started == []
    live = TimeOptimalSwingUp()
    live.configure({}, context)
    assert started == [(0.0, math.pi, 0.0, 0.0)]
    assert 'solving it in background process 4242' in caplog.text
    live.configure({'abort_x': 0.2}, context)  # same plan problem: not started again
    assert len(started) == 1


def test_plan_force_is_net_of_the_managers_own_feedforward_settings():
    # The plan pays for friction; the plugin removes exactly the feedforward the manager
    # will add, as the manager is configured (ControlContext.feedforward), not a copy.
    from cartpole_control.feedforward import FrictionFeedforward
    from cartpole_control.manager import ControllerManager
    from cartpole_core.model import CartPoleParameters
    p = CartPoleParameters()
    m = ControllerManager(p, sample_time=p.sample_time)
    assert m.set_parameters({'swingup': 'time_optimal', 'feedforward.right': 4.0,
                             'feedforward.steepness': 50.0, 'time_optimal.precompute': False,
                             'time_optimal.plan_on_activation': False}).successful
    m.update_values(0.0, 0.0, math.pi, 0.0, 0.0)  # applies the queued change
    plugin = m._plugins['swingup']
    assert plugin.context.feedforward == FrictionFeedforward(4.0, 2.8, 50.0)
