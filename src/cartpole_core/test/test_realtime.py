"""Real-time hygiene of the loop's processes (cartpole_core.realtime), without ROS.

Scheduling is changed only in child processes, so the test session keeps its own.
"""
import functools
import gc
import os
import subprocess
import sys
import textwrap

import pytest

from cartpole_core import realtime


def run_child(code: str, env_update=None, drop=()) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(env_update or {})
    return subprocess.run([sys.executable, '-c', textwrap.dedent(code)], env=env,
                          capture_output=True, text=True, timeout=60)


@functools.lru_cache(maxsize=None)
def fifo_permitted() -> bool:
    probe = run_child('''
        import os
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    ''')
    return probe.returncode == 0


# -- numerical threads ---------------------------------------------------------------------------
def test_pin_sets_unset_variables_to_one_and_keeps_the_users():
    env = {'OMP_NUM_THREADS': '4', 'MKL_NUM_THREADS': ''}
    changed = realtime.pin_numerical_threads(env)
    assert env['OMP_NUM_THREADS'] == '4' and 'OMP_NUM_THREADS' not in changed
    assert all(env[name] == '1' for name in realtime.NUMERICAL_THREAD_VARIABLES
               if name != 'OMP_NUM_THREADS')
    assert realtime.unpinned_numerical_threads(env) == {'OMP_NUM_THREADS': '4'}


def test_importing_a_node_module_pins_blas_before_numpy_loads():
    """A node executable imports its package first: no BLAS worker thread is started."""
    result = run_child('''
        import os, sys
        import cartpole_estimation.ekf          # numpy and the filter, as ekf_node does
        assert 'numpy' in sys.modules
        print(os.environ['OPENBLAS_NUM_THREADS'], os.environ['OMP_NUM_THREADS'],
              len(os.listdir('/proc/self/task')))
    ''', drop=realtime.NUMERICAL_THREAD_VARIABLES)
    assert result.returncode == 0, result.stderr
    blas, omp, threads = result.stdout.split()
    assert (blas, omp) == ('1', '1')
    if (os.cpu_count() or 1) > 1:
        assert threads == '1'      # unpinned, OpenBLAS starts one thread per extra core


# -- the environment switch ----------------------------------------------------------------------
@pytest.mark.parametrize('text,priority', [('', realtime.DEFAULT_PRIORITY),
                                           ('on', realtime.DEFAULT_PRIORITY), ('off', 0),
                                           ('0', 0), ('5', 5), (' 49 ', 49)])
def test_priority_from_environment(text, priority):
    env = {realtime.ENVIRONMENT_SWITCH: text} if text else {}
    assert realtime.priority_from_environment(env) == priority


@pytest.mark.parametrize('text', ['fast', '50', '-1', '99', '2.5'])
def test_a_bad_switch_is_refused_with_the_accepted_values(text):
    with pytest.raises(ValueError, match='expected on, off'):
        realtime.priority_from_environment({realtime.ENVIRONMENT_SWITCH: text})


# -- garbage collector ---------------------------------------------------------------------------
def test_collector_frozen_after_start_up_and_run_only_when_idle():
    before = gc.get_threshold()
    lines = []
    hygiene = realtime.enter_loop(0, log=lines.append)
    try:
        assert hygiene.priority == 0 and hygiene.frozen == gc.get_freeze_count() > 1000
        assert gc.get_count()[0] < 10                                 # all of it frozen
        assert lines == [hygiene.message] and 'gc frozen' in lines[0]
        assert gc.get_threshold()[0] == realtime.SAFETY_THRESHOLD
        gc.collect()
        assert realtime.collect_when_idle() == -1                     # nothing due
        garbage = [[i] for i in range(realtime.IDLE_THRESHOLDS[0] + 50)]
        assert gc.get_count()[0] > realtime.IDLE_THRESHOLDS[0]       # no automatic collection
        assert realtime.collect_when_idle() == 0                      # a young collection
        assert gc.get_count()[0] < realtime.IDLE_THRESHOLDS[0]
        generations, kept = [], []
        for _ in range(12 * realtime.IDLE_THRESHOLDS[1]):
            kept.append([[i] for i in range(realtime.IDLE_THRESHOLDS[0] + 50)])
            generations.append(realtime.collect_when_idle())
        assert set(generations) == {0, 1}                             # CPython's cadence,
        assert generations.count(1) < generations.count(0)            # no full collection
        del garbage, kept
    finally:
        hygiene.leave()
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0
    assert realtime.collect_when_idle() == -1                         # policy gone


# -- scheduling ----------------------------------------------------------------------------------
def test_fifo_on_every_thread_then_normal_again():
    if not fifo_permitted():
        pytest.skip('SCHED_FIFO not permitted here')
    result = run_child('''
        import os, threading
        from cartpole_core import realtime
        worker = threading.Event()
        t = threading.Thread(target=worker.wait); t.start()         # a thread from start-up
        hygiene = realtime.enter_loop(7, log=print)
        tasks = os.listdir('/proc/self/task')
        print('during', sorted({os.sched_getscheduler(int(x)) & 0xff for x in tasks}),
              os.sched_getparam(0).sched_priority)
        hygiene.leave()
        print('after', sorted({os.sched_getscheduler(int(x)) for x in tasks}))
        worker.set(); t.join()
    ''')
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert 'SCHED_FIFO priority 7 on 2 threads' in lines[0]
    assert lines[1] == f'during [{os.SCHED_FIFO}] 7'
    assert lines[2] == f'after [{os.SCHED_OTHER}]'


