"""The ``controller_manager`` node: :class:`~cartpole_control.manager.ControllerManager` on ROS.

Wiring only; every decision is the manager's. Each ``cartpole/state``
(JointState, joints ``cart``/``pendulum``) runs one control cycle at once and
publishes ``cartpole/force_command`` (``effort=[F]``, the state's stamp),
``cartpole/force_acting`` (for the EKF) and ``cartpole/controller_status``; a
repeated stamp gets the same answer again. With ``lockstep:=true`` a state's
cycle waits (at most ``lockstep_wait``; the first one, while the graph
discovers, up to 10 s) for the encoders' sample it was estimated from, so
lockstep runs are the same run whatever the delivery order. The plugins'
parameters are ROS parameters: validated (and the new plugin staged) in the
on-set callback, queued in the post-set callback, swapped in between two
cycles. A stale-state timer on the node clock faults with zero force when the
states stop for ``state_timeout`` of this process's running time.
``~/restart_swingup`` starts a new swing-up; ``cartpole/plant_reset`` starts one
from the first state after the reset.
Health on ``/diagnostics`` (``controller_manager: control``); the package's
Python loggers go to ``/rosout`` while the node lives; zero force on shutdown.
Topics, parameters and guards in detail: docs/controller_manager.md.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from cartpole_core.diagnostics import ERROR, OK, STALE, Health, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import SAMPLE, STATE, RigLimits
from cartpole_core.model import CartPoleParameters
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node
from cartpole_core.realtime import CycleGapMeter, collect_when_idle
from cartpole_core.ros_logging import route_to_node

from .controller import ControllerState
from .manager import FAULT, IDLE, STATUS_KEYS, ControllerManager, ManagerOutput
from .manager_parameters import LOCKSTEP_WAIT_RANGE
from .parameter_descriptors import descriptor_for, manager_value, ros_value
from .status_message import NODE_NAME, status_message

__all__ = ['ControllerManagerNode', 'STATUS_KEYS', 'descriptor_for', 'main', 'status_message']

CART_JOINT = 'cart'
PENDULUM_JOINT = 'pendulum'
STALE_CHECK_PERIOD = 0.01
"""Period of the stale-state check on the node clock [s]."""
STALE_CHECK_SLACK = 2 * STALE_CHECK_PERIOD
"""Most of one interval between two stale checks counted as time without a state [s];
a longer interval is a stall of this process (module docstring)."""
STARTUP_SAMPLE_WAIT = 10.0
"""Lockstep: wall seconds the first state waits for its sample before any has arrived (the
graph may still be discovering: up to about 3 s with Fast DDS); later states wait
``lockstep_wait``."""
LAST_COMMAND_ACK_TIMEOUT = 1.0
"""Longest wait on shutdown for every subscriber to acknowledge the last zero force [s]
(a dead subscriber never does; the node goes after this)."""


def load_plant_parameters(path: str) -> CartPoleParameters:
    """The controllers' plant model: the thesis values, or a CartPoleParameters YAML file."""
    if not path:
        return CartPoleParameters()
    if not Path(path).is_file():
        raise ValueError(f'plant_params_file {path!r} does not exist')
    return CartPoleParameters.from_yaml(path)


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _stamp_seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


