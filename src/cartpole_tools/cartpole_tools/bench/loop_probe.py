"""The loop benchmark's measurement: a probe node timing sample -> command, and the runs it times.

:func:`measure` starts processes (``cartpole run --sim``, or the bare floor),
waits for their first command, and records the latency of every force command
(receipt time - the stamp of the sample it was computed from), the gaps between
samples and each process's CPU (:mod:`.procfs`). :mod:`.loop` compares the graph
with its floor, :mod:`.loop_view` the graph with and without its live view.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

from .procfs import children, cpu_seconds, process_name

SAMPLE_TIME = 0.005
WARMUP_S = 3.0
"""Default wait after the first command before a measurement starts [s]."""


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class Probe:
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


def stats(probe: Probe) -> dict[str, Any]:
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


def start(cmd: list[str]) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def cpu_by_process(procs: list[subprocess.Popen], labels: list[str]) -> dict[str, int]:
    """The processes to account CPU to: each started one (named by ``labels``) and, for
    a graph started with one process a node, its node processes (by node name). Name -> PID."""
    out: dict[str, int] = {}
    for p, label in zip(procs, labels):
        out[label] = p.pid
        for child in children(p.pid):
            out[process_name(child, f'child {child}')] = child
    return out


def measure(cmds: list[list[str]], sample_topic: str, command_topic: str,
             duration: float, labels: list[str], warmup: float = WARMUP_S,
             viewer_url: str | None = None) -> dict[str, Any]:
    """Latency and CPU of the started processes; with ``viewer_url`` a Foxglove WebSocket
    client (its own process: no GIL shared with the probe) is subscribed to the viewer
    throughout, and ``viewer_messages`` counts what it received per channel."""
    probe = Probe(sample_topic, command_topic)
    procs = [start(c) for c in cmds]
    client = None
    try:
        if not probe.wait_for_traffic(timeout=60.0):
            errors = b''.join(p.stderr.read() if p.poll() is not None else b'' for p in procs)
            raise RuntimeError(f'no traffic on {command_topic}: {errors.decode(errors="replace")[-2000:]}')
        if viewer_url is not None:
            client = start_viewer_client(viewer_url)
        probe.record(warmup)
        probe.sample_stamps.clear()
        probe.latencies.clear()
        pids = cpu_by_process(procs, labels)
        cpu0 = {name: cpu_seconds(pid) for name, pid in pids.items()}
        t0 = time.monotonic()
        probe.record(duration)
        elapsed = time.monotonic() - t0
        cpu1 = {name: cpu_seconds(pid) for name, pid in pids.items()}
        result = stats(probe)
        result['cpu_percent'] = {
            name: None if cpu0[name] is None or cpu1[name] is None
            else 100.0 * (cpu1[name] - cpu0[name]) / elapsed for name in pids}
        if client is not None:
            client.send_signal(signal.SIGINT)
            out, _ = client.communicate(timeout=30)
            result['viewer_messages'] = json.loads(out.strip().splitlines()[-1])
        return result
    finally:
        if client is not None and client.poll() is None:
            client.kill()
            client.communicate()
        stop(procs)
        probe.close()


def start_viewer_client(url: str) -> subprocess.Popen:
    """``python -m cartpole_analysis.viewer.client URL``, started and subscribed."""
    client = subprocess.Popen([sys.executable, '-m', 'cartpole_analysis.viewer.client', url],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)
    if 'subscribed' not in client.stderr.readline():
        client.kill()
        raise RuntimeError(f'the viewer client did not subscribe: {client.communicate()[1][-1000:]}')
    return client


def graph_cmds(mode: str, duration: float, executor: str,
                view_port: int | None = None) -> list[list[str]]:
    cmd = [sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim', '--duration',
           str(duration + 60.0), '--executor', executor]
    if mode == 'processes':
        cmd.append('--processes')
    if view_port is not None:
        cmd += ['--view', f'127.0.0.1:{view_port}']
    return [cmd]


def graph_labels(mode: str) -> list[str]:
    return ['cartpole run (monitor)' if mode == 'processes' else 'cartpole run']
