"""Namespaces: `-r __ns:=` moves a node whole, `cartpole run --namespace` a graph whole.

- Every node's endpoints, read through the rclpy graph API: in the root
  namespace the names of always (/joint_states, /cartpole/...); with
  `--ros-args -r __ns:=/rig2` every one of them under /rig2 except ROS's own
  global topics (/rosout, /parameter_events, /clock, /diagnostics).
- Sim time follows the graph's own clock: `-r /clock:=/rig1/clock` reaches
  rclpy's time source, which subscribes /clock itself.
- Two lockstep graphs in rig1 and rig2 on one domain run side by side with
  their own controllers and their own clocks, each bag holds its own topics
  only, the analysis reads a namespaced bag, and a third graph in rig1 is
  refused, naming the namespace and the node found.
"""
from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from cartpole_core.namespaces import (bag_namespace, graph_topic, in_namespace, normalize,
                                         parameters_in_namespace, ros_arguments)

pytestmark = pytest.mark.ros

GLOBAL = frozenset({'/rosout', '/parameter_events', '/clock', '/diagnostics'})
"""ROS's own topics, the same for every node in every namespace."""

# node -> (module, class, parameter overrides, topics it publishes or subscribes and services,
# by their names in the root namespace; the node's private names apart)
NODES = {
    'sim': ('cartpole_sim.sim_node', 'SimNode', {'lockstep': True, 'recorder_window': 10},
            {'/joint_states', '/cartpole/true_state', '/cartpole/plant_reset',
             '/cartpole/command_applied', '/cartpole/force_command',
             '/cartpole/recorder/progress'}, {'/sim/reset'}),
    'ekf': ('cartpole_estimation.ekf_node', 'EkfNode', {},
            {'/cartpole/state', '/cartpole/ekf/health', '/cartpole/plant_reset',
             '/joint_states', '/cartpole/force_command', '/cartpole/force_acting'},
            {'/ekf/reset'}),
    'controller_manager': ('cartpole_control.manager_node', 'ControllerManagerNode', {},
                           {'/cartpole/force_command', '/cartpole/force_acting',
                            '/cartpole/controller_status', '/cartpole/plant_reset',
                            '/cartpole/state',
                            '/cartpole/command_applied', '/joint_states'},
                           {'/controller_manager/restart_swingup'}),
    'recorder': ('cartpole_bringup.graph.recorder', 'RecorderNode', {'lockstep': True},
                 {'/joint_states', '/cartpole/state', '/cartpole/force_command',
                  '/cartpole/force_acting', '/cartpole/true_state', '/cartpole/controller_status',
                  '/cartpole/ekf/health',
                  '/cartpole/hw/health', '/cartpole/recorder/progress'}, set()),
    'viewer': ('cartpole_analysis.viewer.node', 'ViewerNode', {'port': 0},
               {'/cartpole/state', '/cartpole/controller_status', '/joint_states'}, set()),
    # The bridge: only that everything it has moves (its endpoints depend on its state).
    'hw_bridge': ('cartpole_hw.hw_node', 'HwBridgeNode', {}, None, None),
}


def _endpoints(probe, name: str, namespace: str) -> tuple[set[str], set[str]]:
    """(topics, services) of node ``namespace/name`` as the graph API lists them."""
    topics = {t for t, _ in probe.get_publisher_names_and_types_by_node(name, namespace)}
    topics |= {t for t, _ in probe.get_subscriber_names_and_types_by_node(name, namespace)}
    services = {s for s, _ in probe.get_service_names_and_types_by_node(name, namespace)}
    return topics, services


