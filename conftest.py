"""Test isolation for the whole workspace (package tests and test/).

Every test session gets its own ROS_DOMAIN_ID and localhost-only discovery, so
concurrent runs on one machine (and the network) never see each other. Set
before any rclpy import and inherited by every subprocess a test starts.
"""
import atexit
import os
import shutil
import subprocess
import sys
import tempfile

import pytest

# Under pytest-xdist (``make test`` runs two workers) the controller picks the domain and
# each worker takes the next ones: ``gw0`` base + 1, ``gw1`` base + 2 (never one shared).
_WORKER = os.environ.get('PYTEST_XDIST_WORKER', '')
if not _WORKER:
    os.environ['CARTPOLE_TEST_DOMAIN_BASE'] = str(os.environ.get('CARTPOLE_TEST_DOMAIN_ID')
                                                  or 1 + os.getpid() % 200)
os.environ['ROS_DOMAIN_ID'] = str(int(os.environ['CARTPOLE_TEST_DOMAIN_BASE'])
                                  + (int(_WORKER[2:]) + 1 if _WORKER.startswith('gw') else 0))
# Localhost discovery with the DDS profiles every cartpole process takes for it (UDP on
# 127.0.0.1; cartpole_core.middleware), in this process too.
from cartpole_core.middleware import set_discovery_range  # noqa: E402

set_discovery_range('LOCALHOST')
os.environ.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '1')
os.environ.setdefault('MPLBACKEND', 'Agg')
# time_optimal's plan cache: a fresh one per session, never the user's ~/.cache.
os.environ['CARTPOLE_CACHE_DIR'] = tempfile.mkdtemp(prefix='cartpole-test-cache-')
atexit.register(shutil.rmtree, os.environ['CARTPOLE_CACHE_DIR'], True)

ROS_GRAPH_GROUP = 'ros_graph'
"""The xdist group of every ``ros`` test: one worker runs them one after another, so no two
graphs (a real-time one needs more than one core) share the 2 cores; the other tests
spread over both workers, at a lower CPU priority than the graph (``_graph_first``)."""


@pytest.hookimpl(tryfirst=True)   # before xdist's own, which reads the group marks
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.get_closest_marker('ros') is not None:
            item.add_marker(pytest.mark.xdist_group(ROS_GRAPH_GROUP))


@pytest.fixture(autouse=True)
def _graph_first(request):
    """Under xdist, a test without a ROS graph runs (with what it starts) at nice 10, so the
    graph tests on the other worker keep their real-time budget; as root, ``ros`` tests go
    back to nice 0. Outside xdist, or not root, nothing changes."""
    if not _WORKER or os.geteuid() != 0:
        yield
        return
    wanted = 0 if request.node.get_closest_marker('ros') is not None else 10
    os.setpriority(os.PRIO_PROCESS, 0, wanted)
    yield


@pytest.fixture(autouse=True)
def _rclpy_needs_the_ros_marker(request, monkeypatch):
    """A test that starts rclpy in this process is marked ``ros`` (so ``make test-fast``,
    ``-m "not ros and not slow"``, never waits on DDS): unmarked, rclpy.init refuses."""
    if request.node.get_closest_marker('ros') is not None:
        return
    import rclpy
    if getattr(rclpy.init, '__module__', None) != 'rclpy':
        return  # a test's own stand-in (the fuzz tests stop the work there)

    def refuse(*args, **kwargs):
        raise RuntimeError(f'{request.node.nodeid} starts rclpy: mark it pytest.mark.ros')
    monkeypatch.setattr(rclpy, 'init', refuse)


@pytest.fixture
def ros_context():
    """An initialised rclpy Context, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def spin_until():
    """spin_until(executor, predicate, timeout) -> bool: spin until predicate() holds.

    Waits on the executor (work arrives as events), never on a bare sleep; the
    timeout only bounds a failing test.
    """
    from cartpole_core.spin import spin_until as _spin

    def _spin_until(executor, predicate, timeout=30.0):
        return _spin(executor, predicate, timeout)
    return _spin_until


@pytest.fixture
def truth_stamps(ros_context):
    """(stamps seen, executor): a probe node on ``/cartpole/true_state`` collecting the
    stamps [ns] of the plant's samples, to tell how far a run started by the test has
    come (spin the executor with ``spin_until``); destroyed after the test."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    probe = Node('_truth_probe', context=ros_context)
    seen: list[int] = []
    probe.create_subscription(JointState, '/cartpole/true_state', lambda m: seen.append(
        m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    try:
        yield seen, executor
    finally:
        executor.shutdown(timeout_sec=1.0)
        probe.destroy_node()


@pytest.fixture
def three_ways():
    """three_ways(run, cases) -> (serial, pool, dask): a sweep runner's results on every executor.

    ``run(cases, workers=..., dask_address=...)`` is :func:`cartpole_tools.bench.control.run_sweep`
    or :func:`cartpole_tools.bench.robustness.run_grid`: serially, on a pool of two
    processes and on a local Dask cluster of two worker processes.
    """
    def _three_ways(run, cases):
        from distributed import LocalCluster

        serial = run(cases, workers=1)
        pool = run(cases, workers=2)
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:
            dask = run(cases, dask_address=cluster.scheduler_address)
        return serial, pool, dask
    return _three_ways


@pytest.fixture(scope='session')
def cold_plan_run(tmp_path_factory):
    """``cartpole offline --swingup time_optimal --json`` once a session from a cold plan
    cache (a fresh directory): ``(cache directory, CompletedProcess)``.

    The run solves the default start's plan first (about 10 s); tests that need that
    plan use this cache directory instead of solving it again. Under xdist the first
    worker that needs it runs it (the others wait on a lock) and each worker gets its
    own copy of the cache it left.
    """
    import fcntl
    import json

    mine = tmp_path_factory.getbasetemp()
    shared = mine.parent if _WORKER else mine   # xdist: <session>/popen-gwN
    solved, record = shared / 'plan-cache-cold', shared / 'plan-cache-cold.json'
    with open(shared / 'plan-cache-cold.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not record.exists():
            solved.mkdir()
            run = subprocess.run(
                [sys.executable, '-m', 'cartpole_bringup.cli', 'offline', '--swingup',
                 'time_optimal', '--json'], capture_output=True, text=True, timeout=900,
                env=dict(os.environ, CARTPOLE_CACHE_DIR=str(solved)))
            record.write_text(json.dumps([run.args, run.returncode, run.stdout, run.stderr]))
    args, code, out, err = json.loads(record.read_text())
    cache = tmp_path_factory.mktemp('plan-cache')
    shutil.copytree(solved, cache, dirs_exist_ok=True)
    return cache, subprocess.CompletedProcess(args, code, out, err)
