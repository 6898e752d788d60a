"""The recorder node ``recorder``: every topic of the graph into a rosbag2 bag.

Subscribes the topics of docs/architecture.md (:data:`cartpole_analysis.bags.writer.TOPICS`)
with ``raw=True`` and writes the serialized CDR bytes unchanged into an MCAP
bag (readable by ``ros2 bag info``, Foxglove and ``rosbags``), log time = the
message's own stamp (:mod:`cartpole_analysis.bags.writer`). Run alone next to
a graph: ``ros2 run cartpole_bringup recorder --ros-args -p output:=runs/my_bag``.
The bag is closed when the node is destroyed (Ctrl-C, SIGTERM); until then it
is written in chunks at most ``flush_period`` old, so a SIGKILL loses at most
that (``cartpole bag repair``); a new file is begun every ``max_bag_duration`` s
(:mod:`cartpole_analysis.bags.writer`), so its memory stays bounded. In real time it
runs at a SCHED_FIFO priority below the loop's (:mod:`cartpole_core.realtime`). With
``lockstep:=true`` it publishes its
progress on ``cartpole/recorder/progress`` and the simulator waits for it
(:mod:`cartpole_bringup.graph.record_ledger`); in real time the messages it
missed are counted by stamp (``recorder_missed`` in the bag's custom_data; those
before a publisher was discovered apart, ``recorder_missed_at_start``).
In a namespace it records the graph's topics by the names they have there.
"""
from __future__ import annotations

import collections
import datetime as _dt
import threading
import time
from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

from cartpole_core.diagnostics import OK, Health, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import COMMAND, SAMPLE, STATE, TRUTH, RigLimits
from cartpole_core.node_runner import run_node

from cartpole_analysis.bags.writer import (FLUSH_PERIOD, MAX_BAG_DURATION, TOPICS, BagWriter,
                                           cdr_stamp_ns, update_custom_data)
from cartpole_core.namespaces import NAMESPACE_KEY, ROOT, relative
from .progress import LockstepProgress
from . import record_ledger as ledger
from .record_ledger import PROGRESS_TOPIC, RecordLedger



JUDGED = {ledger.JOINT_STATES: SAMPLE, ledger.STATE: STATE, ledger.FORCE: COMMAND,
          ledger.ACTING: COMMAND, ledger.TRUE_STATE: TRUTH}
"""The recorded topics whose messages are judged (counted, never dropped: it is a recorder)."""

QUEUE_DEPTH = 200
"""Default depth of each subscription's queue (1 s of a 200 Hz topic); the real-time
priority keeps the recorder fed. 1000 was tried: a loop process stalled 330-340 ms early
in 3 of 6 short soaks with it, 1 of 7 with 200 (docs/soak.md)."""

