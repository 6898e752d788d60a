"""Loop latency of the real node graph against the bare rclpy floor
(docs/realtime.md, "Benchmarks").

What is measured, the same way for the graph and for its floor:

- the graph: ``cartpole run --sim`` in real time (one process, or one process a
  node with ``--processes``); the simulator stamps each ``/joint_states``
  sample with its clock at publication; the EKF and the controller manager copy
  that stamp to ``/cartpole/state`` and ``/cartpole/force_command``. A probe
  node in this process receives the force commands: latency = receipt time -
  stamp, i.e. sample -> EKF -> controller -> command, plus one delivery to the
  probe.
- the floor: a chain of the same shape with no computation, ``source`` (a
  200 Hz timer publishing stamped JointState) -> ``relay`` -> ``relay``, in one
  process or in three, measured by the same probe, **spun the way the graph is
  spun**: in one process by the same executor (:func:`cartpole_bringup.graph.graph.make_executor`,
  ``spin_once`` every 0.05 s as :class:`~cartpole_bringup.graph.graph.Graph` does), one
  process a node by rclpy's SingleThreadedExecutor as every node's ``main``
  (:func:`cartpole_core.node_runner.run_node`). The ratio of the two isolates
  what our nodes add to what rclpy and DDS cost on this machine.

Executors (:data:`EXECUTORS`): the one-process graph runs on the C++
EventsExecutor by default (``cartpole run --executor events``) or on rclpy's
SingleThreadedExecutor; both are measured, each against its own floor. With
one process a node every node spins a SingleThreadedExecutor.

With ``view_rounds=N`` (``cartpole bench loop --view N``) each run also
gets N alternating pairs: the graph alone, then the graph with its live view
(``cartpole run --sim --view``) and a Foxglove WebSocket client subscribed to
every viewer channel, the load a user watching the run puts on it
(:mod:`cartpole_tools.bench.loop_view`).

Missed cycles: samples (stamps on ``/joint_states``) more than 1.5 Ts after
the previous one, and samples for which no command arrived. CPU: user +
system time of each process from /proc over the run (``utime + stime``, not
the children's), per node with one process a node (the graph's nodes are the
children of ``cartpole run``, named by their executable).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

SAMPLE_TIME = 0.005

EXECUTORS = {'single': ('events', 'single'), 'processes': ('single',)}
"""Executors measured per mode (one process: either, ``cartpole run --executor``;
one process a node: node_runner.run_node's SingleThreadedExecutor)."""
BARE_ROLES = ('source', 'relay1', 'relay2')
"""The floor's chain."""
SPIN_TIMEOUT = {'single': 0.05, 'processes': 0.1}
"""spin_once timeout of the floor: Graph.spin_until's and run_node's."""
WARMUP_S = 3.0
"""Default wait after the first command before a measurement starts [s]."""


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def _stat_fields(pid: int) -> list[str] | None:
    """/proc/<pid>/stat from field 3 (state) on, or None if the process is gone."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None


def _cpu_seconds(pid: int) -> float | None:
    """CPU time of this process alone: utime + stime (fields 14, 15) [s]."""
    fields = _stat_fields(pid)
    if fields is None:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def _process_name(pid: int, default: str) -> str:
    """The graph node a process runs (its executable's name, as in graph.NODES), else ``default``."""
    from cartpole_bringup.graph.graph import NODES
    try:
        argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
    except OSError:
        return default
    names = {exe: name for name, (_, exe, _, _) in NODES.items()}
    names.setdefault('cartpole_viewer', 'viewer')  # cartpole run --view's viewer process
    for arg in argv[:2]:
        base = os.path.basename(arg.decode(errors='replace'))
        if base in names:
            return names[base]
    return default


def _children(pid: int) -> list[int]:
    """Direct children of ``pid`` (scanning /proc for their parent PID)."""
    out = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            fields = _stat_fields(int(entry.name))
            if fields is not None and int(fields[1]) == pid:
                out.append(int(entry.name))
    return sorted(out)


class _Probe:
    """Receives samples and commands; records latency = receipt (system clock) - stamp.

    It stands in for the command's real consumer (the simulator or the bridge,
    which run at the loop's real-time priority), so once its threads exist it
    takes that priority too (:func:`cartpole_core.realtime.enter_loop`, the
    ``CARTPOLE_REALTIME`` setting): at normal priority its receipt times held
    its own wait behind any other process on the machine (a viewer client),
    which is not the loop's latency.
    """

    def __init__(self, sample_topic: str, command_topic: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile
        from sensor_msgs.msg import JointState

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('latency_probe', context=self.context)
        qos = QoSProfile(depth=100)
        self.sample_stamps: list[float] = []
        self.latencies: list[tuple[float, float]] = []
        self.node.create_subscription(JointState, sample_topic, self._on_sample, qos)
        self.node.create_subscription(JointState, command_topic, self._on_command, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._recording = False
        self._thread.start()
        from cartpole_core.realtime import enter_loop
        self.hygiene = enter_loop(log=lambda text: None,
                                  warn=lambda text: print(f'latency probe: {text}',
                                                          file=sys.stderr),
                                  what='latency probe')

    def _spin(self) -> None:
        while self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def _on_sample(self, msg) -> None:
        if self._recording:
            self.sample_stamps.append(_stamp_s(msg.header.stamp))

    def _on_command(self, msg) -> None:
        now = time.time()
        if self._recording:
            self.latencies.append((_stamp_s(msg.header.stamp), now - _stamp_s(msg.header.stamp)))

    def record(self, seconds: float) -> None:
        self._recording = True
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(min(0.2, max(0.0, end - time.monotonic())))
        self._recording = False

    def wait_for_traffic(self, timeout: float) -> bool:
        self._recording = True
        end = time.monotonic() + timeout
        while time.monotonic() < end and not self.latencies:
            time.sleep(0.05)
        ok = bool(self.latencies)
        self._recording = False
        self.sample_stamps.clear()
        self.latencies.clear()
        return ok

    def close(self) -> None:
        import rclpy
        self.hygiene.leave()
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=2.0)


def _stats(probe: _Probe) -> dict[str, Any]:
    lat = np.array([v for _, v in probe.latencies]) * 1e3
    stamps = np.array(sorted(set(probe.sample_stamps)))
    gaps = np.diff(stamps) if stamps.size > 1 else np.array([])
    answered = {s for s, _ in probe.latencies}
    unanswered = sum(1 for s in stamps[:-2] if s not in answered)
    return {
        'samples': int(stamps.size), 'commands': int(lat.size),
        'p50_ms': float(np.percentile(lat, 50)) if lat.size else None,
        'p99_ms': float(np.percentile(lat, 99)) if lat.size else None,
        'max_ms': float(lat.max()) if lat.size else None,
        'late_cycles': int(np.sum(gaps > 1.5 * SAMPLE_TIME)),
        'missed_cycles': int(np.sum(np.maximum(np.round(gaps / SAMPLE_TIME) - 1, 0))),
        'unanswered_samples': int(unanswered),
    }


def _start(cmd: list[str]) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def _cpu_by_process(procs: list[subprocess.Popen], labels: list[str]) -> dict[str, int]:
    """The processes to account CPU to: each started one (named by ``labels``) and, for
    a graph started with one process a node, its node processes (by node name). Name -> PID."""
    out: dict[str, int] = {}
    for p, label in zip(procs, labels):
        out[label] = p.pid
        for child in _children(p.pid):
            out[_process_name(child, f'child {child}')] = child
    return out


def _measure(cmds: list[list[str]], sample_topic: str, command_topic: str,
             duration: float, labels: list[str], warmup: float = WARMUP_S,
             viewer_url: str | None = None) -> dict[str, Any]:
    """Latency and CPU of the started processes; with ``viewer_url`` a Foxglove WebSocket
    client (its own process: no GIL shared with the probe) is subscribed to the viewer
    throughout, and ``viewer_messages`` counts what it received per channel."""
    probe = _Probe(sample_topic, command_topic)
    procs = [_start(c) for c in cmds]
    client = None
    try:
        if not probe.wait_for_traffic(timeout=60.0):
            errors = b''.join(p.stderr.read() if p.poll() is not None else b'' for p in procs)
            raise RuntimeError(f'no traffic on {command_topic}: {errors.decode(errors="replace")[-2000:]}')
        if viewer_url is not None:
            client = _start_viewer_client(viewer_url)
        probe.record(warmup)
        probe.sample_stamps.clear()
        probe.latencies.clear()
        pids = _cpu_by_process(procs, labels)
        cpu0 = {name: _cpu_seconds(pid) for name, pid in pids.items()}
        t0 = time.monotonic()
        probe.record(duration)
        elapsed = time.monotonic() - t0
        cpu1 = {name: _cpu_seconds(pid) for name, pid in pids.items()}
        stats = _stats(probe)
        stats['cpu_percent'] = {
            name: None if cpu0[name] is None or cpu1[name] is None
            else 100.0 * (cpu1[name] - cpu0[name]) / elapsed for name in pids}
        if client is not None:
            client.send_signal(signal.SIGINT)
            out, _ = client.communicate(timeout=30)
            stats['viewer_messages'] = json.loads(out.strip().splitlines()[-1])
        return stats
    finally:
        if client is not None and client.poll() is None:
            client.kill()
            client.communicate()
        _stop(procs)
        probe.close()


def _start_viewer_client(url: str) -> subprocess.Popen:
    """``python -m cartpole_analysis.viewer.client URL``, started and subscribed."""
    client = subprocess.Popen([sys.executable, '-m', 'cartpole_analysis.viewer.client', url],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)
    if 'subscribed' not in client.stderr.readline():
        client.kill()
        raise RuntimeError(f'the viewer client did not subscribe: {client.communicate()[1][-1000:]}')
    return client


def _graph_cmds(mode: str, duration: float, executor: str,
                view_port: int | None = None) -> list[list[str]]:
    cmd = [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration',
           str(duration + 60.0), '--executor', executor]
    if mode == 'processes':
        cmd.append('--processes')
    if view_port is not None:
        cmd += ['--view', f'127.0.0.1:{view_port}']
    return [cmd]


def _graph_labels(mode: str) -> list[str]:
    return ['cartpole run (monitor)' if mode == 'processes' else 'cartpole run']


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
    from . import loop_view

    env_note = os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    results: dict[str, Any] = {'discovery_range': env_note}
    runs = [(mode, ex) for mode in modes for ex in EXECUTORS[mode]
            if ex in executors or mode == 'processes']
    for mode, ex in runs:
        graph = _measure(_graph_cmds(mode, duration, ex), '/joint_states',
                         '/cartpole/force_command', duration, _graph_labels(mode), warmup)
        bare = _measure(_bare_cmds(mode, ex), '/bench/source', '/bench/relay2', duration,
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