class ControllerManagerNode(Node):
    """The controller manager node (name ``controller_manager``); see the module docstring."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # Before the manager exists: a plugin its registry refuses is logged on /rosout.
        self._log_route = route_to_node(self, 'cartpole_control')
        try:
            self._start()
        except BaseException:  # refused to start: the loggers are no longer routed here
            self._log_route.remove()
            Node.destroy_node(self)   # and nothing of the node stays in the graph
            raise

    def _start(self) -> None:
        """The rest of ``__init__``: parameters, the manager, topics, services, timers."""
        self.declare_parameter('plant_params_file', '', ParameterDescriptor(
            description="YAML of the controllers' plant model (CartPoleParameters); '' = the "
                        'thesis values', read_only=True))
        self.declare_parameter('lockstep', False, ParameterDescriptor(
            description='Lockstep simulation: run the control cycle of a state only once the '
                        "encoders' sample it was estimated from has arrived on joint_states, so "
                        "the plant's reports and samples before it are taken first "
                        '(deterministic whatever the delivery order).', read_only=True))
        self.declare_parameter('lockstep_wait', 0.5, ParameterDescriptor(
            description='Lockstep: longest wait for that sample [wall s]; then the cycle runs '
                        'without it.', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=LOCKSTEP_WAIT_RANGE[0],
                                                     to_value=LOCKSTEP_WAIT_RANGE[1], step=0.0)]))
        self.declare_parameter('sample_time', 0.005, ParameterDescriptor(
            description='Control period Ts [s] the plugins are designed for', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=1e-4, to_value=0.1, step=0.0)]))
        plant = load_plant_parameters(self.get_parameter('plant_params_file').value)
        self.manager = ControllerManager(plant, self.get_parameter('sample_time').value)
        self.inputs = InputGuard(self, RigLimits.from_parameters(
            plant, stamp_tolerance=declare_stamp_tolerance(self)),
            ('cartpole/state', 'joint_states', 'cartpole/plant_reset', 'cartpole/command_applied'))
        """Judges every message before it is taken (refused_inputs in the health)."""
        self._specs = self.manager.parameter_specs()
        for name, spec in self._specs.items():
            self.declare_parameter(name, ros_value(spec, spec.default), descriptor_for(spec))
        initial = {}
        for name, spec in self._specs.items():
            value = manager_value(self.get_parameter(name).value)
            if value != spec.default:
                initial[name] = value
        result = self.manager.set_parameters(initial)
        if not result.successful:  # a bad parameter file: refuse to start, say why
            raise ValueError(f'controller_manager: invalid parameters: {result.reason}')
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        self._pub_force = self.create_publisher(JointState, 'cartpole/force_command',
                                                PUBLISH_DEPTH)
        self._pub_acting = self.create_publisher(JointState, 'cartpole/force_acting',
                                                 PUBLISH_DEPTH)
        self._pub_status = self.create_publisher(DiagnosticArray, 'cartpole/controller_status',
                                                 PUBLISH_DEPTH)
        # Created before the state subscription: when several are ready at once, the
        # executor hands over the reset, then what the plant reported (when each command
        # took effect: the loop's latency; the encoders' samples: the pendulum's natural
        # frequency and the actuator), then the state.
        self.create_subscription(Header, 'cartpole/plant_reset', self._on_plant_reset,
                                 PLANT_RESET_QOS)
        self.create_subscription(TimeReference, 'cartpole/command_applied',
                                 self._on_command_applied, PUBLISH_DEPTH)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                 PUBLISH_DEPTH)
        self.create_subscription(JointState, 'cartpole/state', self._on_state, 10)
        self._lockstep = bool(self.get_parameter('lockstep').value)
        self._newest_sample_ns: int | None = None
        """Stamp of the newest encoders' sample received on joint_states [ns]."""
        self._held_state: JointState | None = None
        """Lockstep: a state whose sample has not arrived yet (see _on_state)."""
        self._held_since = 0.0
        """time.monotonic() when the held state's stamp was first held [s]."""
        self.lockstep_timeouts = 0
        """Lockstep: states run without their sample after lockstep_wait."""
        self._hold_timer = None
        self._stale_floor = 0.0
        """Lockstep: silence up to lockstep_wait is the graph's scheduling, not a stale state
        (an EKF descheduled 60 ms on a loaded machine faulted a lockstep run)."""
        if self._lockstep:
            self._stale_floor = float(self.get_parameter('lockstep_wait').value)
            self._hold_timer = self.create_timer(
                self._stale_floor, self._on_hold_timeout,
                clock=Clock(clock_type=ClockType.STEADY_TIME))
            self._hold_timer.cancel()
        self.create_service(Trigger, '~/restart_swingup', self._on_restart)
        self._reset_from: float | None = None
        """Stamp [s] of a plant reset not yet handed over (see _on_plant_reset)."""
        self._last_check_ns: int | None = None
        self.cycle_gaps = CycleGapMeter()
        self.cycle_compute = 0.0
        """Compute time of the last control cycle (the manager's update) [s]."""
        self.max_cycle_compute = 0.0
        """The longest control cycle since start [s]."""
        self._last_state_ns: int | None = None
        self._silent_ns = 0
        """Running time without a state since the last one [ns] (see _check_stale)."""
        self._last_stamp = None
        self._last_command: JointState | None = None
        self._stale = False
        self.bad_states = 0
        """State messages without the cart/pendulum positions and velocities (ignored)."""
        self.create_timer(STALE_CHECK_PERIOD, self._check_stale)
        self.diagnostics = NodeDiagnostics(self, 'control', 'cartpole', self.health,
                                           inputs=('states',),
                                           degraded=('bad_states', 'lockstep_timeouts'))
        values = self.manager.get_parameters()
        self.get_logger().info(
            f"controller_manager: swing-up {values['swingup']}, stabiliser "
            f"{values['stabilizer']}, enabled {values['enabled']}, x_ref {values['x_ref']:g} m")

    # -- parameters ----------------------------------------------------------------------
    def _changes(self, parameters: list[Parameter]) -> dict[str, Any]:
        return {p.name: manager_value(p.value) for p in parameters if p.name in self._specs}

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Refuse a change the manager would refuse (reason included); nothing changes then.

        The check builds and configures what the change needs (outside the
        control cycle); :meth:`_apply_parameters` queues that very instance."""
        result = self.manager.check_parameters(self._changes(parameters))
        if not result.successful:
            self.get_logger().warning(f'parameter change refused: {result.reason}')
        return SetParametersResult(successful=result.successful, reason=result.reason)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Queue accepted changes; the manager applies them before its next cycle."""
        changes = self._changes(parameters)
        if changes:
            result = self.manager.set_parameters(changes)
            if not result.successful:  # cannot happen after the on-set check; say so if it does
                self.get_logger().error(f'parameter change not taken: {result.reason}')

    # -- the control cycle (latency path) ------------------------------------------------------
    def _on_state(self, msg: JointState) -> None:
        """One control cycle; in lockstep, once the state's own sample has arrived.

        The EKF estimates the state at t from the sample stamped t, published
        by the plant after its reports and samples before t; so once that sample
        is here, everything the cycle at t takes (:meth:`ControllerManager._take_reports`)
        has been handed over (the subscriptions are created in that order), and
        two lockstep runs are the same run however the processes are scheduled.
        In real time the cycle runs at once: the latency path does not wait.
        """
        if not self.inputs.accept(msg, STATE, 'cartpole/state'):
            self.bad_states += 1
            return
        if self._lockstep:
            newest = self._newest_sample_ns
            stamp_ns = _stamp_ns(msg.header.stamp)
            if newest is None or newest < stamp_ns:
                held = self._held_state
                if held is None or _stamp_ns(held.header.stamp) != stamp_ns:
                    # The same state again (the simulator re-publishes sample 0 until the
                    # loop answers) keeps waiting on the first one's timer; a newer one
                    # releases the old.
                    if held is not None:
                        self._release_held_state()
                    self._hold_timer.reset()
                    self._held_since = time.monotonic()
                self._held_state = msg
                self._last_state_ns = self.get_clock().now().nanoseconds  # the EKF is not silent
                self._silent_ns = 0
                return
        self._control_cycle(msg)

    def _release_held_state(self) -> None:
        msg, self._held_state = self._held_state, None
        self._hold_timer.cancel()
        self._control_cycle(msg)

    def _on_hold_timeout(self) -> None:
        if self._held_state is None:
            self._hold_timer.cancel()
            return
        if self._newest_sample_ns is None and \
                time.monotonic() - self._held_since < STARTUP_SAMPLE_WAIT:
            return  # the graph may still be discovering: joint_states not yet matched
        self.lockstep_timeouts += 1
        self.get_logger().warning(
            f'lockstep: the sample of the state at t = '
            f'{_stamp_seconds(self._held_state.header.stamp):.3f} s did not arrive on '
            f'joint_states within lockstep_wait; the cycle runs without it',
            throttle_duration_sec=5.0)
        self._release_held_state()

    def _control_cycle(self, msg: JointState) -> None:
        last = self._last_stamp
        if last is not None and self._last_command is not None and \
                msg.header.stamp.sec == last.sec and msg.header.stamp.nanosec == last.nanosec:
            self._pub_force.publish(self._last_command)  # the same sample: the same answer
            self._last_state_ns = self.get_clock().now().nanoseconds
            self._silent_ns = 0
            return
        try:
            c = msg.name.index(CART_JOINT)
            p = msg.name.index(PENDULUM_JOINT)
            state = ControllerState(_stamp_seconds(msg.header.stamp), msg.position[c],
                                    msg.position[p], msg.velocity[c], msg.velocity[p])
        except (ValueError, IndexError):
            self.bad_states += 1
            self.get_logger().warning(
                '/cartpole/state needs position and velocity of joints cart and pendulum; '
                'message ignored', throttle_duration_sec=1.0)
            return
        self.cycle_gaps.tick()
        reset = self._reset_from is not None and state.t >= self._reset_from
        if reset:
            self._reset_from = None
            self.manager.reset()
        started = time.perf_counter()
        out = self.manager.update(state)
        self.cycle_compute = compute = time.perf_counter() - started
        if compute > self.max_cycle_compute:
            self.max_cycle_compute = compute
        force = JointState()
        force.header.stamp = msg.header.stamp
        force.name = [CART_JOINT]
        force.effort = [out.force]
        self._pub_force.publish(force)
        self._publish_acting(state.t, out.force, msg.header.stamp)
        self._last_command = force
        self._last_state_ns = self.get_clock().now().nanoseconds
        self._silent_ns = 0
        self._last_stamp = msg.header.stamp
        self._stale = False
        self._publish_status(out, msg.header.stamp, 'plant_reset' if reset else '')
        self.manager.between_cycles()  # the command is out: work ahead (the MPC's catch QP)
        collect_when_idle()  # the command is out: the loop has time until the next sample

    def _publish_acting(self, t: float, command: float, stamp) -> None:
        """``cartpole/force_acting``: the force the cart feels over the next interval by the
        plant estimate (:meth:`PlantEstimate.force_for_filter`); what the EKF predicts with."""
        msg = JointState()
        msg.header.stamp = stamp
        msg.name = [CART_JOINT]
        msg.effort = [self.manager.plant_estimate.force_for_filter(t, command)]
        self._pub_acting.publish(msg)

    def _on_command_applied(self, msg: TimeReference) -> None:
        if not self.inputs.accept_stamps('cartpole/command_applied', msg.header.stamp,
                                         msg.time_ref):
            return
        self.manager.command_applied(_stamp_seconds(msg.time_ref), _stamp_seconds(msg.header.stamp))

    def _on_joint_states(self, msg: JointState) -> None:
        if not self.inputs.accept(msg, SAMPLE, 'joint_states'):
            return
        stamp_ns = _stamp_ns(msg.header.stamp)
        if self._newest_sample_ns is not None and stamp_ns <= self._newest_sample_ns:
            return  # a re-published sample 0, or one overtaken: the estimates have it or a newer
        self._newest_sample_ns = stamp_ns
        try:
            self._measured(msg)
        finally:
            held = self._held_state
            if held is not None and self._newest_sample_ns >= _stamp_ns(held.header.stamp):
                self._release_held_state()

    def _measured(self, msg: JointState) -> None:
        try:
            c = msg.name.index(CART_JOINT)
            p = msg.name.index(PENDULUM_JOINT)
            x, theta = float(msg.position[c]), float(msg.position[p])
        except (ValueError, IndexError):
            return  # the EKF reports a bad measurement; the estimate just skips it
        if math.isfinite(x) and math.isfinite(theta):
            self.manager.measured(_stamp_seconds(msg.header.stamp), x, theta)

    def _on_plant_reset(self, msg: Header) -> None:
        if not self.inputs.accept_stamps('cartpole/plant_reset', msg.stamp):
            return
        self._reset_from = _stamp_seconds(msg.stamp)
        self.get_logger().info(f'plant reset at t = {self._reset_from:.3f} s: a new swing-up '
                               'starts from the first state after it')

    def _publish_status(self, out: ManagerOutput, stamp, extra_event: str = '') -> None:
        self._pub_status.publish(status_message(out, stamp, self.cycle_gaps.longest,
                                                extra_event, self.cycle_compute,
                                                self.max_cycle_compute))
        if out.event.startswith('fault') or ';fault' in out.event:
            self.get_logger().error(f'fault: {out.fault_reason}; zero force until '
                                    '~/restart_swingup')
        elif out.event:
            self.get_logger().info(f'{out.event} at t = {out.t:.3f} s')

    def _check_stale(self) -> None:
        now = self.get_clock().now()
        previous, self._last_check_ns = self._last_check_ns, now.nanoseconds
        if self._last_state_ns is None or self._stale:
            return
        # Time without a state since the later of the last state and the last check; of
        # an interval longer than the slack this process was stalled for the rest (the
        # states may be waiting in the subscription: they get their turn; the stall
        # shows in longest_cycle_gap_s).
        since = self._last_state_ns if previous is None else max(self._last_state_ns, previous)
        self._silent_ns += min(max(now.nanoseconds - since, 0), int(STALE_CHECK_SLACK * 1e9))
        if self._silent_ns * 1e-9 <= max(self.manager.state_timeout, self._stale_floor):
            return
        self._stale = True
        stamp = now.to_msg()
        if self._last_stamp is not None:
            # In the states' own clock (the simulator's in a sim run; a wall-clock stamp
            # there sorts after the whole run in a bag): the last state's, plus the silence.
            ns = _stamp_ns(self._last_stamp) + max(now.nanoseconds - self._last_state_ns, 0)
            stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
        out = self.manager.stale(_stamp_seconds(stamp))
        self.publish_zero(stamp)
        self._publish_status(out, stamp)

    # -- health ------------------------------------------------------------------------------
    def health(self) -> Health:
        """The manager's health for ``/diagnostics`` with the input checks' counts
        (:meth:`_own_health`; WARN once an input was refused)."""
        return self.inputs.health(self._own_health())

    def _own_health(self) -> Health:
        """The manager's health for ``/diagnostics`` (``controller_manager: control``): OK
        while it controls or idles (no state yet, control disabled), ERROR in a fault, STALE
        while the states have stopped (the stale-state fault); WARN when states were ignored
        since the previous report. The 200 Hz status stays the loop's telemetry."""
        m = self.manager
        plugins = m.active_plugins()
        values = {
            'mode': m.mode, 'enabled': m.enabled, 'fault_reason': m.fault_reason,
            **{kind: plugin.name for kind, plugin in sorted(plugins.items())},
            'catch_count': m.catch_count, 'fall_count': m.fall_count,
            'states': self.cycle_gaps.cycles, 'bad_states': self.bad_states,
            'lockstep_timeouts': self.lockstep_timeouts,
            'state_stamp': 0.0 if self._last_stamp is None else _stamp_seconds(self._last_stamp),
            'longest_cycle_gap_s': self.cycle_gaps.longest,
            'cycle_compute_s': self.cycle_compute, 'max_cycle_compute_s': self.max_cycle_compute,
        }
        restart = 'zero force until ~/restart_swingup'
        if m.mode == FAULT and self._stale:
            return Health(STALE, f'no state for state_timeout: fault ({m.fault_reason}); '
                                 f'{restart}', values)
        if m.mode == FAULT:
            return Health(ERROR, f'fault: {m.fault_reason}; {restart}', values)
        if self._last_state_ns is None:
            return Health(OK, 'waiting for /cartpole/state', values)
        if m.mode == IDLE:
            return Health(OK, 'idle' if m.enabled else 'idle: control disabled (enabled = false)',
                          values)
        return Health(OK, m.mode, values)

    # -- services and shutdown ---------------------------------------------------------------------
    def _on_restart(self, request, response):
        answer = self.manager.restart()
        response.success, response.message = answer.successful, answer.reason
        self.get_logger().info(f'restart_swingup: {response.message}')
        return response

    def publish_zero(self, stamp=None) -> None:
        """Publish a zero force command (stamp: the given one, else the last state's, else now)."""
        if not self.context.ok():
            return
        msg = JointState()
        if stamp is None:
            stamp = self._last_stamp if self._last_stamp is not None else \
                self.get_clock().now().to_msg()
        msg.header.stamp = stamp
        msg.name = [CART_JOINT]
        msg.effort = [0.0]
        self._pub_force.publish(msg)

    def destroy_node(self) -> None:
        """Command zero force, wait until every subscriber has it, then destroy the node.

        The wait (at most :data:`LAST_COMMAND_ACK_TIMEOUT`) is what makes the zero
        arrive: the command topic is reliable, but a message still unacknowledged
        when its writer is deleted is lost with it (a process that exits at once
        after publishing lost its zero about 1 run in 10 on a loaded machine).
        """
        try:
            self.publish_zero()
            self._pub_force.wait_for_all_acked(Duration(seconds=LAST_COMMAND_ACK_TIMEOUT))
        except Exception:  # the context may already be shutting down; the node still goes
            pass
        self._log_route.remove()
        super().destroy_node()


def main(args=None) -> None:
    """Run the node until Ctrl-C / SIGTERM; its destroy_node commands zero force.

    :func:`cartpole_core.node_runner.run_node` keeps the context alive while the
    node shuts down, so the last zero force is still published.
    """
    run_node(ControllerManagerNode, args, name='controller_manager')

if __name__ == '__main__':
    main()