def test_in_real_time_the_pages_mapped_are_locked_then_unlocked():
    """mlockall(MCL_CURRENT | MCL_ONFAULT): nothing evicted under a neighbour's file reads
    stalls the loop, and nothing is faulted in for it (the resident size stays)."""
    if not fifo_permitted():
        pytest.skip('SCHED_FIFO not permitted here')
    result = run_child('''
        from cartpole_core import realtime

        def status(key):
            for line in open('/proc/self/status'):
                if line.startswith(key + ':'):
                    return int(line.split()[1])
        rss = status('VmRSS')
        hygiene = realtime.enter_loop(5, log=print)
        print('during', hygiene.memory_locked, status('VmLck') > 0,
              status('VmRSS') < rss + 20_000)
        hygiene.leave()
        print('after', hygiene.memory_locked, status('VmLck'))
    ''')
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert 'memory locked' in lines[0], lines[0]
    assert lines[1:] == ['during True True True', 'after False 0']


def test_memory_not_locked_says_how_to_allow_it(monkeypatch):
    if not fifo_permitted():
        pytest.skip('SCHED_FIFO not permitted here')
    monkeypatch.setattr(realtime, 'lock_memory', lambda: 'Cannot allocate memory')
    monkeypatch.setattr(realtime, '_set_policy', lambda policy, priority: 1)
    warnings = []
    hygiene = realtime.enter_loop(20, log=print, warn=warnings.append, what='sim')
    try:
        assert hygiene.priority == 20 and not hygiene.memory_locked
        (line,) = warnings
        assert 'memory not locked (Cannot allocate memory)' in line and 'ulimit -l' in line
    finally:
        hygiene.priority = 0  # nothing was really changed
        hygiene.leave()


def test_a_runaway_thread_drops_the_process_back_to_normal_priority():
    """RLIMIT_RTTIME: a real-time thread that never blocks cannot starve the machine."""
    if not fifo_permitted():
        pytest.skip('SCHED_FIFO not permitted here')
    result = run_child('''
        import os, time
        from cartpole_core import realtime
        realtime.RUNAWAY_LIMIT = 0.05
        hygiene = realtime.enter_loop(3, log=print)
        t0 = time.monotonic()
        while hygiene.priority and time.monotonic() - t0 < 5.0:
            pass                                     # spins without a blocking call
        print(os.sched_getscheduler(0), round(time.monotonic() - t0, 1))
    ''')
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[1].startswith('real-time priority dropped: a thread ran 0.05 s without '
                               'blocking (SIGXCPU)')
    policy, spun = lines[2].split()
    assert int(policy) == os.SCHED_OTHER and float(spun) < 5.0


def test_not_permitted_says_so_and_runs_at_normal_priority(monkeypatch):
    def refuse(*args):
        raise PermissionError(1, 'Operation not permitted')
    monkeypatch.setattr(realtime.os, 'sched_setscheduler', refuse)
    infos, warnings = [], []
    hygiene = realtime.enter_loop(20, log=infos.append, warn=warnings.append, what='ekf')
    try:
        assert hygiene.priority == 0 and infos == []
        (line,) = warnings
        assert line.startswith('ekf: real-time: ')
        assert 'SCHED_FIFO 20) not permitted (Operation not permitted)' in line
        assert 'CARTPOLE_REALTIME=off' in line and 'ulimit -r' in line
    finally:
        hygiene.leave()


def test_the_loop_nodes_take_the_priority_and_the_recorder_one_below(monkeypatch):
    """By role, whatever the node is called (``-r __node:=plant`` keeps the sim's priority)."""
    asked = []
    monkeypatch.setattr(realtime, 'enter_loop',
                        lambda priority, **kw: asked.append((kw['what'], priority)))

    class Logger:
        info = warning = staticmethod(print)
    monkeypatch.setenv(realtime.ENVIRONMENT_SWITCH, '9')
    for name in ('controller_manager', 'ekf', 'hw_bridge', 'sim', 'recorder'):
        realtime.node_hygiene(name, Logger())
    realtime.node_hygiene('controller_manager', Logger(), simulated_time=True)   # lockstep
    realtime.node_hygiene('sim', Logger(), name='plant')                          # renamed
    realtime.node_hygiene(None, Logger(), name='sim')               # no role: a name is not one
    realtime.node_hygiene('recorder', Logger(), simulated_time=True)             # lockstep
    monkeypatch.setenv(realtime.ENVIRONMENT_SWITCH, '5')
    realtime.node_hygiene('recorder', Logger(), name='low')        # never at or above the loop
    # the recorder, not in the loop, below it (a starved recorder loses samples)
    assert asked == [('controller_manager', 9), ('ekf', 9), ('hw_bridge', 9), ('sim', 9),
                     ('recorder', 4), ('controller_manager', 0), ('plant', 9), ('sim', 0),
                     ('recorder', 0), ('low', 0)]


def test_an_executable_s_role_does_not_depend_on_its_node_name():
    from cartpole_core.roles import LOOP_ROLES, role_of_executable
    assert {role_of_executable(exe) for exe in ('sim_node', 'hw_bridge', 'ekf_node',
                                                'controller_manager')} == LOOP_ROLES
    assert role_of_executable('recorder') == 'recorder'
    assert role_of_executable('viewer') is None and role_of_executable('sim') is None


# -- stall figure --------------------------------------------------------------------------------
def test_cycle_gap_meter_keeps_the_longest_gap():
    meter = realtime.CycleGapMeter()
    for t in (10.0, 10.005, 10.010, 10.060, 10.065):
        meter.tick(t)
    assert meter.longest == pytest.approx(0.05) and meter.cycles == 5
    assert meter.tick(10.066) == pytest.approx(0.001)
