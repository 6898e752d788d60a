"""The recorder node ``recorder``: every topic of the graph into a rosbag2 bag.

Subscribes the topics of docs/architecture.md (:data:`cartpole_bringup.bag.TOPICS`)
with ``raw=True``, so rclpy hands over the serialized CDR bytes, and writes
them unchanged into an MCAP bag (metadata version 9, readable by
``ros2 bag info``, Foxglove and ``rosbags``). Log time = the message's own
stamp (simulated time in lockstep); see :mod:`cartpole_bringup.bag`.

Run alone next to a graph started otherwise::

    ros2 run cartpole_bringup recorder --ros-args -p output:=runs/my_bag

The bag is closed (``metadata.yaml`` written) when the node is destroyed,
on Ctrl-C and on SIGTERM alike. Until then the MCAP file is written in
chunks at most ``flush_period`` old (also while no message arrives: a wall
timer writes an idle chunk), so a recorder killed with SIGKILL loses at most
that much; ``cartpole bag repair BAG`` makes the rest readable.
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from cartpole_sim.node_main import run_node

from .bag import FLUSH_PERIOD, TOPICS, BagWriter


def _import_type(name: str):
    """The rclpy message class of ``pkg/msg/Type``."""
    import importlib
    package, _, type_name = name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), type_name)


def default_output() -> str:
    """``recording_<UTC timestamp>`` in the working directory."""
    return 'recording_' + _dt.datetime.now(_dt.timezone.utc).strftime('%Y%m%dT%H%M%SZ')


def parse_custom_data(items) -> dict[str, str]:
    """``['key=value', ...]`` -> dict; ValueError on an item without '='."""
    out = {}
    for item in items:
        key, sep, value = str(item).partition('=')
        if not sep or not key:
            raise ValueError(f"custom_data item {item!r} is not 'key=value'")
        out[key] = value
    return out


class RecorderNode(Node):
    """Records the graph's topics into an MCAP bag (node name ``recorder``)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('recorder', **kwargs)
        self.declare_parameter('output', '', ParameterDescriptor(
            description="Bag directory to create (must not exist); '' = "
                        'recording_<UTC timestamp> in the working directory.', read_only=True))
        self.declare_parameter('topics', list(TOPICS), ParameterDescriptor(
            description='Topics to record; each must be one of the graph topics of '
                        'docs/architecture.md.', read_only=True))
        self.declare_parameter('custom_data', [''], ParameterDescriptor(
            description="'key=value' strings stored in the bag's custom_data "
                        '(x_ref, controllers, scenario).', read_only=True))
        self.declare_parameter('log_time', 'stamp', ParameterDescriptor(
            description="Log time of each message: 'stamp' (its header stamp; simulated time "
                        "in lockstep) or 'receive' (the node clock when it arrived).",
            read_only=True))
        self.declare_parameter('flush_period', FLUSH_PERIOD, ParameterDescriptor(
            description='Longest time [s] a received message waits in memory before it is '
                        'written to the file (what a SIGKILL can lose).', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=60.0, step=0.0)]))
        self.declare_parameter('queue_depth', 200, ParameterDescriptor(
            description='Subscription queue depth (reliable QoS).', read_only=True,
            integer_range=[IntegerRange(from_value=1, to_value=100000, step=1)]))

        topics = [str(t) for t in self.get_parameter('topics').value]
        unknown = sorted(set(topics) - set(TOPICS))
        if unknown:
            raise ValueError(f'cannot record {unknown}: known topics are {sorted(TOPICS)}')
        custom = parse_custom_data(c for c in self.get_parameter('custom_data').value if c)
        output = self.get_parameter('output').value or default_output()
        flush_period = float(self.get_parameter('flush_period').value)
        self._bag = BagWriter(Path(output), {t: TOPICS[t] for t in topics}, custom,
                              log_time=str(self.get_parameter('log_time').value),
                              flush_period=flush_period)
        qos = QoSProfile(depth=int(self.get_parameter('queue_depth').value),
                         reliability=ReliabilityPolicy.RELIABLE)
        for topic in topics:
            self.create_subscription(_import_type(TOPICS[topic]), topic,
                                     self._writer_for(topic), qos, raw=True)
        # Wall clock: an idle chunk is written even when /clock (sim time) stands still.
        self.create_timer(min(0.1, flush_period / 2), self._flush_if_due,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'recording {len(topics)} topics into {self._bag.path}')

    def _flush_if_due(self) -> None:
        if not self._bag.closed:
            self._bag.flush_if_due()

    def _writer_for(self, topic: str):
        def write(data: bytes) -> None:
            if not self._bag.closed:
                self._bag.write(topic, data, self.get_clock().now().nanoseconds)
        return write

    @property
    def bag_path(self) -> Path:
        """The bag directory being written."""
        return self._bag.path

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        return dict(self._bag.counts)

    def close(self) -> None:
        """Close the bag now (``metadata.yaml`` written); later messages are dropped."""
        self._bag.close()

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


def _executor():
    """The C++ EventsExecutor (about 3x less overhead per message), else rclpy's own.

    The recorder takes every message of the graph (about 1200 per second), so
    the executor's overhead decides whether it keeps up.
    """
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return SingleThreadedExecutor()
    return EventsExecutor()


def drain(node: RecorderNode, executor, quiet_spins: int = 3) -> None:
    """Write what has already arrived: spin until ``quiet_spins`` spins in a row bring nothing."""
    quiet = 0
    while quiet < quiet_spins:
        before = sum(node.counts.values())
        executor.spin_once(timeout_sec=0.01)
        quiet = quiet + 1 if sum(node.counts.values()) == before else 0


def main(args=None) -> None:
    """Record until SIGINT/SIGTERM, then write what had arrived (drain) and close the bag."""
    run_node(RecorderNode, args, name='recorder', make_executor=_executor, on_interrupt=drain)


if __name__ == '__main__':
    main()
