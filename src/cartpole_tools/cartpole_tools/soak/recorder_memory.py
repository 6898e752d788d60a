"""The recorder's memory over simulated hours, offline: where a long recording's growth goes.

A real :class:`cartpole_bringup.graph.recorder.RecorderNode` (its own context, never
spun: no DDS traffic) is fed the graph's messages through its subscription callbacks,
as its executor would hand them over: every 5 ms sample a ``/joint_states``,
``/cartpole/true_state``, ``/clock``, ``/cartpole/state``, ``/cartpole/force_command``,
``/cartpole/force_acting`` and ``/cartpole/controller_status``, and the EKF's health every
0.1 s, with stamps advancing 5 ms a sample, as fast as the writer thread writes them, with the node
process's collector policy (:func:`cartpole_core.realtime.enter_loop`: start-up frozen,
young generations collected between callbacks, as ``run_node`` does). Every simulated
``--every`` s it reads the resident memory and the Python heap (``tracemalloc``) and,
at the end, the allocation sites that grew most. Run::

    python -m cartpole_tools.soak.recorder_memory --hours 1 [--max-bag-duration 300]
"""
from __future__ import annotations

import argparse
import gc
import json
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

SAMPLE_NS = 5_000_000
HEALTH_EVERY = 20
"""Samples between two EKF health messages (0.1 s)."""


def _messages():
    """Serialized templates (stamp patched per sample) of the topics the recorder takes."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    def joint(names, n):
        return serialize_message(JointState(name=list(names), position=[0.1] * n,
                                            velocity=[0.2] * n, effort=[0.3] * n))

    def status(keys):
        return serialize_message(DiagnosticArray(status=[DiagnosticStatus(
            name='controller_manager', message='balancing',
            values=[KeyValue(key=f'key_{k}', value=f'{k * 0.123456:.6f}') for k in range(keys)])]))

    per_sample = {'/joint_states': joint(('cart', 'pendulum'), 2),
                  '/cartpole/true_state': joint(('cart', 'pendulum'), 2),
                  '/clock': serialize_message(Clock()),
                  '/cartpole/state': joint(('cart', 'pendulum'), 2),
                  '/cartpole/force_command': joint(('cart',), 1),
                  '/cartpole/force_acting': joint(('cart',), 1),
                  '/cartpole/controller_status': status(24)}
    return per_sample, {'/cartpole/ekf/health': status(12)}


def _stamped(template: bytes, stamp_ns: int) -> bytes:
    out = bytearray(template)
    out[4:12] = int(stamp_ns // 1_000_000_000).to_bytes(4, 'little', signed=True) + \
        int(stamp_ns % 1_000_000_000).to_bytes(4, 'little')
    return bytes(out)


def _rss_mb() -> float:
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith('VmRSS:'):
            return int(line.split()[1]) * 1024 / 1e6
    return float('nan')


def measure(hours: float, every_s: float, out: Path, max_bag_duration: float) -> dict:
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from cartpole_bringup.graph.recorder import RecorderNode
    from cartpole_core import realtime

    context = Context()
    rclpy.init(args=[], context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = RecorderNode(context=context, parameter_overrides=[
        Parameter('output', value=str(out)), Parameter('stamp_tolerance', value=0.0),
        Parameter('max_bag_duration', value=float(max_bag_duration))])
    per_sample, health = _messages()
    callbacks = {s.topic_name: s.callback for s in node.subscriptions}
    samples_per_row = int(round(every_s * 1e9 / SAMPLE_NS))
    rows, k, start = [], 0, time.time_ns()
    gc.collect()
    hygiene = realtime.enter_loop(0, log=lambda text: None)
    tracemalloc.start(1)
    first = tracemalloc.take_snapshot()
    try:
        for row in range(int(round(hours * 3600.0 / every_s)) + 1):
            if row:
                for _ in range(samples_per_row):
                    stamp = start + k * SAMPLE_NS
                    for topic, template in per_sample.items():
                        callbacks[topic](_stamped(template, stamp))
                    if k % HEALTH_EVERY == 0:
                        for topic, template in health.items():
                            callbacks[topic](_stamped(template, stamp))
                    k += 1
                    realtime.collect_when_idle()
                    if k % 200 == 0:
                        while len(node._queue) > 2000:  # as fast as the writer thread writes
                            time.sleep(0.001)
            node.health()  # the diagnostics timer's call, once a row
            traced, _ = tracemalloc.get_traced_memory()
            rows.append({'t_s': k * SAMPLE_NS * 1e-9, 'rss_mb': round(_rss_mb(), 3),
                         'python_heap_mb': round(traced / 1e6, 3),
                         'gc_counts': gc.get_count(),
                         'files': len(node._bag.files)})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
        last = tracemalloc.take_snapshot()
        top = [str(s) for s in last.compare_to(first, 'lineno')[:12]]
    finally:
        tracemalloc.stop()
        hygiene.leave()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return {'hours': hours, 'max_bag_duration': max_bag_duration, 'rows': rows,
            'top_growth': top}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m cartpole_tools.soak.recorder_memory',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=1.0)
    parser.add_argument('--every', type=float, default=300.0, help='simulated s a row')
    parser.add_argument('--max-bag-duration', type=float, default=300.0)
    parser.add_argument('--out', type=Path, default=None, help='bag directory (default: temp)')
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp) / 'bag'
        print(json.dumps(measure(args.hours, args.every, out, args.max_bag_duration), indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
