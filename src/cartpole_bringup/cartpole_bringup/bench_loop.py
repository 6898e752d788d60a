"""Loop latency of the real node graph against the bare rclpy floor (SPEC section 6).

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
  process or in three, measured by the same probe. The ratio of the two
  isolates what our nodes add to what rclpy and DDS cost on this machine.

With ``view_rounds=N`` (``cartpole bench loop --view N``) each mode also
runs N alternating pairs: the graph alone, then the graph with its live
viewer (``cartpole run --sim --view``, the ``viewer`` node in its own
process) and a Foxglove WebSocket client subscribed to every viewer channel
(``python -m cartpole_bringup.viewer_client``, its own process), the load a
user watching the run puts on it. Pairs measured back to back see about the same
machine; the median of their p99 ratios is the viewer's cost to the loop.

Missed cycles: samples (stamps on ``/joint_states``) more than 1.5 Ts after
the previous one, and samples for which no command arrived. CPU: user + system
time of each process from /proc over the run.
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


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


def _cpu_seconds(pid: int) -> float | None:
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    ticks = os.sysconf('SC_CLK_TCK')
    return (int(fields[11]) + int(fields[12]) + int(fields[13]) + int(fields[14])) / ticks


class _Probe:
    """Receives samples and commands; records latency = receipt (system clock) - stamp."""

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


def _measure(cmds: list[list[str]], sample_topic: str, command_topic: str, duration: float,
             warmup: float = 3.0, viewer_url: str | None = None) -> dict[str, Any]:
    probe = _Probe(sample_topic, command_topic)
    procs = [_start(c) for c in cmds]
    client = None
    try:
        if not probe.wait_for_traffic(timeout=60.0):
            errors = b''.join(p.stderr.read() if p.poll() is not None else b'' for p in procs)
            raise RuntimeError(f'no traffic on {command_topic}: {errors.decode(errors="replace")[-2000:]}')
        if viewer_url is not None:  # its own process: no GIL shared with the probe
            client = subprocess.Popen(
                [sys.executable, '-m', 'cartpole_bringup.viewer_client', viewer_url],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                start_new_session=True)
            if 'subscribed' not in client.stderr.readline():
                client.kill()
                raise RuntimeError(f'the viewer client did not subscribe: '
                                   f'{client.communicate()[1][-1000:]}')
        probe.record(warmup)
        probe.sample_stamps.clear()
        probe.latencies.clear()
        cpu0 = [_cpu_seconds(p.pid) for p in procs]
        t0 = time.monotonic()
        probe.record(duration)
        elapsed = time.monotonic() - t0
        cpu1 = [_cpu_seconds(p.pid) for p in procs]
        stats = _stats(probe)
        stats['cpu_percent'] = [None if a is None or b is None else 100.0 * (b - a) / elapsed
                                for a, b in zip(cpu0, cpu1)]
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


def _graph_cmds(mode: str, duration: float, view_port: int | None = None) -> list[list[str]]:
    cmd = [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration',
           str(duration + 60.0)]
    if mode == 'processes':
        cmd.append('--processes')
    if view_port is not None:
        cmd += ['--view', f'127.0.0.1:{view_port}']
    return [cmd]


def _free_port() -> int:
    """A TCP port that is free now (for the viewer of the run to bind)."""
    import socket
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def _bare_cmds(mode: str) -> list[list[str]]:
    me = [sys.executable, '-m', 'cartpole_bringup.bench_loop']
    if mode == 'processes':
        return [me + ['--node', 'source'], me + ['--node', 'relay1'], me + ['--node', 'relay2']]
    return [me + ['--node', 'source', '--node', 'relay1', '--node', 'relay2']]


def _view_rounds(mode: str, duration: float, rounds: int) -> list[dict[str, Any]]:
    """Alternating pairs on the same machine state: the graph alone, then with its viewer
    and a client attached (``cartpole run --sim --view``)."""
    out = []
    for _ in range(rounds):
        alone = _measure(_graph_cmds(mode, duration), '/joint_states', '/cartpole/force_command',
                         duration)
        port = _free_port()
        viewed = _measure(_graph_cmds(mode, duration, port), '/joint_states',
                          '/cartpole/force_command', duration,
                          viewer_url=f'ws://127.0.0.1:{port}')
        out.append({'graph': alone, 'graph_view': viewed,
                    'p99_ratio': (viewed['p99_ms'] / alone['p99_ms'])
                    if viewed['p99_ms'] and alone['p99_ms'] else None})
    return out


def _view_markdown(results: dict[str, Any], modes, duration: float) -> list[str]:
    md = [f'\nThe viewer\'s cost: alternating pairs of {duration:g} s runs, the graph alone, '
          'then the graph with `--view` (the viewer node in its own process, `nice` +10) and a '
          'Foxglove WebSocket client subscribed to every viewer channel.\n',
          '| mode | round | p99 alone [ms] | p99 with viewer [ms] | ratio | p50 alone / with '
          '[ms] | missed cycles alone / with | CPU of the graph alone / with [%] |',
          '|' + '---|' * 8]
    for mode in modes:
        rounds = results[mode].get('view_rounds')
        if not rounds:
            continue
        for k, r in enumerate(rounds, 1):
            a, v = r['graph'], r['graph_view']
            ratio = '-' if r['p99_ratio'] is None else f'{r["p99_ratio"]:.2f}'
            md.append(f'| {mode} | {k} | {a["p99_ms"]:.3f} | {v["p99_ms"]:.3f} | {ratio} | '
                      f'{a["p50_ms"]:.3f} / {v["p50_ms"]:.3f} | {a["missed_cycles"]} / '
                      f'{v["missed_cycles"]} | {a["cpu_percent"][0]:.0f} / '
                      f'{v["cpu_percent"][0]:.0f} |')
        ratio = results[mode]['p99_ratio_view']
        md.append(f'| {mode} | median ratio | | | {"-" if ratio is None else f"{ratio:.2f}"} '
                  '| | | |')
    return md


def run_loop_benchmark(duration: float = 60.0, modes=('single', 'processes'),
                       view_rounds: int = 0) -> dict[str, Any]:
    """Measure graph and floor in each mode (and, with ``view_rounds``, the graph with and
    without its viewer in alternating pairs); returns results and a markdown table."""
    env_note = os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    results: dict[str, Any] = {'discovery_range': env_note}
    for mode in modes:
        results[mode] = {
            'graph': _measure(_graph_cmds(mode, duration), '/joint_states', '/cartpole/force_command',
                              duration),
            'bare': _measure(_bare_cmds(mode), '/bench/source', '/bench/relay2', duration),
        }
        if view_rounds:
            rounds = _view_rounds(mode, duration, view_rounds)
            ratios = [r['p99_ratio'] for r in rounds if r['p99_ratio'] is not None]
            results[mode]['view_rounds'] = rounds
            results[mode]['p99_ratio_view'] = float(np.median(ratios)) if ratios else None
        g, b = results[mode]['graph'], results[mode]['bare']
        results[mode]['p99_ratio'] = (g['p99_ms'] / b['p99_ms']) if g['p99_ms'] and b['p99_ms'] else None
    md = [f'Real-time graph, {duration:g} s measured per row after 3 s warm-up; latency = receipt of '
          'the force command - stamp of the sample it was computed from. The floor is the same '
          'chain shape (source -> relay -> relay) with no computation.\n',
          '| mode | path | p50 [ms] | p99 [ms] | max [ms] | samples | missed cycles | late cycles '
          '| unanswered samples | CPU per process [%] |', '|' + '---|' * 10]
    for mode in modes:
        for path in ('graph', 'bare'):
            r = results[mode][path]
            cpu = ', '.join('-' if c is None else f'{c:.0f}' for c in r['cpu_percent'])
            md.append(f'| {mode} | {"our graph" if path == "graph" else "bare rclpy floor"} | '
                      f'{r["p50_ms"]:.3f} | {r["p99_ms"]:.3f} | {r["max_ms"]:.3f} | {r["samples"]} | '
                      f'{r["missed_cycles"]} | {r["late_cycles"]} | {r["unanswered_samples"]} | {cpu} |')
        ratio = results[mode]['p99_ratio']
        md.append(f'| {mode} | p99 ratio graph / floor | {ratio:.2f} | | | | | | | |' if ratio else
                  f'| {mode} | p99 ratio | - | | | | | | | |')
    if view_rounds:
        md += _view_markdown(results, modes, duration)
    results_md = '\n'.join(md) + '\n'
    return {'results': results, 'markdown': results_md}


# -- the bare chain's nodes ------------------------------------------------------------
def _bare_main(roles: list[str]) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

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
    executor = SingleThreadedExecutor()
    for n in nodes:
        executor.add_node(n)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description='bare rclpy chain for the loop benchmark')
    parser.add_argument('--node', action='append', choices=['source', 'relay1', 'relay2'], required=True)
    sys.exit(_bare_main(parser.parse_args().node))
