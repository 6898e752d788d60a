"""ROS 2 managed (lifecycle) node ``hw_bridge``: the rig (or its emulator) on ``/joint_states``
and ``/cartpole/force_command`` through the Joint serial protocol (docs/rig.md, "The Joint protocol").

The node only wires ROS to :class:`~cartpole_hw.serial_link.SerialLink` and
:class:`~cartpole_hw.bridge.BridgeCore`, where every rule lives (read
``bridge.py``'s docstring for the safety rules). Armed is its lifecycle state
(``rclpy.lifecycle``, the standard services ``~/change_state``,
``~/get_state``, ``~/get_available_transitions``, ... that ``ros2 lifecycle``
calls):

- **unconfigured** (at start): the port is closed;
- **configure**: opens the port (refused with the reason if it cannot be
  opened), handshakes (``V`` answer, refused if none within
  :data:`HANDSHAKE_TIMEOUT`), homes the encoders if ``home_on_start`` (once,
  the first configure), and streams samples, disarmed: **inactive**
  publishes ``/joint_states`` etc. with the amplifier disabled, re-opening a
  vanished port; ``~/home`` works here;
- **activate**: arms (``E,1``): the encoders homed and the control loop warm
  (20 fresh force commands in a row, :meth:`BridgeCore.activate`), else
  refused with the reason in the log; **active** forwards force commands;
- **deactivate**: ``U,0`` and ``E,0`` at once (the device's next sample shows
  zero), back to inactive, still streaming;
- **cleanup**: ``U,0``, ``E,0``, streaming off, port closed: unconfigured;
- **shutdown** (and ``destroy_node``) and **on_error**: the same, to
  finalized and unconfigured;
- **a fault while active** (the bridge's rules: a watchdog, a limit switch,
  a device fault, the port lost, ...): the core zeroes and disarms at once
  (reader thread); the executor then runs ``deactivate``, which returns ERROR,
  so rclpy runs ``on_error``: port closed, unconfigured (configure again to go
  on).

Publishing happens in executor callbacks only: the reader thread of the
link hands samples over through a queue and wakes the executor
(``create_task`` of the executor the node is in, which for rclpy's executors
triggers their guard condition; a guard condition of the node's own would do
the same there, but the EventsExecutor of ``cartpole run`` refuses nodes that
have one). The health timer drains the queue too, should a wake-up be lost.
What the reader thread and the callbacks share (the core, the receipts) is
under one lock. The publishers are plain ones, not lifecycle publishers: the
inactive state publishes the samples on purpose (the estimator and the
controller warm up on them before the amplifier is enabled).

Topics and services:

- publishes ``/joint_states`` (``cart``, ``pendulum``; x from the unwrapped
  cart count (2.4), theta = pi + pendulum count (2.3); ``header.stamp`` =
  the device's time of the sample, its ``t_us`` mapped to the host clock
  (:mod:`cartpole_hw.device_clock`: USB latency jitter does not reach the
  stamps) and read on the node clock), for every valid ``S`` line;
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
- ``~/home`` (std_srvs/Trigger) resets the encoders (configured and disarmed only);
- publishes ``/cartpole/hw/health`` (diagnostic_msgs/DiagnosticArray,
  status ``hw_bridge``) every ``health_period``, in every state, and the same health
  as ``hw_bridge: serial link`` on ``/diagnostics`` once a second (:meth:`HwBridgeNode.health`);
- publishes ``/cartpole/command_applied`` (sensor_msgs/TimeReference,
  ``source='hw_bridge'``), once for every command the
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
import time

from builtin_interfaces.msg import Time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from . import protocol as jp
from .bridge import BridgeConfig, BridgeCore, JointSample
from .serial_link import SerialLink
from cartpole_core.diagnostics import ERROR, OK, WARN, Health, HealthReport, NodeDiagnostics
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node

RECEIPTS_KEPT = 400
"""Receipt times kept for the command-age rule (2 s of samples at 200 Hz); also the
most samples waiting for the executor (older ones are dropped, ``handoff_dropped``)."""
HANDSHAKE_TIMEOUT = 3.0
"""configure: longest wait for the device's ``V`` answer (and a homing's) [s]; the
bridge pings every 0.5 s until it answers."""

DEGRADED = ('lost_samples', 'seq_gaps', 'bad_lines', 'bad_samples', 'bad_commands',
            'stale_commands', 'watchdog_trips', 'device_watchdog_trips', 'reconnects')
"""Health counters whose growth since the previous report makes it WARN."""

_CALIBRATION = ('cart_sign', 'pendulum_sign', 'force_sign', 'cart_ticks_over_travel', 'travel',
                'pendulum_ticks_per_rev', 'setpoint_per_newton', 'dac_zero')
SUCCESS, FAILURE, TRANSITION_ERROR = (TransitionCallbackReturn.SUCCESS,
                                      TransitionCallbackReturn.FAILURE,
                                      TransitionCallbackReturn.ERROR)


class HwBridgeNode(LifecycleNode):
    """Serial bridge to the Arduino Due I/O firmware (managed node ``hw_bridge``).

    Why one class of about 330 lines: a node adapter whose ``__init__`` declares the
    bridge's parameters, topics and services, and whose transition callbacks open,
    arm, disarm and close the link; everything it decides is
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
                        '/tmp/cartpole-emu); opened by configure, re-opened after a '
                        'disconnect while inactive', **ro))
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
                        'active [s]; a trip sends U,0 and E,0 and ends in on_error',
            floating_point_range=fp(0.005, 1.0)))
        self.declare_parameter('sample_timeout', 0.05, ParameterDescriptor(
            description='longest gap between valid samples while active before the fault [s]',
            floating_point_range=fp(0.01, 1.0)))
        self.declare_parameter('reconnect_period', 0.5, ParameterDescriptor(
            description='period of the attempts to re-open a vanished port while inactive [s]',
            floating_point_range=fp(0.05, 10.0)))
        self.declare_parameter('health_period', 0.2, ParameterDescriptor(
            description='period of /cartpole/hw/health [s]', floating_point_range=fp(0.02, 10.0),
            **ro))
        self.declare_parameter('home_on_start', False, ParameterDescriptor(
            description='reset the encoders (R) at the first configure, once the device '
                        'answers; the cart must be at the left stop and the pendulum hanging '
                        'still', **ro))

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
        self.port = port

        self.core = BridgeCore(config)
        self._lock = threading.RLock()
        """Guards the core (shared with the link) and the receipts below."""
        self.link: SerialLink | None = None
        """The open link while configured (inactive or active), else None."""
        self._home_pending = bool(self.get_parameter('home_on_start').value)
        self._active = False
        self._fault: str | None = None
        """Why the executor is taking the node out of active (a fault), until on_error."""
        self._last_refusal = ''
        self._down_reason = ''
        """Why the bridge is unconfigured, if not by choice: a fault (on_error) or a refused
        configure ('' after a configure or a cleanup)."""

        self._handoff: collections.deque[JointSample] = collections.deque()
        self._handoff_lock = threading.Lock()
        self._drain_scheduled = False
        self.handoff_dropped = 0
        """Samples dropped because the executor had not taken :data:`RECEIPTS_KEPT` yet."""

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
        self.create_service(Trigger, '~/home', self._on_home)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(self.get_parameter('health_period').value, self._on_health_timer)
        port_id = str(self.get_parameter('port').value)
        self._health_report = HealthReport('hw_bridge', port_id, ('samples',), DEGRADED)
        self.diagnostics = NodeDiagnostics(self, 'serial link', port_id, self.health,
                                           inputs=('samples',), degraded=DEGRADED)

    # -- lifecycle ---------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Open the port, handshake, (home once if asked,) stream samples disarmed."""
        link = SerialLink(self.core, self.port, self.get_parameter('baud').value,
                          notify=self._hand_over,
                          reconnect_period=self.get_parameter('reconnect_period').value,
                          lock=self._lock, logger=self.get_logger().info)
        reason = link.open()
        if reason:
            return self._refuse('configure', f'cannot open {self.port}: {reason}')
        link.start()
        self.link = link
        if not link.wait_for(lambda core: core.link_ready, HANDSHAKE_TIMEOUT):
            with self._lock:
                last = self.core.last_error
            why = f'the device did not answer the ping (no V line within ' \
                  f'{HANDSHAKE_TIMEOUT:g} s)' + (f'; last error: {last}' if last else '')
            self._close()
            return self._refuse('configure', why)
        if self._home_pending:
            self._home_pending = False
            ok, reason = link.call(lambda core, now: core.home(now))
            done = ok and link.wait_for(lambda core: not core.homing, HANDSHAKE_TIMEOUT)
            with self._lock:
                homed = self.core.homed and done
            log = self.get_logger().info if homed else self.get_logger().warning
            log(f'home_on_start: {"encoders homed" if homed else self.core.last_error or reason}')
        self._down_reason = ''
        self._log_transition('configured: streaming samples, disarmed')
        return SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Arm: homed encoders and a warm control loop (the core's rule), else refused."""
        ok, reason = self.link.call(lambda core, now: core.activate(now))
        if not ok:
            return self._refuse('activate', reason)
        self._active = True
        self._log_transition('active: armed, forwarding force commands')
        return SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Zero force and disarm at once (``U,0``, ``E,0``); ERROR if a fault brought us here."""
        self._active = False
        self.link.call(lambda core, now: (True, '', core.disarm()))
        if self._fault is not None:
            self.get_logger().error(f'fault while active: {self._fault}; disarmed (U,0, E,0), '
                                    f'closing the port (on_error)')
            return TRANSITION_ERROR
        self._log_transition('inactive: disarmed (U,0, E,0), streaming samples')
        return SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        self._down_reason = ''
        self._log_transition('unconfigured: port closed')
        return SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close()
        return SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Zero, disarm and close, whatever failed: unconfigured (configure to go on)."""
        self._close()
        self._down_reason = f'fault while active: {self._fault}' if self._fault else \
            f'error in a transition from {state.label}'
        self._fault = None
        self.get_logger().error('on_error: disarmed, port closed; unconfigured')
        return SUCCESS

    def _close(self) -> None:
        """Zero force, disable, stop streaming, close the port (if open); drop pending samples."""
        self._active = False
        link, self.link = self.link, None
        if link is not None:
            link.stop()
        with self._handoff_lock:
            self._handoff.clear()

    def _refuse(self, transition: str, reason: str) -> TransitionCallbackReturn:
        """Log why a transition is refused: a warning, then debug while the gist of the
        reason (up to its colon, without the counts) stays the same (a caller retrying)."""
        gist = f'{transition}: {reason.split(":")[0]}'
        log = self.get_logger().debug if gist == self._last_refusal else \
            self.get_logger().warning
        self._last_refusal = gist
        log(f'{transition} refused: {reason}')
        if transition == 'configure':
            self._down_reason = f'configure refused: {reason}'
        return FAILURE

    def _log_transition(self, text: str) -> None:
        self._last_refusal = ''
        self.get_logger().info(text)

    def destroy_node(self) -> None:
        """Zero force and disable on the way out, then close the port (the shutdown
        transition, or the same directly if the context is gone)."""
        if getattr(self, 'link', None) is not None:
            try:
                self.trigger_shutdown()
            except Exception:  # noqa: BLE001 - the context may be shut down: close anyway
                self._close()
        super().destroy_node()
        # rclpy 7 leaves the lifecycle state machine (which holds the rcl node) to the
        # garbage collector: until then the node, and its context's participant, stay in
        # the ROS graph as a stale /hw_bridge
        self._state_machine.destroy_when_not_in_use()

    # -- samples: reader thread -> executor ----------------------------------------------------
    def _hand_over(self, samples: list[JointSample]) -> None:
        """Reader thread: queue the samples (or a fault) and wake the executor. Nothing else."""
        with self._handoff_lock:
            for sample in samples:
                if len(self._handoff) >= RECEIPTS_KEPT:
                    self._handoff.popleft()
                    self.handoff_dropped += 1
                self._handoff.append(sample)
            wake, self._drain_scheduled = not self._drain_scheduled, True
        if not wake:
            return
        executor = self.executor
        try:
            executor.create_task(self._drain)
        except Exception:  # noqa: BLE001 - no executor (yet), or shut down: the timer drains
            with self._handoff_lock:
                self._drain_scheduled = False

    def _drain(self) -> None:
        """Executor: publish the samples handed over, then act on a fault while active."""
        with self._handoff_lock:
            self._drain_scheduled = False
            batch = list(self._handoff)
            self._handoff.clear()
        offset_ns = self._clock_offset_ns() if batch else 0
        for sample in batch:
            self._publish_sample(sample, offset_ns)
        if batch and self.core.device_version != self._version_logged:
            self._log_version()
        with self._lock:
            faulted = self._active and not self.core.armed
            reason = self.core.last_error
        if faulted and self._fault is None:
            self._fault = reason or 'disarmed'
            self._publish_health()      # the reason, ahead of the transition events
            self.trigger_deactivate()   # on_deactivate returns ERROR: rclpy runs on_error

    def _publish_sample(self, sample: JointSample, offset_ns: int) -> None:
        """Publish one sample; ``offset_ns``: node clock minus the link's clock [ns]."""
        msg = JointState()
        stamp_ns = offset_ns + int(round(sample.stamp * 1e9))
        received_ns = offset_ns + int(round(sample.receipt * 1e9))
        msg.header.stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        self._note_receipt(stamp_ns, received_ns, sample.seq)
        if sample.applied is not None:
            self._publish_applied(sample, stamp_ns)
        msg.header.frame_id = ''
        msg.name = ['cart', 'pendulum']
        msg.position = [sample.x, sample.theta]
        with self._lock:
            homes = self.core.counts.homes
        if homes != self._homes_announced:
            self._homes_announced = homes
            self._reset_pub.publish(Header(stamp=msg.header.stamp))
        self._joint_pub.publish(msg)

    def _publish_applied(self, sample: JointSample, stamp_ns: int) -> None:
        """``/cartpole/command_applied`` for the command the device reports in force:
        ``time_ref`` the stamp given to the sample it answers, ``header.stamp`` when it
        took effect, on the node clock through the same offset as this sample's stamp."""
        applied = sample.applied
        with self._lock:
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
        with self._lock:
            version, tags = self.core.device_version, self.core.tags_commands
        self._version_logged = version
        if version is None:
            return
        if tags:
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
        with self._lock:
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
        with self._lock:
            received = self._received.get(stamp_ns)
        return (now_ns - (stamp_ns if received is None else received[0])) * 1e-9

    def sample_seq(self, stamp_ns: int) -> int | None:
        """``seq`` of the published sample stamped ``stamp_ns`` (None: not one of ours)."""
        with self._lock:
            received = self._received.get(stamp_ns)
        return None if received is None else received[1]

    def _clock_offset_ns(self) -> int:
        """Node clock minus the link's clock (monotonic) [ns], from the two read back to
        back: the tightest of a few readings (one interrupted by a thread switch is wide)."""
        clock, read = self.get_clock(), time.monotonic   # the link's clock
        best = None
        for _ in range(8):
            before = read()
            now_ns = clock.now().nanoseconds
            after = read()
            if best is None or after - before < best[0]:
                best = (after - before, now_ns - int(round(0.5 * (before + after) * 1e9)))
            if after - before < 2e-5:
                break
        return best[1]

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
        link = self.link
        if link is None:   # unconfigured: nothing to send, the command still counts
            with self._lock:
                self.core.on_command(force, time.monotonic(), latency, tag)
            return
        link.call(lambda core, now: (True, '', core.on_command(force, now, latency, tag)))

    # -- home --------------------------------------------------------------------------------------
    def _on_home(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        link = self.link
        if link is None:
            response.success = False
            response.message = 'not configured: configure first (ros2 lifecycle set /hw_bridge configure)'
            return response
        ok, reason = link.call(lambda core, now: core.home(now))
        response.success, response.message = ok, reason
        return response

    # -- parameters ---------------------------------------------------------------------------------
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for param in params:
            if param.name in ('command_timeout', 'sample_timeout', 'reconnect_period'):
                value = param.value
                if not isinstance(value, float) or not math.isfinite(value) or value <= 0:
                    return SetParametersResult(successful=False,
                                               reason=f'{param.name} must be a finite number > 0')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for param in params:
            if param.name in ('command_timeout', 'sample_timeout'):
                with self._lock:
                    self.core.config = dataclasses.replace(self.core.config,
                                                           **{param.name: param.value})
            elif param.name == 'reconnect_period' and self.link is not None:
                self.link.reconnect_period = param.value

    # -- health -----------------------------------------------------------------------------------
    def _on_health_timer(self) -> None:
        self._drain()   # should a wake-up have been lost
        self._publish_health()

    def _publish_health(self) -> None:
        state = self._state_machine.current_state[1]   # rclpy 7 has no public accessor
        with self._lock:
            values = self.core.health()
        with self._handoff_lock:
            dropped = self.handoff_dropped
        values = {'state': state, **values, 'handoff_dropped': str(dropped)}
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self._health_report.status(self.health(values, state))]
        self._health_pub.publish(msg)

    def health(self, values: dict[str, str] | None = None, state: str | None = None) -> Health:
        """The bridge's health (``values``: the core's, read under the lock if not given;
        ``state``: the lifecycle's): unconfigured is OK (idle, port closed; its sample count
        left out: no samples is no staleness then) or ERROR after a fault or a refused
        configure; configured: ERROR disconnected or disarmed by a fault, WARN waiting for
        the device's answer, OK armed or disarmed (idle); the reports add STALE when the
        samples stopped."""
        state = state or self._state_machine.current_state[1]
        with self._lock:
            if values is None:
                values = {'state': state, **self.core.health()}
            armed, connected = self.core.armed, self.core.connected
            link_ready, error = self.core.link_ready, self.core.last_error
        if state not in ('inactive', 'active'):
            values = {k: v for k, v in values.items() if k != 'samples'}
            if self._down_reason:
                return Health(ERROR, f'{state}: {self._down_reason}', values)
            return Health(OK, f'{state}: port closed', values)
        if not connected:
            return Health(ERROR, 'disconnected', values)
        if not link_ready:
            return Health(WARN, 'waiting for the device', values)
        if armed:
            return Health(OK, 'armed', values)
        if error:
            return Health(ERROR, f'disarmed: {error}', values)
        return Health(OK, 'disarmed', values)


def main(args=None) -> None:
    run_node(HwBridgeNode, args, name='hw_bridge')

if __name__ == '__main__':
    main()
