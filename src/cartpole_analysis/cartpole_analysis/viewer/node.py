"""The ``viewer`` node: the running graph, live, in Foxglove (a WebSocket server).

Subscribes the graph's topics and feeds :class:`cartpole_analysis.viewer.server.LiveView`
(the Foxglove WebSocket protocol through the foxglove-sdk)::

    ros2 run cartpole_bringup viewer                      # ws://127.0.0.1:8765

It never publishes on the graph and subscribes best-effort, so a viewer that
falls behind drops samples and the loop never waits for it. It takes only
``cartpole/state`` (each one due draws the scene), ``cartpole/controller_status``,
one of ``cartpole/true_state`` (while it has a publisher) or ``joint_states``
(chosen every :data:`PLANT_TOPIC_CHECK_PERIOD`) and ``/parameter_events``:
every subscription costs the publishers a send per message. With
``feed:=PATH`` it takes the samples from the ``viewer_tap`` node's Unix
socket instead (:mod:`cartpole_analysis.viewer.feed`; ``cartpole run --view``).
It runs at the lowest CPU priority and prints ``viewer: serving ws://HOST:PORT``
to stderr on start. docs/live_view.md.
"""
from __future__ import annotations

import math
import os
import sys
import threading
from typing import NamedTuple

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterEvent, ParameterType, SetParametersResult)
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from cartpole_sim.geometry import RigGeometry
from cartpole_core.diagnostics import OK, Health, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import SAMPLE, RigLimits
from cartpole_core.message_checks import STATE as STATE_KIND, TRUTH as TRUTH_KIND
from cartpole_core.model import CartPoleParameters
from cartpole_core.node_runner import run_node

from ..analysis.analyze import JOINTS, STATE, STATUS, TRUE_STATE, parse_joint_state
from ..bags.writer import cdr_stamp_ns
from cartpole_core.namespaces import relative
from .diagnostics_cdr import parse_diagnostic_array
from .server import DEFAULT_HOST, DEFAULT_PORT, MAX_RATE_HZ, ControlSample, LiveView, ViewerServer
from .feed import ESTIMATE, MEASUREMENT, STATUS as STATUS_KIND, TRUTH, FeedReceiver

NODE_NAME = 'viewer'
X_REF_QUERY_PERIOD = 1.0
"""Wall seconds between attempts to read the controller manager's x_ref at start."""
X_REF_QUERY_ATTEMPTS = 30
PLANT_TOPIC_CHECK_PERIOD = 1.0
"""Wall seconds between checks whether /cartpole/true_state has a publisher."""


class _Stamp(NamedTuple):
    sec: int
    nanosec: int


class _Header(NamedTuple):
    stamp: _Stamp


class _JointStateView(NamedTuple):
    """A parsed JointState as :func:`cartpole_core.message_checks.judge` reads it."""

    header: _Header
    name: list
    position: object
    velocity: object
    effort: object


