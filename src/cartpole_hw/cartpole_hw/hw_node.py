"""ROS 2 node ``hw_bridge``: the rig (or its emulator) on ``/joint_states`` and
``/cartpole/force_command`` through the Joint serial protocol (docs/rig.md, "The Joint protocol").

The node only wires ROS to :class:`~cartpole_hw.serial_link.SerialLink` and
:class:`~cartpole_hw.bridge.BridgeCore`, where every rule lives (read
``bridge.py``'s docstring for the safety rules):

- publishes ``/joint_states`` (``cart``, ``pendulum``; x from the unwrapped
  cart count (2.4), theta = pi + pendulum count (2.3); ``header.stamp`` =
  the device's time of the sample, its ``t_us`` mapped to the host clock
  (:mod:`cartpole_hw.device_clock`: USB latency jitter does not reach the
  stamps) and read on the node clock) from the reader thread, for every valid
  ``S`` line;
- subscribes ``/cartpole/force_command`` (``name=['cart']``, ``effort=[F]``)
  and sends ``U,<setpoint>``, setpoint = 56.744 F (A.3), while armed, tagged
  ``U,<setpoint>,<seq>`` with the ``seq`` of the sample it answers (found by its
  stamp among the last :data:`RECEIPTS_KEPT` published) when the device speaks
  protocol version 2; a
  command's age (the bridge's freshness rule) counts from the host's receipt
  of the sample it answers (found by its stamp), not from the device's
  sampling time: the USB latency before the receipt is the device
  watchdog's business, and counting it twice made a late-read sample's
  prompt answer stale;
- ``~/arm`` (std_srvs/SetBool) and the ``armed`` parameter arm/disarm;
  ``~/home`` (std_srvs/Trigger) resets the encoders (disarmed only);
- publishes ``/cartpole/hw/health`` (diagnostic_msgs/DiagnosticArray,
  status ``hw_bridge``) every ``health_period``, and the same health as
  ``hw_bridge: serial link`` on ``/diagnostics`` once a second (:meth:`HwBridgeNode.health`);
- publishes ``/cartpole/command_applied`` (sensor_msgs/TimeReference,
  ``source='hw_bridge'``) from the reader thread, once for every command the
  device reports in force (protocol version 2): ``time_ref`` = the stamp this
  bridge gave the sample the command answers, ``header.stamp`` = when it took
  effect, the device's time mapped to the host clock as the samples' are: the
  controller manager's measure of the loop's latency;
- after a homing (the position reference moved: x = 0 now), announces it on
  ``/cartpole/plant_reset`` (std_msgs/Header, stamp = the first sample's)
  before that sample, so the EKF re-initialises instead of filtering the jump.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import threading

from builtin_interfaces.msg import Time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger

from . import protocol as jp
from .bridge import BridgeConfig, BridgeCore, JointSample
from .serial_link import SerialLink
from cartpole_sim.diagnostics import ERROR, OK, WARN, Health, HealthReport, NodeDiagnostics
from cartpole_sim.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node

RECEIPTS_KEPT = 400
"""Receipt times kept for the command-age rule (2 s of samples at 200 Hz)."""

DEGRADED = ('lost_samples', 'seq_gaps', 'bad_lines', 'bad_samples', 'bad_commands',
            'stale_commands', 'watchdog_trips', 'device_watchdog_trips', 'reconnects')
"""Health counters whose growth since the previous report makes it WARN."""

_CALIBRATION = ('cart_sign', 'pendulum_sign', 'force_sign', 'cart_ticks_over_travel', 'travel',
                'pendulum_ticks_per_rev', 'setpoint_per_newton', 'dac_zero')


class HwBridgeNode(Node):
    """Serial bridge to the Arduino Due I/O firmware (node name ``hw_bridge``).

    Why one class of about 230 lines: a node adapter whose ``__init__`` declares the
    bridge's parameters, topics and services; everything it decides is
    :class:`cartpole_hw.bridge.BridgeCore`.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('hw_bridge', **kwargs)
        cal = jp.Calibration()

        def fp(lo, hi):
            return [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]

        def ir(lo, hi, step=1):
            return [IntegerRange(from_value=lo, to_value=hi, step=step)]

        ro = dict(read_only=True)
        self.declare_parameter('port', '/dev/ttyACM0', ParameterDescriptor(
            description='serial device of the Arduino Due (or the emulator link, e.g. '
                        '/tmp/cartpole-emu); re-opened after a disconnect', **ro))
        self.declare_parameter('baud', 115200, ParameterDescriptor(
            description='baud rate (8N1)', integer_range=ir(1200, 4_000_000), **ro))
        for name, meaning in (('cart_sign', 'a growing cart count means the cart moves right'),
                              ('pendulum_sign', 'a growing pendulum count means theta grows'),
                              ('force_sign', 'a positive setpoint pushes the cart right')):
            self.declare_parameter(name, getattr(cal, name), ParameterDescriptor(
                description=f'+1 if {meaning}, else -1', integer_range=ir(-1, 1, 2), **ro))
        for name, meaning, lo, hi in (
                ('cart_ticks_over_travel', 'cart ticks over the travel (2.4)', 1, 1e6),
                ('travel', 'cart travel between the end stops [m] (section 2.3)', 0.01, 10.0),
                ('pendulum_ticks_per_rev', 'pendulum ticks per revolution (2.3)', 1, 1e6),
                ('setpoint_per_newton', 'DAC setpoint per newton, 1/0.017623 (A.3)', 1.0, 1000.0)):
            self.declare_parameter(name, getattr(cal, name), ParameterDescriptor(
                description=meaning, floating_point_range=fp(lo, hi), **ro))
        self.declare_parameter('dac_zero', cal.dac_zero, ParameterDescriptor(
            description='DAC value of zero current (Appendix A)', integer_range=ir(0, 4095), **ro))
        self.declare_parameter('command_timeout', 0.05, ParameterDescriptor(
            description='host watchdog: longest gap between fresh force commands while '
                        'armed [s]; a trip sends U,0 and E,0 and disarms',
            floating_point_range=fp(0.005, 1.0)))
        self.declare_parameter('sample_timeout', 0.05, ParameterDescriptor(
            description='longest gap between valid samples while armed before disarming [s]',
            floating_point_range=fp(0.01, 1.0)))
        self.declare_parameter('reconnect_period', 0.5, ParameterDescriptor(
            description='period of the attempts to re-open a vanished port [s]',
            floating_point_range=fp(0.05, 10.0)))
        self.declare_parameter('health_period', 0.2, ParameterDescriptor(
            description='period of /cartpole/hw/health [s]', floating_point_range=fp(0.02, 10.0),
            **ro))
        self.declare_parameter('home_on_start', False, ParameterDescriptor(
            description='reset the encoders (R) once the device first answers; the cart must be '
                        'at the left stop and the pendulum hanging still', **ro))
        self.declare_parameter('armed', False, ParameterDescriptor(
            description='true enables the amplifier and forwards force commands; true at start '
                        'arms as soon as the device answers, the encoders are homed and the '
                        'control loop answers the samples in time (20 fresh commands); any '
                        'fault sets it back to false'))

        p = {name: self.get_parameter(name).value for name in _CALIBRATION}
        p['cart_ticks_over_travel'] = float(p['cart_ticks_over_travel'])
        p['pendulum_ticks_per_rev'] = float(p['pendulum_ticks_per_rev'])
        try:
            calibration = jp.Calibration(**p)
            config = BridgeConfig(calibration=calibration,
                                  command_timeout=self.get_parameter('command_timeout').value,
                                  sample_timeout=self.get_parameter('sample_timeout').value)
        except ValueError as exc:
            raise ValueError(f'hw_bridge: bad calibration parameters: {exc}') from exc
        port = self.get_parameter('port').value
        if not isinstance(port, str) or not port.strip():
            raise ValueError('hw_bridge: parameter port must name a serial device')

        self.core = BridgeCore(config)
        self.core.arm_requested = bool(self.get_parameter('armed').value)
        self._home_pending = bool(self.get_parameter('home_on_start').value)
        self._lock = threading.RLock()
        self._syncing = False

        self._joint_pub = self.create_publisher(JointState, 'joint_states', PUBLISH_DEPTH)
        self._health_pub = self.create_publisher(DiagnosticArray, 'cartpole/hw/health', 10)
        self._reset_pub = self.create_publisher(Header, 'cartpole/plant_reset', PLANT_RESET_QOS)
        self._applied_pub = self.create_publisher(TimeReference, 'cartpole/command_applied',
                                                  PUBLISH_DEPTH)
        self._homes_announced = 0
        self._version_logged: int | None = None
        self._received: dict[int, tuple[int, int]] = {}
        """Stamp [ns] of each recent published sample -> (node-clock time of its receipt
        [ns], its seq)."""
        self._stamp_of_seq: dict[int, int] = {}
        """seq of each recent published sample -> its stamp [ns]."""
        self._received_order: collections.deque = collections.deque()
        self.create_subscription(JointState, 'cartpole/force_command', self._on_force_command, 10)
        self.create_service(SetBool, '~/arm', self._on_arm)
        self.create_service(Trigger, '~/home', self._on_home)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(self.get_parameter('health_period').value, self._on_health_timer)
        port_id = str(self.get_parameter('port').value)
        self._health_report = HealthReport('hw_bridge', port_id, ('samples',), DEGRADED)
        self.diagnostics = NodeDiagnostics(self, 'serial link', port_id, self.health,
                                           inputs=('samples',), degraded=DEGRADED)

        self.link = SerialLink(self.core, port, self.get_parameter('baud').value,
                               on_sample=self._publish_sample,
                               reconnect_period=self.get_parameter('reconnect_period').value,
                               lock=self._lock, logger=self.get_logger().info)
        self.link.start()

    # -- samples and commands ------------------------------------------------------------------
    def _publish_sample(self, sample: JointSample) -> None:
        msg = JointState()
        stamp_ns, received_ns = self._node_time_ns(sample.stamp)
        msg.header.stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        self._note_receipt(stamp_ns, received_ns, sample.seq)
        if sample.applied is not None:
            self._publish_applied(sample, stamp_ns)
        if self.core.device_version != self._version_logged:
            self._log_version()
        msg.header.frame_id = ''
        msg.name = ['cart', 'pendulum']
        msg.position = [sample.x, sample.theta]
        homes = self.core.counts.homes
        if homes != self._homes_announced:
            self._homes_announced = homes
            self._reset_pub.publish(Header(stamp=msg.header.stamp))
        self._joint_pub.publish(msg)
        if self._home_pending and self.core.link_ready:
            self._home_pending = False
            ok, reason = self.link.call(lambda core, now: core.home(now))
            self.get_logger().info(f'home_on_start: {reason}')

    def _publish_applied(self, sample: JointSample, stamp_ns: int) -> None:
        """``/cartpole/command_applied`` for the command the device reports in force:
        ``time_ref`` the stamp given to the sample it answers, ``header.stamp`` when it
        took effect, on the node clock through the same offset as this sample's stamp."""
        applied = sample.applied
        source_ns = self._stamp_of_seq.get(applied.seq)
        if source_ns is None:   # not a sample published here (before a homing, say)
            return
        applied_ns = stamp_ns + int(round((applied.stamp - sample.stamp) * 1e9))
        msg = TimeReference()
        msg.header.stamp = Time(sec=applied_ns // 10**9, nanosec=applied_ns % 10**9)
        msg.time_ref = Time(sec=source_ns // 10**9, nanosec=source_ns % 10**9)
        msg.source = 'hw_bridge'
        self._applied_pub.publish(msg)

    def _log_version(self) -> None:
        """Say once (per device version seen) whether the loop's latency is reported."""
        version = self.core.device_version
        self._version_logged = version
        if version is None:
            return
        if self.core.tags_commands:
            self.get_logger().info(
                f'device speaks protocol {version}: commands tagged, the latency it reports '
                f'is published on /cartpole/command_applied')
        else:
            self.get_logger().warning(
                f'device speaks protocol {version}: it works, but reports no latency '
                f'(commands untagged, nothing on /cartpole/command_applied); flash the '
                f'protocol-{jp.PROTOCOL_VERSION} firmware for the latency compensation')

    def _note_receipt(self, stamp_ns: int, received_ns: int, seq: int) -> None:
        """Remember that the sample ``seq`` stamped ``stamp_ns`` was received at
        ``received_ns`` (node clock; the last :data:`RECEIPTS_KEPT`)."""
        self._received[stamp_ns] = (received_ns, seq)
        self._stamp_of_seq[seq] = stamp_ns
        self._received_order.append((stamp_ns, seq))
        while len(self._received_order) > RECEIPTS_KEPT:
            old_stamp, old_seq = self._received_order.popleft()
            self._received.pop(old_stamp, None)
            if self._stamp_of_seq.get(old_seq) == old_stamp:
                del self._stamp_of_seq[old_seq]

    def command_age(self, stamp_ns: int, now_ns: int) -> float:
        """Age [s] of a command answering the sample stamped ``stamp_ns``: from that
        sample's receipt when it is one of ours, else from the stamp itself."""
        received = self._received.get(stamp_ns)
        return (now_ns - (stamp_ns if received is None else received[0])) * 1e-9

    def sample_seq(self, stamp_ns: int) -> int | None:
        """``seq`` of the published sample stamped ``stamp_ns`` (None: not one of ours)."""
        received = self._received.get(stamp_ns)
        return None if received is None else received[1]

    def _node_time_ns(self, link_time: float) -> tuple[int, int]:
        """``link_time`` (the link's clock, monotonic) on the node clock [ns], and the node
        clock's reading it was mapped with (now) [ns]: the two clocks read back to back,
        again if something came between the reads."""
        clock, read = self.get_clock(), self.link.clock
        for _ in range(3):
            before = read()
            now_ns = clock.now().nanoseconds
            after = read()
            if after - before < 5e-5:
                break
        return now_ns - int(round((0.5 * (before + after) - link_time) * 1e9)), now_ns

    def _on_force_command(self, msg: JointState) -> None:
        try:
            force = float(msg.effort[list(msg.name).index('cart')]) if msg.name else float(msg.effort[0])
        except (ValueError, IndexError):
            with self._lock:
                self.core.counts.bad_commands += 1
            return
        stamp = msg.header.stamp
        latency = tag = None
        if stamp.sec or stamp.nanosec:
            stamp_ns = stamp.sec * 10**9 + stamp.nanosec
            latency = self.command_age(stamp_ns, self.get_clock().now().nanoseconds)
            tag = self.sample_seq(stamp_ns)
        self.link.call(lambda core, now: (True, '', core.on_command(force, now, latency, tag)))

    # -- arm / home --------------------------------------------------------------------------------
    def _on_arm(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        result = self.set_parameters([Parameter('armed', value=bool(request.data))])[0]
        response.success = result.successful
        response.message = result.reason or ('armed' if request.data else 'disarmed')
        return response

    def _on_home(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        ok, reason = self.link.call(lambda core, now: core.home(now))
        response.success, response.message = ok, reason
        return response

    # -- parameters ---------------------------------------------------------------------------------
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            if param.name == 'armed':
                if param.type_ != Parameter.Type.BOOL:
                    return SetParametersResult(successful=False, reason='armed must be a bool')
                if param.value and not self._syncing:
                    with self._lock:
                        refusal = self.core.arm_refusal()
                    if refusal:
                        return SetParametersResult(successful=False,
                                                   reason=f'cannot arm: {refusal}')
            if param.name in ('command_timeout', 'sample_timeout', 'reconnect_period'):
                value = param.value
                if not isinstance(value, float) or not math.isfinite(value) or value <= 0:
                    return SetParametersResult(successful=False,
                                               reason=f'{param.name} must be a finite number > 0')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for param in params:
            if param.name == 'armed' and not self._syncing:
                if param.value:
                    ok, reason = self.link.call(lambda core, now: core.arm(now))
                    self.get_logger().info(f'arm: {reason}')
                else:
                    self.link.call(lambda core, now: (True, '', core.disarm()))
                    self.get_logger().info('disarmed')
            elif param.name in ('command_timeout', 'sample_timeout'):
                with self._lock:
                    self.core.config = dataclasses.replace(self.core.config,
                                                           **{param.name: param.value})
            elif param.name == 'reconnect_period':
                self.link.reconnect_period = param.value

    # -- health -----------------------------------------------------------------------------------
    def _on_health_timer(self) -> None:
        with self._lock:
            values = self.core.health()
            armed, wanted = self.core.armed, self.core.arm_requested
            connected, link_ready = self.core.connected, self.core.link_ready
        if self.get_parameter('armed').value and not armed and not wanted:
            # a fault (or the link) disarmed the bridge: the parameter follows
            self._syncing = True
            try:
                self.set_parameters([Parameter('armed', value=False)])
            finally:
                self._syncing = False
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._health_report.status(self.health(values))]
        self._health_pub.publish(msg)

    def health(self, values: dict[str, str] | None = None) -> Health:
        """The bridge's health (``values``: the core's, read under the lock if not given):
        ERROR disconnected or disarmed by a fault, WARN waiting for the device's answer, OK
        armed or disarmed (idle); the reports add STALE when the samples stopped."""
        with self._lock:
            values = self.core.health() if values is None else values
            armed, connected = self.core.armed, self.core.connected
            link_ready, error = self.core.link_ready, self.core.last_error
        if not connected:
            return Health(ERROR, 'disconnected', values)
        if not link_ready:
            return Health(WARN, 'waiting for the device', values)
        if armed:
            return Health(OK, 'armed', values)
        if error:
            return Health(ERROR, f'disarmed: {error}', values)
        return Health(OK, 'disarmed', values)

    def destroy_node(self) -> None:
        """Zero force and disable on the way out, then close the port."""
        link = getattr(self, 'link', None)
        if link is not None:
            link.stop()
        super().destroy_node()


def main(args=None) -> None:
    run_node(HwBridgeNode, args, name='hw_bridge')

if __name__ == '__main__':
    main()
