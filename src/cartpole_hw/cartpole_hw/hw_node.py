"""ROS 2 managed (lifecycle) node ``hw_bridge``: the rig (or its emulator) on ``joint_states``
and ``cartpole/force_command`` through the Joint serial protocol.

The node only wires ROS to :class:`~cartpole_hw.serial_link.SerialLink` and
:class:`~cartpole_hw.bridge.BridgeCore`, where every safety rule lives. Armed
is its lifecycle state: configure opens the port and streams samples disarmed,
activate arms once the encoders are homed and the control loop is warm,
deactivate zeroes and disarms, a fault while active ends in ``on_error``
(port closed, unconfigured). It publishes ``joint_states`` (stamped with the
device's sampling time), ``cartpole/command_applied`` (the device's latency
report), ``cartpole/plant_reset`` after a homing and ``cartpole/hw/health``;
it forwards ``cartpole/force_command`` while active and offers ``~/home``.
Publishing happens in executor callbacks only: the link's reader thread hands
the samples over through a queue and wakes the executor (``create_task``; the
EventsExecutor of ``cartpole run`` refuses a node's own guard condition).
States, transitions, topics and health keys: docs/rig.md ("The lifecycle",
"/cartpole/hw/health").
"""
from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time

from builtin_interfaces.msg import Time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from . import protocol as jp
from .bridge import BridgeCore
from .bridge_records import JointSample
from .hw_parameters import bridge_config, declare_bridge_parameters
from .receipts import RECEIPTS_KEPT, ReceiptLog
from .serial_link import SerialLink
from cartpole_core.diagnostics import ERROR, OK, WARN, Health, HealthReport, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import COMMAND, RigLimits
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node

HANDSHAKE_TIMEOUT = 3.0
"""configure: longest wait for the device's ``V`` answer (and a homing's) [s]; the
bridge pings every 0.5 s until it answers."""

DEGRADED = ('lost_samples', 'seq_gaps', 'bad_lines', 'bad_samples', 'bad_commands',
            'stale_commands', 'watchdog_trips', 'device_watchdog_trips', 'reconnects')
"""Health counters whose growth since the previous report makes it WARN."""

SUCCESS, FAILURE, TRANSITION_ERROR = (TransitionCallbackReturn.SUCCESS,
                                      TransitionCallbackReturn.FAILURE,
                                      TransitionCallbackReturn.ERROR)


class HwBridgeNode(LifecycleNode):
    """Serial bridge to the Arduino Due I/O firmware (managed node ``hw_bridge``); what it
    decides is :class:`cartpole_hw.bridge.BridgeCore`'s."""

    def __init__(self, **kwargs) -> None:
        super().__init__('hw_bridge', **kwargs)
        try:
            self._start()
        except BaseException:   # refused: nothing of the node stays in the graph
            self.destroy_node()
            raise

    def _start(self) -> None:
        """The rest of ``__init__``: parameters, the core, topics, services, timers."""
        declare_bridge_parameters(self)
        config, self.port = bridge_config(self)
        self.inputs = InputGuard(self, RigLimits(
            travel=config.calibration.travel, stamp_tolerance=declare_stamp_tolerance(self)),
            ('cartpole/force_command',))
        """Judges every force command before it is taken (refused_inputs in the health)."""

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
        self.receipts = ReceiptLog(RECEIPTS_KEPT)
        """The recent published samples: stamp, receipt, seq (node clock)."""
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
        self.receipts.note(stamp_ns, received_ns, sample.seq)
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
        source_ns = self.receipts.stamp_of(applied.seq)
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

    def command_age(self, stamp_ns: int, now_ns: int) -> float:
        """Age [s] of a command answering the sample stamped ``stamp_ns`` (:class:`ReceiptLog`)."""
        return self.receipts.command_age(stamp_ns, now_ns)

    def sample_seq(self, stamp_ns: int) -> int | None:
        """``seq`` of the published sample stamped ``stamp_ns`` (None: not one of ours)."""
        return self.receipts.seq_of(stamp_ns)

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
        if not self.inputs.accept(msg, COMMAND, 'cartpole/force_command'):
            with self._lock:
                self.core.counts.bad_commands += 1
            return
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
        """The bridge's health (:meth:`_own_health`) with the input checks' counts (WARN
        once a force command was refused)."""
        return self.inputs.health(self._own_health(values, state))

    def _own_health(self, values: dict[str, str] | None = None,
                    state: str | None = None) -> Health:
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
