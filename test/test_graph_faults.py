"""Node death is a reported fault, not a crash; an orderly stop reports none.

SIGKILL of one node of `cartpole run --processes`: the run commands zero force
through whoever is left, stops the rest in order, closes (or repairs) the bag,
writes summary.json with the fault and exits 1; the bag reads back with every
message up to the kill. In one process a callback that raises is the fault.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from cartpole_core.child_process import child_running, reap

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FORCE = '/cartpole/force_command'
TRUTH = '/cartpole/true_state'


def _run_and_kill(tmp_path, truth_stamps, spin_until, victim: str, after_s: float = 2.0):
    """Start a lockstep --processes run, SIGKILL ``victim`` after ``after_s`` simulated s."""
    seen, executor = truth_stamps
    proc = subprocess.Popen([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                             '--processes', '--lockstep', '--duration', '60',
                             '--record', str(tmp_path), '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert spin_until(executor, lambda: seen and seen[-1] >= after_s * 1e9, 120.0), \
            'the graph did not run'
        os.kill(child_running(proc.pid, victim), signal.SIGKILL)
        killed_at = seen[-1]
        out, err = proc.communicate(timeout=120)
    finally:
        reap(proc)
    return proc.returncode, out, err, killed_at


def _read(bag: Path) -> dict[str, list[tuple[int, float]]]:
    """(stamp, effort[0]) of the JointState topics of a bag, in stamp order."""
    from rosbags.highlevel import AnyReader

    from cartpole_analysis.bags.cdr_parse import parse_joint_state
    out: dict[str, list[tuple[int, float]]] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.msgtype == 'sensor_msgs/msg/JointState']
        for c, _, raw in reader.messages(connections=conns):
            stamp, _, _, _, effort = parse_joint_state(raw)
            out.setdefault(c.topic, []).append((stamp, float(effort[0]) if len(effort) else 0.0))
    return {t: sorted(v) for t, v in out.items()}


def _assert_fault_reported(code, out, err, fault: str) -> tuple[dict, Path]:
    assert code == 1, err[-3000:]
    assert 'Traceback' not in err, err[-3000:]
    assert f'fault: {fault}' in err
    result = json.loads([line for line in out.splitlines() if line.startswith('{')][-1])
    assert result['fault'] == fault and result['success'] is False
    bag = Path(result['bag'])
    assert json.loads((bag.parent / 'summary.json').read_text())['fault'] == fault
    assert (bag / 'metadata.yaml').is_file()
    return result, bag


def test_sigkill_of_the_controller_manager_is_a_reported_fault(tmp_path, truth_stamps,
                                                               spin_until):
    code, out, err, killed_at = _run_and_kill(tmp_path, truth_stamps, spin_until,
                                              'controller_manager')
    result, bag = _assert_fault_reported(code, out, err, 'controller_manager died (SIGKILL)')
    msgs = _read(bag)
    truth = sorted({s for s, _ in msgs[TRUTH]})
    # Every sample up to (at least) the kill, none missing (with one process a node the
    # recorder can miss the plant's very first samples: README, "Recording").
    assert truth[-1] >= killed_at
    assert all(b - a == 5_000_000 for a, b in zip(truth, truth[1:]))
    commands = msgs[FORCE]
    nonzero = [s for s, f in commands if f != 0.0]
    # Every sample the manager answered before it died has its command in the bag ...
    answered = {s for s, _ in commands}
    assert all(s in answered for s in truth if s <= nonzero[-1])
    # ... and after its last one the run itself commanded zero force, which the plant
    # applied within 50 ms (stamps: the first sample whose actuator force is zero).
    last_stamp, last_force = commands[-1]
    assert last_force == 0.0 and last_stamp - nonzero[-1] <= 50_000_000
    applied = [s for s, f in msgs[TRUTH] if s > nonzero[-1] and abs(f) < 1e-3]
    assert applied and applied[0] - nonzero[-1] <= 50_000_000, err[-3000:]
    assert result['controllers'][0]['name'] == 'pendulum_energy'
    analysed = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'analyze', str(bag),
                               '--json'], capture_output=True, text=True, timeout=120)
    assert json.loads(analysed.stdout)['fault'] == 'controller_manager died (SIGKILL)'


def test_sigkill_at_the_first_sample_is_a_reported_fault(tmp_path, truth_stamps, spin_until):
    # A death while the run is still starting (the run's own subscriptions can match
    # after the plant's first samples) is the same reported fault, not a start-up error.
    code, out, err, _ = _run_and_kill(tmp_path, truth_stamps, spin_until, 'controller_manager',
                                      after_s=0.0)
    _assert_fault_reported(code, out, err, 'controller_manager died (SIGKILL)')


def test_sigkill_of_the_recorder_is_reported_and_its_bag_repaired(tmp_path, truth_stamps,
                                                                  spin_until):
    code, out, err, killed_at = _run_and_kill(tmp_path, truth_stamps, spin_until,
                                              'cartpole_recorder')
    result, bag = _assert_fault_reported(code, out, err, 'recorder died (SIGKILL)')
    assert 'truncated MCAP recovered' in err
    truth = sorted({s for s, _ in _read(bag)[TRUTH]})
    # No gap (with one process a node the recorder can miss the plant's very first samples,
    # before their processes have discovered each other: README, "Recording").
    assert all(b - a == 5_000_000 for a, b in zip(truth, truth[1:]))
    # What the recorder had not yet written when it was killed: under one second.
    assert killed_at - truth[-1] < 1_000_000_000
    assert (bag / 'bag_0.mcap.damaged').is_file()


def test_a_raising_callback_in_one_process_is_the_fault(ros_context):
    from cartpole_bringup.graph.graph import Graph, GraphSpec

    graph = Graph(GraphSpec(plant='sim', lockstep=True), ros_context, report=lambda text: None)
    try:
        graph.start()
        graph.run_for(1.0)
        manager = graph.nodes['controller_manager'].manager

        def broken(*args, **kwargs):
            raise RuntimeError('boom')
        manager.update = broken
        graph.run_for(30.0)  # returns at the fault
        assert graph.fault == 'controller_manager raised RuntimeError: boom'
        assert graph.elapsed() < 5.0
    finally:
        graph.close()
    assert graph.monitor.last_force == 0.0  # zero force commanded at the stop


def test_sigkill_of_the_whole_run_loses_under_a_second_after_repair(tmp_path, truth_stamps,
                                                                    spin_until):
    """The whole `cartpole run` killed: only bag_0.mcap is left; `cartpole bag repair` makes it
    readable by rosbags and `cartpole analyze`, missing less than a second."""
    seen, executor = truth_stamps
    proc = subprocess.Popen([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                             '--lockstep', '--duration', '60', '--record', str(tmp_path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert spin_until(executor, lambda: seen and seen[-1] >= 6e9, 120.0), 'no run'
        proc.kill()
        last_seen = seen[-1]
        proc.communicate(timeout=30)
    finally:
        reap(proc)
    (bag,) = tmp_path.glob('*/bag')
    assert not (bag / 'metadata.yaml').exists()
    repaired = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'bag', 'repair',
                               str(bag)], capture_output=True, text=True, timeout=120)
    assert repaired.returncode == 0 and 'recovered' in repaired.stdout, repaired.stderr
    truth = sorted({s for s, _ in _read(bag)[TRUTH]})
    assert truth[0] == 0 and all(b - a == 5_000_000 for a, b in zip(truth, truth[1:]))
    assert last_seen - truth[-1] < 1_000_000_000
    analysed = subprocess.run([sys.executable, '-m', 'cartpole_bringup.cli', 'analyze', str(bag),
                               '--json'], capture_output=True, text=True, timeout=120)
    assert json.loads(analysed.stdout)['catch_time_s'] is not None