@pytest.mark.parametrize('namespace', ['/', '/rig2'])
def test_every_name_of_every_node_moves_with_its_namespace(ros_context, spin_until, tmp_path,
                                                           namespace):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    probe = Node('_namespace_probe', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    cli_args = ['--ros-args', '-r', f'__ns:={namespace}'] if namespace != '/' else None
    prefix = namespace.rstrip('/') + '/'
    try:
        for name, (module, cls, overrides, topics, services) in NODES.items():
            if name == 'recorder':
                overrides = {**overrides, 'output': str(tmp_path / f'bag_{name}')}
            if name == 'hw_bridge':
                overrides = {'port': str(tmp_path / 'no-such-port')}
            node_class = getattr(importlib.import_module(module), cls)
            node = node_class(context=ros_context, cli_args=cli_args, parameter_overrides=[
                Parameter(k, value=v) for k, v in overrides.items()])
            try:
                assert node.get_namespace() == namespace and node.get_name() == name
                found: dict = {}

                def listed() -> bool:
                    try:
                        found['names'] = _endpoints(probe, name, namespace)
                    except Exception:  # not discovered yet (NodeNameNonExistentError)
                        return False
                    return bool(found['names'][1])
                assert spin_until(executor, listed, 10.0), f'{name} not seen in the graph'
                have_topics, have_services = found['names']
                moved = sorted(n for n in have_topics | have_services
                               if n not in GLOBAL and not n.startswith(prefix))
                assert moved == [], f'{name}: outside {namespace}: {moved}'
                assert any(s == f'{prefix}{name}/get_parameters' for s in have_services)
                if topics is None:
                    continue
                private = prefix + name + '/'
                graph_topics = {t for t in have_topics - GLOBAL if not t.startswith(private)}
                assert graph_topics == {in_namespace(t, normalize(namespace)) for t in topics}, name
                assert {in_namespace(s, normalize(namespace)) for s in services} <= have_services
            finally:
                node.destroy_node()
    finally:
        executor.shutdown(timeout_sec=1.0)
        probe.destroy_node()


def test_sim_time_follows_the_clock_of_the_graph_s_namespace(ros_context, spin_until):
    """rclpy's time source subscribes /clock itself: the graph's remap moves it to /rig1/clock."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from builtin_interfaces.msg import Time
    from rclpy.parameter import Parameter
    from rosgraph_msgs.msg import Clock

    node = Node('timed', context=ros_context, cli_args=['--ros-args', *ros_arguments('/rig1')],
                parameter_overrides=[Parameter('use_sim_time', value=True)])
    other = Node('other_graph', context=ros_context)
    seen_global: list[int] = []
    other.create_subscription(Clock, '/clock', lambda m: seen_global.append(m.clock.sec), 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (node, other):
        executor.add_node(n)
    try:
        assert [s.topic_name for s in node.subscriptions if s.msg_type is Clock] == ['/rig1/clock']
        own = other.create_publisher(Clock, '/rig1/clock', 10)
        shared = other.create_publisher(Clock, '/clock', 10)

        def published() -> bool:
            shared.publish(Clock(clock=Time(sec=100)))
            own.publish(Clock(clock=Time(sec=7)))
            return seen_global != [] and node.get_clock().now().nanoseconds == 7 * 10**9
        assert spin_until(executor, published, 10.0)
        assert node.get_clock().now().nanoseconds == 7 * 10**9  # never the other graph's 100 s
    finally:
        executor.shutdown(timeout_sec=1.0)
        for n in (node, other):
            n.destroy_node()


def test_a_bag_reads_by_its_root_names_whatever_its_namespace():
    assert normalize('rig2') == normalize('/rig2/') == '/rig2' and normalize('') == '/'
    with pytest.raises(ValueError, match="'2x'"):
        normalize('lab/2x')
    assert ros_arguments('/') == []
    assert graph_topic('/rig2/clock', '/rig2') == '/clock'
    assert graph_topic('/rig20/joint_states', '/rig2') == '/rig20/joint_states'
    topics = ['/lab/rig2/clock', '/lab/rig2/joint_states']
    assert bag_namespace({}, topics) == '/lab/rig2'          # recorded with ros2 bag record
    assert bag_namespace({'namespace': '/rig2'}, []) == '/rig2'
    assert bag_namespace({}, ['/joint_states', '/x/joint_states']) == '/'


def test_a_parameters_file_gives_each_node_its_section_in_the_namespace():
    """rcl matches a section by the node's full name: `cartpole run --namespace` moves the
    sections of the graph's nodes along (else `controller_manager:` would miss
    /rig2/controller_manager)."""
    data = {'controller_manager': {'ros__parameters': {'x_ref': 0.3}},
            '/ekf': {'ros__parameters': {'q_x': 1.0}}, '/**': {'ros__parameters': {}},
            'other': {'ros__parameters': {}}}
    moved = parameters_in_namespace(data, '/rig2', ['controller_manager', 'ekf'])
    assert moved == {'/rig2/controller_manager': data['controller_manager'],
                     '/rig2/ekf': data['/ekf'], '/**': data['/**'], 'other': data['other']}
    assert parameters_in_namespace(data, '/', ['controller_manager']) == {
        '/controller_manager': data['controller_manager'], '/ekf': data['/ekf'],
        '/**': data['/**'], 'other': data['other']}


def _run(namespace: str, stabilizer: str, record: Path, duration: float,
         *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--lockstep',
         '--duration', f'{duration:g}', '--namespace', namespace, '--stabilizer', stabilizer,
         '--record', str(record), '--json', *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _claimed(namespace: str, proc: subprocess.Popen) -> bool:
    """Whether ``proc`` holds its graph's lock in ``namespace``: the ``cartpole_run`` role's
    lock file (cartpole_core.domain_guard) names its PID."""
    from cartpole_bringup.graph.run_monitor import NODE_NAME
    from cartpole_core.domain_guard import _lock_path, domain_id
    path = _lock_path(domain_id(), normalize(namespace), NODE_NAME)
    return path.is_file() and f'(PID {proc.pid}:' in path.read_text(errors='replace')


def test_two_graphs_in_two_namespaces_share_a_domain(ros_context, spin_until, tmp_path):
    """rig1 (smc) and rig2 (pid, x* = 0.3 m from a parameters file), lockstep, at once on one
    domain: both succeed, each bag holds its own topics (its own clock too), and a third
    graph in rig1 is refused."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from cartpole_analysis.analysis.analyze import analyze_bag
    from cartpole_bringup.graph.graph import DuplicateNodeError, Graph, GraphSpec
    from cartpole_core.child_process import interrupt

    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'controller_manager': {'ros__parameters': {'x_ref': 0.3}}}))
    runs = {'rig1': _run('rig1', 'smc', tmp_path / 'rig1', 14.0),
            'rig2': _run('rig2', 'pid', tmp_path / 'rig2', 14.0, '--params', str(params))}
    probe = Node('_rig_probe', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    results = {}
    try:
        # rig1 runs once it holds its namespace's locks (their files name its PID): what
        # refuses the third graph below, and seen on this machine without DDS discovery.
        started = spin_until(executor, lambda: _claimed('rig1', runs['rig1'])
                             or runs['rig1'].poll() is not None, 60.0)
        if not started or runs['rig1'].poll() is not None:  # say why, in the runs' own words
            ended = {name: proc.poll() for name, proc in runs.items()}
            for proc in runs.values():
                interrupt(proc, 10.0, drain=False)
            pytest.fail(f'rig1 did not claim /rig1 (exit codes: {ended}); ' + '; '.join(
                f'{name}: {proc.stderr.read()[-1500:]!r}' for name, proc in runs.items()))
        # The third graph is started here, in this process (what `cartpole run` does once
        # it has imported; as a process it could come too late for a lockstep run of a
        # few wall seconds): refused, with the line `cartpole run` prints.
        with pytest.raises(DuplicateNodeError) as refused:
            Graph(GraphSpec(plant='sim', lockstep=True, namespace='rig1'), ros_context)
        assert runs['rig1'].poll() is None, 'rig1 ended before the third graph was tried'
        line = str(refused.value)
        assert '\n' not in line and 'another graph runs in namespace /rig1 ' in line
        assert 'node /rig1/cartpole_run (PID ' in line and '--namespace NAME' in line
        Graph(GraphSpec(plant='sim', lockstep=True, namespace='rig3'), ros_context).close()
        for name, proc in runs.items():
            out, err = proc.communicate(timeout=300)
            assert proc.returncode == 0, f'{name}: {err[-2000:]}'
            results[name] = json.loads(out)
    finally:
        for proc in runs.values():
            if proc.poll() is None:
                interrupt(proc, 10.0)
        executor.shutdown(timeout_sec=1.0)
        probe.destroy_node()
    for name, stabilizer, x_ref in (('rig1', 'smc', 0.3845), ('rig2', 'pid', 0.3)):
        summary = results[name]
        assert summary['success'] is True and summary['fault'] is None, (name, summary)
        assert summary['stabilizer'] == stabilizer
        assert [c['name'] for c in summary['controllers'] if c['kind'] == 'stabilizer'] == \
            [stabilizer]
        bag = Path(summary['bag'])
        analysis = analyze_bag(bag)  # the analysis of a bag recorded in a namespace
        assert analysis.summary['success'] is True and analysis.source == '/cartpole/true_state'
        assert abs(analysis.series.x[-1] - x_ref) < 0.02  # the manager of its namespace took x*
        assert {'/clock', '/joint_states', '/cartpole/force_command'} <= set(analysis.topics)
        info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        recorded = {t['topic_metadata']['name'] for t in info['topics_with_message_count']}
        assert recorded and all(t.startswith(f'/{name}/') for t in recorded), recorded
        assert f'/{name}/clock' in recorded and f'/{name}/joint_states' in recorded
        assert info['custom_data']['namespace'] == f'/{name}'
