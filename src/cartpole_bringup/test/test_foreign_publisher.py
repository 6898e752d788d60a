"""A foreign node cannot knock the pendulum over: while ``cartpole run --sim`` balances in
real time, a publisher in another process (a node of someone else's on the same domain)
sends every kind of bad message on ``joint_states``, ``cartpole/force_command`` and
``cartpole/state``; the run still succeeds, and the nodes that dropped the messages say
so on ``/diagnostics`` (WARN, ``refused_inputs``, ``foreign_publishers``)."""
import json
import os
import subprocess
import sys
import time

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

INTRUDER = r'''
import math, sys, time
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState

rclpy.init()
node = Node('intruder')
topics = ('joint_states', 'cartpole/force_command', 'cartpole/state')
pubs = {t: node.create_publisher(JointState, t, 10) for t in topics}
# every subscriber of the graph matched (their counts in argv), not only the first one
expected = dict(zip(topics, (int(n) for n in sys.argv[2:5])))
deadline = time.monotonic() + 20.0
while time.monotonic() < deadline and not all(
        pubs[t].get_subscription_count() >= max(expected[t], 1) for t in topics):
    rclpy.spin_once(node, timeout_sec=0.05)
print('ready', flush=True)
sys.stdin.readline()   # go: the pendulum balances


def joints(names, position=(), velocity=(), effort=(), zero_stamp=False):
    msg = JointState()
    if not zero_stamp:
        msg.header.stamp = node.get_clock().now().to_msg()
    msg.name, msg.position = list(names), [float(v) for v in position]
    msg.velocity, msg.effort = [float(v) for v in velocity], [float(v) for v in effort]
    return msg


nan, inf = math.nan, math.inf
both = ('cart', 'pendulum')
bad = {
    'joint_states': [joints(both, (nan, 3.1)), joints(both, (0.4, inf)), joints(both, (1e308, 3.1)),
                     joints(both, (0.4, 1e308)), joints(('cart', 'pole'), (0.4, 3.1)), joints((), ()),
                     joints(both, (0.4,)), joints(both, (0.4, 3.1), zero_stamp=True)],
    'cartpole/force_command': [joints(('cart',), effort=(nan,)), joints(('cart',), effort=(inf,)),
                               joints(('cart',), effort=(1e308,)),
                               joints(('pendulum',), effort=(5.0,)), joints((), effort=(5.0,)),
                               joints(('cart',), effort=(5.0, 5.0)),
                               joints(('cart',), effort=(30.0,), zero_stamp=True)],
    'cartpole/state': [joints(both, (0.4, nan), (0.0, 0.0)), joints(both, (0.4, 0.0), (inf, 0.0)),
                       joints(both, (0.4, 0.0), (50.0, 0.0)),
                       joints(both, (1e308, 0.0), (0.0, 0.0)), joints(('x', 'y'), (0.4, 0.0), (0, 0)),
                       joints(both, (0.4, 0.0)), joints(both, (0.4, 0.0), (0.0, 0.0), zero_stamp=True)],
}
sent = 0
for _ in range(int(sys.argv[1])):
    for topic, messages in bad.items():
        for msg in messages:
            pubs[topic].publish(msg)
            sent += 1
            rclpy.spin_once(node, timeout_sec=0.02)
time.sleep(2.0)       # stay in the graph a while: the nodes name us on /diagnostics
print(sent, min(p.get_subscription_count() for p in pubs.values()), flush=True)
node.destroy_node()
rclpy.shutdown()
'''

ROUNDS = 3


def test_a_foreign_node_s_bad_messages_are_dropped_while_the_pendulum_balances(
        ros_context, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    run = subprocess.Popen([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                            '--duration', '20', '--json'],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env=dict(os.environ))
    probe = Node('_foreign_test_probe', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    reports: dict[str, list] = {}

    def on_diagnostics(msg):
        for status in msg.status:
            reports.setdefault(status.name, []).append(
                (status.level, status.message, {kv.key: kv.value for kv in status.values}))

    probe.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
    intruder = None
    try:
        def balancing():
            control = reports.get('controller_manager: control', [])
            return bool(control) and control[-1][2].get('mode') == 'stabilizing'
        if not spin_until(executor, balancing, 60.0):
            run.kill()
            pytest.fail(f'the run does not balance: {run.communicate()[1][-3000:]}')
        # Started once the graph balances: a publisher on the graph's topics before the run
        # has claimed its namespace is another graph to the run's duplicate check, which
        # then refuses to start (as it should).
        subscribers = [str(probe.count_subscribers('/' + t))
                       for t in ('joint_states', 'cartpole/force_command', 'cartpole/state')]
        intruder = subprocess.Popen([sys.executable, '-c', INTRUDER, str(ROUNDS), *subscribers],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
        assert intruder.stdout.readline().strip() == 'ready', intruder.stderr.read()
        intruder.stdin.write('go\n')
        intruder.stdin.flush()
        deadline = time.monotonic() + 60.0
        while intruder.poll() is None and time.monotonic() < deadline:
            spin_until(executor, lambda: False, 0.2)
        out, err = intruder.communicate(timeout=10)
        assert intruder.returncode == 0, err
        sent, subscribed = (int(word) for word in out.split()[-2:])
        assert sent == ROUNDS * 22 and subscribed > 0, out
        spin_until(executor, lambda: False, 2.5)     # one more report of every node
        summary_text, run_err = run.communicate(timeout=90)
    finally:
        if intruder is not None and intruder.poll() is None:
            intruder.kill()
        if run.poll() is None:
            run.kill()
        executor.shutdown()
        probe.destroy_node()
    summary = json.loads(summary_text)
    assert run.returncode == 0, (summary, run_err[-2000:])
    assert summary['success'] is True and summary['fault'] is None, summary
    # Who takes what: the EKF joint_states (8 kinds) and force commands (7), the manager
    # joint_states (8) and states (7), the simulator force commands (7).
    expected = {'ekf: estimation': 15 * ROUNDS, 'controller_manager: control': 15 * ROUNDS,
                'sim: simulation': 7 * ROUNDS}
    for name, count in expected.items():
        level, message, values = reports[name][-1]
        assert int(values['refused_inputs']) == count, (name, values)
        assert level == b'\x01' and 'dropped' in message, (name, level, message)   # WARN
        named = [r[2].get('foreign_publishers', '') for r in reports[name]]
        assert any('/intruder' in text for text in named), (name, named)
    ekf = reports['ekf: estimation'][-1][2]
    for reason in ('non_finite', 'cart_range', 'pendulum_range', 'joint_names',
                   'array_length', 'zero_stamp', 'effort_range'):
        assert int(ekf[f'refused_inputs.{reason}']) > 0, (reason, ekf)
    control = reports['controller_manager: control'][-1][2]
    assert int(control['refused_inputs.velocity_range']) == ROUNDS, control
    assert control['mode'] == 'stabilizing', control