WRITE_PERIOD = 0.01
"""Wall seconds between two looks of the writer thread at the queue."""


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
                        'docs/architecture.md (an unknown name is refused), by its name in '
                        'the root namespace (recorded in the node\'s).', read_only=True))
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
        self.declare_parameter('max_bag_duration', MAX_BAG_DURATION, ParameterDescriptor(
            description='Log time [s] a bag file spans before the next file is begun (as '
                        '`ros2 bag record --max-bag-duration`); 0 never splits by time. A '
                        "closed file's index leaves memory.", read_only=True,
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=86400.0,
                                                     step=0.0)]))
        self.declare_parameter('max_bag_size', 0, ParameterDescriptor(
            description='Bytes a bag file holds before the next file is begun (as '
                        '`ros2 bag record --max-bag-size`); 0 never splits by size.',
            read_only=True,
            integer_range=[IntegerRange(from_value=0, to_value=2**62, step=1)]))
        self.declare_parameter('lockstep', False, ParameterDescriptor(
            description='Lockstep: publish the progress the simulator waits for on '
                        f'{PROGRESS_TOPIC} and write a re-published sample once.',
            read_only=True))
        self.declare_parameter('queue_depth', QUEUE_DEPTH, ParameterDescriptor(
            description='Subscription queue depth (reliable QoS).', read_only=True,
            integer_range=[IntegerRange(from_value=1, to_value=100000, step=1)]))
        try:
            self.inputs = InputGuard(self, RigLimits(
                stamp_tolerance=declare_stamp_tolerance(self)), [])
            self._start()
        except BaseException:
            # refused (an unknown topic, an existing bag): no half-built recorder, with its
            # subscriptions and services, stays on the graph of the process that asked
            super().destroy_node()
            raise

    def _start(self) -> None:
        """Subscribe to the topics and open the bag, or refuse."""
        topics = [str(t) for t in self.get_parameter('topics').value]
        unknown = sorted(set(topics) - set(TOPICS))
        if unknown:
            raise ValueError(f'cannot record {unknown}: known topics are {sorted(TOPICS)}')
        custom = parse_custom_data(c for c in self.get_parameter('custom_data').value if c)
        if self.get_namespace() != ROOT:
            custom[NAMESPACE_KEY] = self.get_namespace()
        output = self.get_parameter('output').value or default_output()
        flush_period = float(self.get_parameter('flush_period').value)
        qos = QoSProfile(depth=int(self.get_parameter('queue_depth').value),
                         reliability=ReliabilityPolicy.RELIABLE)
        lockstep = bool(self.get_parameter('lockstep').value)
        self.ledger = RecordLedger(topics, skip_repeats=lockstep)
        self._progress = LockstepProgress(self, self.ledger) if lockstep else None
        self._recorded: dict[str, str] = {}
        """Topic (root name) -> the name it is recorded by (as subscribed, remapped)."""
        for topic in topics:
            sub = self.create_subscription(_import_type(TOPICS[topic]), relative(topic),
                                           self._writer_for(topic), qos, raw=True)
            self._recorded[topic] = sub.topic_name
        self._judged = {self._recorded[t]: JUDGED[t] for t in topics if t in JUDGED}
        """Recorded name -> the kind its messages are judged as (in the writer thread)."""
        self.inputs.topics = tuple(relative(t) for t in topics if t in JUDGED)
        self._bag = BagWriter(Path(output), {self._recorded[t]: TOPICS[t] for t in topics},
                              custom, log_time=str(self.get_parameter('log_time').value),
                              flush_period=flush_period,
                              max_bag_duration=float(self.get_parameter('max_bag_duration').value),
                              max_bag_size=int(self.get_parameter('max_bag_size').value))
        # The callbacks only queue what arrives; a thread writes it into the bag and
        # finishes the chunks on time (also while nothing arrives). The signal that stops
        # the recorder (a KeyboardInterrupt, cartpole_core.node_runner) can land anywhere in
        # this thread's callbacks, but never in the middle of writing a record, which
        # would make its chunk unreadable.
        self._queue: collections.deque = collections.deque()
        self._stop_writer = threading.Event()
        self._writer = threading.Thread(target=self._write_loop, name='recorder_writer',
                                        daemon=True)
        self._writer.start()
        self.get_logger().info(f'recording {len(topics)} topics into {self._bag.path}')
        self.diagnostics = NodeDiagnostics(self, 'recording', 'cartpole', self.health,
                                           degraded=('refused_inputs',))

    def _writer_for(self, topic: str):
        if topic not in self.ledger.topics:
            def queue(data: bytes) -> None:
                self._queue.append((self._recorded[topic], data,
                                    self.get_clock().now().nanoseconds))
            return queue

        def book_and_queue(data: bytes) -> None:
            if not self.ledger.take(topic, cdr_stamp_ns(data)):
                return  # a sample re-published while the graph started: written once
            self._queue.append((self._recorded[topic], data, self.get_clock().now().nanoseconds))
            if self._progress is not None:
                self._progress.update()
        return book_and_queue

    def _write_queued(self) -> None:
        queue, bag, judged = self._queue, self._bag, self._judged
        while queue:
            topic, data, received = queue.popleft()
            bag.write(topic, data, received)
            kind = judged.get(topic)
            if kind is not None:
                self._judge(topic, kind, data, received)

    def _judge(self, topic: str, kind: str, data: bytes, received: int) -> None:
        """Count a recorded message the rig cannot have produced (it stays in the bag)."""
        try:
            msg = deserialize_message(data, JointState)
        except Exception:  # noqa: BLE001 - undecodable bytes: counted like any bad message
            self.inputs.refuse(topic, 'undecodable')
            return
        self.inputs.accept(msg, kind, topic, received)

    def health(self) -> Health:
        """The recorder's health for ``/diagnostics`` (``recorder: recording``): OK while it
        writes, WARN once it recorded a message the rig cannot produce (refused_inputs)."""
        written = self._bag.counts
        return self.inputs.health(Health(OK, f'recording into {self._bag.path}', {
            'written': sum(written.values()), 'missed': self.ledger.missed}))

    def _write_loop(self) -> None:
        while not self._stop_writer.wait(WRITE_PERIOD):
            self._write_queued()
            self._bag.flush_if_due()
        self._write_queued()

    @property
    def bag_path(self) -> Path:
        """The bag directory being written."""
        return self._bag.path

    @property
    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic by its root name (the queue is written every
        10 ms)."""
        written = self._bag.counts
        return {topic: written[name] for topic, name in self._recorded.items() if name in written}

    def close(self) -> None:
        """Write what was queued, close the bag (``metadata.yaml``); later messages are dropped."""
        if self._bag.closed:
            return
        self._stop_writer.set()
        self._writer.join()
        self._write_queued()
        self._bag.close()
        missed = self.ledger.finish()
        at_start = self.ledger.missed_at_start
        update_custom_data(self._bag.path, {'recorder_missed': str(missed),
                                            'recorder_missed_at_start': str(at_start)})
        if missed:
            self.get_logger().warning(f'the recorder missed {missed} messages (by stamp)')
        if at_start:
            self.get_logger().info(f'{at_start} messages were published before the recorder '
                                   'had discovered their publisher')

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


def drain(node: RecorderNode, executor, quiet_rounds: int = 3, pause: float = 0.01) -> None:
    """Write what has already arrived, then return (the bag is closed after it).

    The signal that ends the recorder interrupts the executor, possibly in the
    middle of a callback, so the queues are not left to the executor's
    bookkeeping: every subscription's queue is emptied directly
    (``take_message``), in rounds ``pause`` apart, until ``quiet_rounds``
    rounds in a row bring nothing. The writer thread then writes them.
    """
    quiet = 0
    while quiet < quiet_rounds:
        taken = 0
        for sub in node.subscriptions:
            with sub.handle:
                while (info := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
                    sub.callback(info[0])
                    taken += 1
        quiet = 0 if taken else quiet + 1
        if not taken:
            time.sleep(pause)


def main(args=None) -> None:
    """Record until SIGINT/SIGTERM, then write what had arrived (drain) and close the bag."""
    run_node(RecorderNode, args, name='recorder', make_executor=_executor, on_interrupt=drain)


if __name__ == '__main__':
    main()