class ViewerNode(Node):
    """Node ``viewer`` (see the module docstring); takes ``**kwargs`` of ``rclpy.node.Node``."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._start()
        except BaseException:   # refused: nothing of the node stays in the graph
            server = getattr(self, 'server', None)
            if server is not None:
                server.stop()
            Node.destroy_node(self)
            raise

    def _start(self) -> None:
        """The rest of ``__init__``: parameters, the server, subscriptions, timers."""
        self.declare_parameter('host', DEFAULT_HOST, ParameterDescriptor(
            description='Address the Foxglove WebSocket server binds to (0.0.0.0: every '
                        'interface)', read_only=True))
        self.declare_parameter('port', DEFAULT_PORT, ParameterDescriptor(
            description='TCP port of the server (0: any free port, printed at start)',
            read_only=True, integer_range=[IntegerRange(from_value=0, to_value=65535, step=1)]))
        self.declare_parameter('max_rate', MAX_RATE_HZ, ParameterDescriptor(
            description='Upper bound of the scene, state and control rates [Hz], by stamps',
            read_only=True, floating_point_range=[FloatingPointRange(
                from_value=1.0, to_value=MAX_RATE_HZ, step=0.0)]))
        self.declare_parameter('plant_params_file', '', ParameterDescriptor(
            description="CartPoleParameters YAML of the drawn rig (travel, l); '' = the thesis "
                        'values', read_only=True))
        self.declare_parameter('x_ref', math.nan, ParameterDescriptor(
            description='x* marked on the rail [m]; NaN = the controller manager\'s x_ref, else '
                        'the middle of the travel. Follows the controller manager\'s x_ref.'))
        self.declare_parameter('controller_manager', 'controller_manager', ParameterDescriptor(
            description='The node whose x_ref parameter x* follows (relative: in the '
                        'viewer\'s namespace)', read_only=True))
        self.declare_parameter('feed', '', ParameterDescriptor(
            description="'' = subscribe the graph's topics; else the path of a Unix "
                        'socket to take the samples from instead (the viewer_tap node of '
                        'cartpole run --view sends them)', read_only=True))

        path = self.get_parameter('plant_params_file').value
        params = CartPoleParameters.from_yaml(path) if path else CartPoleParameters()
        # Stamps not judged by default: the viewer keeps wall time even in lockstep.
        self.inputs = InputGuard(self, RigLimits.from_parameters(
            params, stamp_tolerance=declare_stamp_tolerance(self, default=0.0)),
            (relative(STATE), relative(JOINTS), relative(TRUE_STATE)))
        """Judges every sample before it is drawn (refused_inputs on /diagnostics)."""
        x_ref = self.get_parameter('x_ref').value
        self._x_ref_fixed = math.isfinite(x_ref)
        host = self.get_parameter('host').value
        port = self.get_parameter('port').value
        try:
            self.server = ViewerServer(host=host, port=port)
        except RuntimeError as error:  # the SDK's FoxgloveError: bind failed, bad address
            raise OSError(f'cannot serve on {host}:{port}: {error}') from None
        self.view = LiveView(self.server, RigGeometry.from_parameters(params),
                             x_ref if self._x_ref_fixed else params.x_middle,
                             max_rate=self.get_parameter('max_rate').value)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self.bad_messages = 0
        """Controller status messages that could not be read (counted, dropped)."""
        self.plant_topic = ''
        """The topic of the drawn plant state: TRUE_STATE or JOINTS."""
        self._plant_subscription = None
        self._feed = None
        feed = self.get_parameter('feed').value
        if feed:
            self._start_feed(feed)
        else:
            self._fast = QoSProfile(depth=20, reliability=ReliabilityPolicy.BEST_EFFORT)
            self.create_subscription(JointState, relative(STATE), self._on_estimate, self._fast,
                                     raw=True)
            self._choose_plant_topic()
            self.create_timer(PLANT_TOPIC_CHECK_PERIOD, self._choose_plant_topic)
            self.create_subscription(DiagnosticArray, relative(STATUS), self._on_status,
                                     QoSProfile(depth=100,
                                                reliability=ReliabilityPolicy.BEST_EFFORT),
                                     raw=True)
        manager = self.get_parameter('controller_manager').value.rstrip('/') or '/'
        if not manager.startswith('/'):
            manager = self.get_namespace().rstrip('/') + '/' + manager
        self._manager = manager
        """The manager's full name, as parameter events name their node."""
        self.create_subscription(ParameterEvent, '/parameter_events', self._on_parameter_event,
                                 QoSProfile(depth=100))
        self._x_ref_client = self.create_client(GetParameters, f'{self._manager}/get_parameters')
        self._x_ref_future = None
        self._x_ref_attempts = 0
        self._x_ref_timer = None
        if not self._x_ref_fixed:
            self._x_ref_timer = self.create_timer(X_REF_QUERY_PERIOD, self._query_x_ref)
        self.diagnostics = NodeDiagnostics(self, 'live view', 'cartpole', self.health,
                                           degraded=('refused_inputs', 'bad_messages'))
        print(f'viewer: serving {self.server.url}', file=sys.stderr, flush=True)

    # -- the feed of cartpole run --view ------------------------------------------------------
    def _start_feed(self, path: str) -> None:
        """Take the samples from the feed socket, read by a thread (no DDS subscriptions)."""
        self._feed = FeedReceiver(path)
        self._feed_stop = threading.Event()
        handlers = {TRUTH: self._on_truth, MEASUREMENT: self._on_measurement,
                    ESTIMATE: self._on_estimate, STATUS_KIND: self._on_status}
        self.plant_topic = 'feed'

        def read() -> None:
            while not self._feed_stop.is_set():
                message = self._feed.receive(0.2)
                if message is not None:
                    handlers[message[0]](message[1])
        self._feed_thread = threading.Thread(target=read, name='viewer_feed', daemon=True)
        self._feed_thread.start()

    # -- topics ----------------------------------------------------------------------------
    def _choose_plant_topic(self) -> None:
        """The truth while the simulator publishes it, else the measurement."""
        topic = TRUE_STATE if self.count_publishers(relative(TRUE_STATE)) > 0 else JOINTS
        if topic == self.plant_topic:
            return
        if self._plant_subscription is not None:
            self.destroy_subscription(self._plant_subscription)
        callback = self._on_truth if topic == TRUE_STATE else self._on_measurement
        self._plant_subscription = self.create_subscription(JointState, relative(topic),
                                                            callback, self._fast, raw=True)
        self.plant_topic = topic

    # The measurement and truth of a sample that is not drawn are not decoded (the stamp
    # is the first field; cdr_stamp_ns reads it alone).
    def _judged(self, data: bytes, kind: str, topic: str):
        """(stamp [ns], {joint: (position, velocity)}) of a sample the rig can produce, else
        None (counted, :mod:`cartpole_core.message_checks`)."""
        try:
            stamp, names, position, velocity, effort = parse_joint_state(data)
        except (ValueError, IndexError, UnicodeDecodeError):
            self.inputs.refuse(topic, 'undecodable')
            return None
        sec, nanosec = divmod(stamp, 1_000_000_000)
        msg = _JointStateView(_Header(_Stamp(sec, nanosec)), names, position, velocity, effort)
        if not self.inputs.accept(msg, kind, topic):
            return None
        at = {name: i for i, name in enumerate(names)}
        return stamp, {name: (position[i], velocity[i] if len(velocity) else 0.0)
                       for name, i in at.items()}

    def _on_measurement(self, data: bytes) -> None:
        if not self.view.wanted(cdr_stamp_ns(data)):
            return
        judged = self._judged(data, SAMPLE, JOINTS)
        if judged is not None:
            stamp, joints = judged
            self.view.measurement(stamp, joints['cart'][0], joints['pendulum'][0])

    def _on_truth(self, data: bytes) -> None:
        if not self.view.wanted(cdr_stamp_ns(data)):
            return
        judged = self._judged(data, TRUTH_KIND, TRUE_STATE)
        if judged is not None:
            stamp, (cart, pendulum) = judged[0], (judged[1]['cart'], judged[1]['pendulum'])
            self.view.truth(stamp, cart[0], pendulum[0], cart[1], pendulum[1])

    def _on_estimate(self, data: bytes) -> None:
        judged = self._judged(data, STATE_KIND, STATE)
        if judged is not None:
            stamp, (cart, pendulum) = judged[0], (judged[1]['cart'], judged[1]['pendulum'])
            self.view.estimate(stamp, cart[0], pendulum[0], cart[1], pendulum[1])

    def health(self) -> Health:
        """The viewer's health for ``/diagnostics`` (``viewer: live view``): OK while it
        serves, WARN once it dropped a sample the rig cannot produce (refused_inputs)."""
        return self.inputs.health(Health(OK, f'serving {self.server.url}', {
            'bad_messages': self.bad_messages, 'plant_topic': self.plant_topic}))

    def _on_status(self, data: bytes) -> None:
        try:
            stamp, statuses = parse_diagnostic_array(data)
        except ValueError as error:
            self.bad_messages += 1
            self.get_logger().warn(f'{STATUS}: {error}', throttle_duration_sec=5.0)
            return
        for status in statuses:
            if status.name == 'controller_manager':
                self.view.status(stamp, ControlSample.from_status_values(status.values))

    # -- x* ----------------------------------------------------------------------------------
    def _on_set_parameters(self, params) -> SetParametersResult:
        for p in params:
            if p.name == 'x_ref':
                value = float(p.value)
                self._x_ref_fixed = math.isfinite(value)
                if self._x_ref_fixed:
                    self.view.set_x_ref(value)
        return SetParametersResult(successful=True)

    def _on_parameter_event(self, event: ParameterEvent) -> None:
        if self._x_ref_fixed or event.node != self._manager:
            return
        for p in list(event.new_parameters) + list(event.changed_parameters):
            if p.name == 'x_ref' and p.value.type == ParameterType.PARAMETER_DOUBLE:
                self.view.set_x_ref(p.value.double_value)

    def _query_x_ref(self) -> None:
        """At start: read the manager's x_ref once (later changes come as parameter events)."""
        future = self._x_ref_future
        if future is not None and future.done():
            result = future.result()
            if result is not None and result.values and \
                    result.values[0].type == ParameterType.PARAMETER_DOUBLE:
                if not self._x_ref_fixed:
                    self.view.set_x_ref(parameter_value_to_python(result.values[0]))
                self._x_ref_timer.cancel()
                return
            self._x_ref_future = future = None
        self._x_ref_attempts += 1
        if self._x_ref_attempts > X_REF_QUERY_ATTEMPTS or self._x_ref_fixed:
            self._x_ref_timer.cancel()
            return
        if future is None and self._x_ref_client.service_is_ready():
            self._x_ref_future = self._x_ref_client.call_async(GetParameters.Request(
                names=['x_ref']))

    def destroy_node(self) -> None:
        if self._feed is not None:
            self._feed_stop.set()
            self._feed_thread.join(timeout=2.0)
            self._feed.close()
        self.server.stop()
        super().destroy_node()


def lower_priority() -> str:
    """Make this process yield the CPU to the control loop; returns what was set.

    ``SCHED_IDLE`` (Linux): the process runs only on CPU time no other
    process wants, and its wake-ups (a DDS sample arriving 600 times a
    second) never preempt the loop's threads; else ``nice`` +10. A viewer
    that gets too little CPU drops samples (best-effort subscriptions).
    """
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        return 'SCHED_IDLE'
    except (AttributeError, OSError):
        pass
    try:
        os.nice(10)
        return 'nice +10'
    except OSError:
        return 'unchanged'


def _executor():
    """rclpy's C++ EventsExecutor: a callback costs about a third of the SingleThreadedExecutor's
    (the viewer takes about 1000 messages a second)."""
    from rclpy.experimental import EventsExecutor
    return EventsExecutor()


def main(args=None) -> None:
    """Serve until Ctrl-C / SIGTERM, at the lowest CPU priority (:func:`lower_priority`)."""
    lower_priority()
    run_node(ViewerNode, args, name=NODE_NAME, make_executor=_executor)


if __name__ == '__main__':
    main()
