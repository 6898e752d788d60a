"""Loop latency of the real node graph against the bare rclpy floor (``cartpole bench loop``).

The graph (``cartpole run --sim`` in real time, one process or one process a node)
and its floor (a chain of the same shape with no computation, ``source`` ->
``relay`` -> ``relay``, spun the way the graph is spun: the same executor in one
process, rclpy's SingleThreadedExecutor a node with ``processes``) are measured
alike by :mod:`.loop_probe`: latency = receipt of each force command - the stamp of
the sample it was computed from, missed and late cycles, CPU per process. The
ratio graph / floor isolates what our nodes add to what rclpy and DDS cost on this
machine; :mod:`.loop_view` adds the live view's cost. docs/realtime.md,
"Benchmarks", describes the method; ``python -m cartpole_tools.bench.loop`` runs
the floor's nodes.
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from cartpole_core.middleware import keep_on_this_host

from . import loop_view
from .loop_probe import SAMPLE_TIME, WARMUP_S, graph_cmds, graph_labels, measure

EXECUTORS = {'single': ('events', 'single'), 'processes': ('single',)}
"""Executors measured per mode (one process: either, ``cartpole run --executor``;
one process a node: node_runner.run_node's SingleThreadedExecutor)."""
BARE_ROLES = ('source', 'relay1', 'relay2')
"""The floor's chain."""
SPIN_TIMEOUT = {'single': 0.05, 'processes': 0.1}
"""spin_once timeout of the floor: Graph.spin_until's and run_node's."""


def _bare_cmds(mode: str, executor: str) -> list[list[str]]:
    me = [sys.executable, '-m', 'cartpole_tools.bench.loop', '--executor', executor,
          '--spin-timeout', repr(SPIN_TIMEOUT[mode])]
    if mode == 'processes':
        return [me + ['--node', role] for role in BARE_ROLES]
    return [me + [arg for role in BARE_ROLES for arg in ('--node', role)]]


def _ratio(graph: dict[str, Any], bare: dict[str, Any], key: str) -> float | None:
    return graph[key] / bare[key] if graph[key] and bare[key] else None


def run_loop_benchmark(duration: float = 60.0, modes=('single', 'processes'),
                       executors=('events', 'single'), view_rounds: int = 0,
                       warmup: float = WARMUP_S) -> dict[str, Any]:
    """Measure graph and floor for each mode and executor; results and a markdown table.

    ``results[mode][executor]`` holds ``graph``, ``bare`` (the floor) and the
    ``p50_ratio`` / ``p99_ratio`` graph / floor; ``executors`` filters
    :data:`EXECUTORS` (one process a node always runs ``single``). With
    ``view_rounds``, each mode's first executor (``events`` by default, what
    ``cartpole run`` spins) also holds ``view_rounds`` (the pairs without and
    with the viewer) and their median ``p99_ratio_view``
    (:func:`cartpole_tools.bench.loop_view.view_rounds`). Each measurement starts
    ``warmup`` s after the first command arrived (discovery, caches, first plots).
    """
    env_note = keep_on_this_host()
    results: dict[str, Any] = {'discovery_range': env_note}
    runs = [(mode, ex) for mode in modes for ex in EXECUTORS[mode]
            if ex in executors or mode == 'processes']
    for mode, ex in runs:
        graph = measure(graph_cmds(mode, duration, ex), '/joint_states',
                         '/cartpole/force_command', duration, graph_labels(mode), warmup)
        bare = measure(_bare_cmds(mode, ex), '/bench/source', '/bench/relay2', duration,
                        list(BARE_ROLES) if mode == 'processes' else ['floor'], warmup)
        results.setdefault(mode, {})[ex] = {
            'graph': graph, 'bare': bare, 'p50_ratio': _ratio(graph, bare, 'p50_ms'),
            'p99_ratio': _ratio(graph, bare, 'p99_ms')}
        if view_rounds and ex == next(e for m, e in runs if m == mode):
            results[mode][ex].update(loop_view.view_rounds(mode, ex, duration, view_rounds,
                                                           warmup))
    markdown = _markdown(results, runs, duration, warmup)
    if view_rounds:
        markdown += loop_view.markdown(results, runs, duration)
    return {'results': results, 'markdown': markdown}


def _markdown(results: dict[str, Any], runs: list[tuple[str, str]], duration: float,
              warmup: float) -> str:
    md = [f'Real-time graph, {duration:g} s measured per row after {warmup:g} s warm-up; latency = receipt of '
          'the force command - stamp of the sample it was computed from. The floor is the same '
          'chain shape (source -> relay -> relay) with no computation, on the same executor, '
          'spun the same way. CPU: each process alone (utime + stime), per node with one '
          'process a node.\n',
          '| mode | executor | path | p50 [ms] | p99 [ms] | max [ms] | samples | missed cycles '
          '| late cycles | unanswered samples | CPU [%] |', '|' + '---|' * 11]
    for mode, ex in runs:
        r = results[mode][ex]
        for path in ('graph', 'bare'):
            m = r[path]
            cpu = ', '.join(f'{name} {"-" if c is None else f"{c:.0f}"}'
                            for name, c in m['cpu_percent'].items())
            md.append(f'| {mode} | {ex} | {"our graph" if path == "graph" else "bare rclpy floor"} '
                      f'| {m["p50_ms"]:.3f} | {m["p99_ms"]:.3f} | {m["max_ms"]:.3f} | '
                      f'{m["samples"]} | {m["missed_cycles"]} | {m["late_cycles"]} | '
                      f'{m["unanswered_samples"]} | {cpu} |')
        ratios = ' / '.join('-' if r[k] is None else f'{r[k]:.2f}' for k in ('p50_ratio', 'p99_ratio'))
        md.append(f'| {mode} | {ex} | ratio graph / floor, p50 / p99 | {ratios} | | | | | | | |')
    return '\n'.join(md) + '\n'


# -- the bare chain's nodes ------------------------------------------------------------
def _bare_main(roles: list[str], executor_kind: str, spin_timeout: float) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    from cartpole_bringup.graph.graph import make_executor

    rclpy.init()
    qos = QoSProfile(depth=10)
    nodes = []
    for role in roles:
        node = rclpy.create_node(f'bench_{role}')
        nodes.append(node)
        if role == 'source':
            pub = node.create_publisher(JointState, '/bench/source', qos)

            def tick(pub=pub, node=node):
                msg = JointState()
                msg.header.stamp = node.get_clock().now().to_msg()
                msg.name = ['cart', 'pendulum']
                msg.position = [0.0, 3.14159]
                pub.publish(msg)
            node.create_timer(SAMPLE_TIME, tick)
        else:
            src = '/bench/source' if role == 'relay1' else '/bench/relay1'
            pub = node.create_publisher(JointState, f'/bench/{role}', qos)
            node.create_subscription(JointState, src, lambda m, pub=pub: pub.publish(m), qos)
    executor = make_executor(executor_kind, rclpy.get_default_context())
    for n in nodes:
        executor.add_node(n)
    try:
        while rclpy.ok():  # as Graph.spin_until and node_runner.run_node spin
            executor.spin_once(timeout_sec=spin_timeout)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description='bare rclpy chain for the loop benchmark')
    parser.add_argument('--node', action='append', choices=BARE_ROLES, required=True)
    parser.add_argument('--executor', choices=EXECUTORS['single'], default='single')
    parser.add_argument('--spin-timeout', type=float, default=SPIN_TIMEOUT['single'])
    cli = parser.parse_args()
    sys.exit(_bare_main(cli.node, cli.executor, cli.spin_timeout))
