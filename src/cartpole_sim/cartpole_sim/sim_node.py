"""The simulator node ``sim``: the plant of :mod:`cartpole_sim.plant` on ROS.

Publishes the encoder samples on ``joint_states`` (quantised, at 1/Ts = 200
Hz), the ground truth on ``cartpole/true_state``, when each command took
effect on ``cartpole/command_applied`` and, in lockstep, ``/clock``; applies
the latest ``cartpole/force_command`` with zero-order hold and a watchdog.
The numerical work is :class:`~cartpole_sim.sim_runner.SimRunner`'s; this
module only wires ROS. Real time: a steady wall timer steps the plant up to
the sample wall time has reached, stamped on the plant's own sample clock
(``t_0 + k Ts``). Lockstep: sample k (stamp k Ts) waits for the command that
echoes its stamp (and, with ``recorder_window`` > 0, for the recorder's
progress), then steps; ``lockstep_timeout`` keeps a missing controller from
hanging the graph. ``~/reset`` puts the plant back to the scenario's start and
announces it on ``cartpole/plant_reset``. Health: ``sim: simulation`` on
``/diagnostics``. Topic names are relative; ``/clock`` stays global. Stamps,
lockstep, reset and watchdog in detail: docs/simulator.md ("The simulator node").
"""
from __future__ import annotations

import time

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from cartpole_core.diagnostics import OK, STALE, Health, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import COMMAND, RigLimits
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node
from .sim_parameters import SCENARIO_PARAMETERS, declare_sim_parameters, scenario_from
from .sim_runner import (CART_JOINT, PENDULUM_JOINT, Sample, SampleClock, SimRunner,
                         force_from_command)

STARTUP_REPUBLISH_PERIOD = 0.1
"""Wall seconds between re-publications of sample 0 while lockstep waits for a controller."""

STARTUP_RECORDER_WAIT = 10.0
"""Lockstep: wall seconds sample 0 waits for the recorder (it may still be discovering the
graph: up to about 3 s with Fast DDS); later samples wait ``lockstep_timeout``."""

START_HOLD_S = 5.0
"""Real time: longest wall wait [s] of the first sample for ``start_subscribers``."""


DEGRADED = ('rejected_commands', 'lockstep_timeouts', 'late_samples', 'watchdog_trips')
"""Health counters whose growth since the previous report makes it WARN."""

LOST_IN_A_ROW_MAX = 2000
"""Lockstep: samples lost in a row stepped past at once (10 s at 5 ms); beyond, the node
waits for its lockstep timeout, so it keeps answering (services, SIGTERM) whatever the drop."""


class SimNode(Node):
    """Simulated cart-pendulum rig (node name ``sim``); see the module docstring."""

    def __init__(self, **kwargs) -> None:
        super().__init__('sim', **kwargs)
        try:
            self._start()
        except BaseException:   # refused: nothing of the node stays in the graph
            Node.destroy_node(self)
            raise

    def _start(self) -> None:
        """The rest of ``__init__``: parameters, the plant, topics, services, timers."""
        declare_sim_parameters(self)
        self.commands = 0
        """Force commands taken (the health's ``commands``)."""
        self.rejected_commands = 0
        """Force commands without a finite effort for ``cart`` (ignored)."""
        self.stale_commands = 0
        """Lockstep: commands whose stamp is not the awaited sample's (ignored)."""
        self.lockstep_timeouts = 0
        self.late_samples = 0
        """Real time: samples published in a later timer period than theirs (a stall)."""

        values = {name: self.get_parameter(name).value for name in SCENARIO_PARAMETERS}
        params, scenario = scenario_from(values)  # raises on a bad start-up value
        self._runner = SimRunner(params, scenario,
                                 integration_step=values['integration_step'],
                                 command_timeout=self.get_parameter('command_timeout').value)
        self.inputs = InputGuard(self, RigLimits.from_parameters(
            params, stamp_tolerance=declare_stamp_tolerance(self)),
            ('cartpole/force_command', 'cartpole/recorder/progress'))
        """Judges every message before it is taken (refused_inputs in the health)."""
        self._lockstep = bool(self.get_parameter('lockstep').value)
        self._loop_established = not (self._lockstep
                                      and self.get_parameter('lockstep_startup_wait').value)
        self._wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._sample_clock = SampleClock(self._runner.sample_period_ns)

        self._pub_joints = self.create_publisher(JointState, 'joint_states', PUBLISH_DEPTH)
        self._pub_truth = self.create_publisher(JointState, 'cartpole/true_state', PUBLISH_DEPTH)
        self._pub_reset = self.create_publisher(Header, 'cartpole/plant_reset', PLANT_RESET_QOS)
        self._pub_applied = self.create_publisher(TimeReference, 'cartpole/command_applied',
                                                  PUBLISH_DEPTH)
        self._reset_stamp_ns = -1
        """Commands stamped before this [ns] answer the run before the last reset."""
        self._pub_clock = None
        self._answered = False
        """Lockstep: the command for the current sample has arrived."""
        self._recorder_window_ns = None
        self._recorder_ns: int | None = None
        self._waiting_since_ns: int | None = None
        window = int(self.get_parameter('recorder_window').value)
        if self._lockstep and window > 0:
            self._recorder_window_ns = window * int(round(params.sample_time * 1e9))
            self.create_subscription(Header, 'cartpole/recorder/progress', self._on_progress,
                                     QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(JointState, 'cartpole/force_command', self._on_command, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.diagnostics = NodeDiagnostics(self, 'simulation', 'cartpole', self.health,
                                           inputs=('commands',), degraded=DEGRADED)

        self._step_timer = None
        self._start_subscribers = int(self.get_parameter('start_subscribers').value)
        """Readers each sample topic must have before the first sample is published."""
        self._timeout_timer = None
        self._startup_timer = None
        self._held_since = time.monotonic()
        """When the first sample began waiting for its readers."""
        period = params.sample_time
        if self._lockstep:
            # As deep as the sample topics: a reader that stalls (a recorder frozen by the
            # machine) must find every /clock message the sim published meanwhile (it steps
            # at most recorder_window + one a lockstep_timeout past the recorder).
            # Absolute, where every node's sim time reads it; a graph in a namespace
            # remaps it for all its nodes (-r /clock:=/<namespace>/clock).
            self._pub_clock = self.create_publisher(
                ClockMsg, '/clock',
                QoSProfile(depth=PUBLISH_DEPTH, reliability=ReliabilityPolicy.RELIABLE))
            self._timeout_timer = self._make_timeout_timer()
            self._first_published = False
            if self._subscribers_matched():
                self._publish_first()
            if not (self._loop_established and self._first_published):
                self._startup_timer = self.create_timer(
                    STARTUP_REPUBLISH_PERIOD, self._republish, clock=self._wall)
        elif self._start_subscribers > 0:
            self._startup_timer = self.create_timer(period, self._await_subscribers,
                                                    clock=self._wall)
        else:
            self._start_stepping()
        self.get_logger().info(
            f'sim: {"lockstep" if self._lockstep else "real time"}, Ts = {period * 1e3:g} ms, '
            f'x0 = {scenario.x0:g} m, theta0 = {scenario.theta0:g} rad')

    def _subscribers_matched(self) -> bool:
        """Every expected reader of both sample topics is matched (``start_subscribers``), or
        START_HOLD_S have passed (with a warning): a reader discovered late loses the first
        samples, and in lockstep the run monitor, which stands in for a dead controller
        manager with zero force, would not know the sample to answer."""
        wanted = self._start_subscribers
        if wanted <= 0:
            return True
        matched = min(self._pub_joints.get_subscription_count(),
                      self._pub_truth.get_subscription_count())
        waited = time.monotonic() - self._held_since
        if matched < wanted and waited < START_HOLD_S:
            return False
        if matched < wanted:
            self.get_logger().warning(
                f'started with {matched} of {wanted} subscriptions matched after '
                f'{START_HOLD_S:g} s: a reader discovered later misses the first samples')
        return True

    def _await_subscribers(self) -> None:
        """Real time: start the plant once every expected reader is matched."""
        if not self._subscribers_matched():
            return
        self.destroy_timer(self._startup_timer)
        self._startup_timer = None
        self._start_stepping()

    def _publish_first(self) -> None:
        """Lockstep: publish the first sample (held until the readers are matched)."""
        self._first_published = True
        self._publish_lockstep(self._runner.sample)

    def _start_stepping(self) -> None:
        """Real time: step the plant every sample period of the wall clock."""
        self._step_timer = self.create_timer(self._runner.params.sample_time,
                                             self._on_step_timer, clock=self._wall)

    def _validate_parameters(self, changed: list[Parameter]) -> SetParametersResult:
        """Refuse a change that would make an invalid scenario; nothing changes then."""
        values = {name: self.get_parameter(name).value for name in SCENARIO_PARAMETERS}
        touched = False
        for parameter in changed:
            if parameter.name in values:
                values[parameter.name] = parameter.value
                touched = True
        if not touched:
            return SetParametersResult(successful=True)
        try:
            params, _ = scenario_from(values)
        except (ValueError, TypeError, OSError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        if params.sample_time != self._runner.params.sample_time:
            return SetParametersResult(
                successful=False,
                reason=f'plant_params_file changes sample_time to {params.sample_time:g} s; '
                       'it is fixed while the node runs')
        return SetParametersResult(successful=True)

    def _apply_parameters(self, changed: list[Parameter]) -> None:
        """Act on accepted changes: timeouts now, scenario at the next reset."""
        for parameter in changed:
            if parameter.name == 'command_timeout':
                self._runner.command_timeout = float(parameter.value)
            elif parameter.name == 'lockstep_timeout' and self._timeout_timer is not None:
                self.destroy_timer(self._timeout_timer)
                self._timeout_timer = self._make_timeout_timer()

    # -- publishing ----------------------------------------------------------------------
    def _stamp(self, sample: Sample):
        if self._lockstep:
            return Time(nanoseconds=sample.stamp_ns).to_msg()
        if self._sample_clock.started:
            return Time(nanoseconds=self._sample_clock.stamp_ns(sample.index)).to_msg()
        return self.get_clock().now().to_msg()

    def _stamp_ns_of(self, index: int) -> int:
        """The stamp [ns] of sample ``index`` (as :meth:`_stamp` gives it, once the clock runs)."""
        if self._lockstep or not self._sample_clock.started:
            return index * self._runner.sample_period_ns
        return self._sample_clock.stamp_ns(index)

    def _publish_applied(self) -> None:
        """Tell when each command took effect (TimeReference: ``header.stamp`` the time it
        acted, ``time_ref`` the stamp of the sample it was computed from): the loop's latency."""
        applied = self._runner.applied
        for source_ns, index, offset_ns in applied:
            msg = TimeReference()
            msg.header.stamp = Time(nanoseconds=self._stamp_ns_of(index) + offset_ns).to_msg()
            msg.time_ref = Time(nanoseconds=source_ns).to_msg()
            msg.source = 'sim'
            self._pub_applied.publish(msg)
        applied.clear()

    def _publish(self, sample: Sample) -> None:
        if self._runner.applied:
            self._publish_applied()
        stamp = self._stamp(sample)
        if self._pub_clock is not None:
            self._pub_clock.publish(ClockMsg(clock=stamp))
        if not sample.lost:  # a lost sample (scenario drop) never reaches the host
            meas = sample.measurement
            joints = JointState()
            joints.header.stamp = stamp
            joints.name = [CART_JOINT, PENDULUM_JOINT]
            joints.position = [meas.x, meas.theta]
            self._pub_joints.publish(joints)
        x, theta, x_dot, theta_dot = sample.true_state
        truth = JointState()
        truth.header.stamp = stamp
        truth.name = [CART_JOINT, PENDULUM_JOINT]
        truth.position = [x, theta]
        truth.velocity = [x_dot, theta_dot]
        truth.effort = [sample.actuator_force, sample.end_stop_force]
        self._pub_truth.publish(truth)

    # -- stepping ---------------------------------------------------------------------------
    def _on_step_timer(self) -> None:
        """Real time: step to the sample that is due, holding the latest command over each
        [t_k, t_k + Ts), and publish every sample on the way (module docstring)."""
        now_ns = self._wall.now().nanoseconds
        clock = self._sample_clock
        if not clock.started:
            # The first sample is due when this call was: the timer's schedule (it calls at
            # or after it), so every later on-time call finds exactly one sample due.
            until_next = self._step_timer.time_until_next_call()
            scheduled_ns = now_ns if until_next is None else \
                min(now_ns, now_ns + until_next - clock.period_ns)
            clock.start(scheduled_ns, self.get_clock().now().nanoseconds - (now_ns - scheduled_ns),
                        self._runner.index + 1)
        due = clock.due(now_ns)
        if due - self._runner.index > 1:
            self.late_samples += due - self._runner.index - 1
        while self._runner.index < due:
            self._publish(self._runner.advance())

    def _make_timeout_timer(self):
        return self.create_timer(float(self.get_parameter('lockstep_timeout').value),
                                 self._on_lockstep_timeout, clock=self._wall)

    def _lockstep_advance(self) -> None:
        self._answered = False
        self._waiting_since_ns = None
        self._publish_lockstep(self._runner.advance())
        self._timeout_timer.reset()

    def _recorder_has_it(self) -> bool:
        """No recorder to wait for, or it holds the samples up to the window."""
        if self._recorder_window_ns is None:
            return True
        if self._recorder_ns is not None and \
                self._recorder_ns >= self._runner.stamp_ns - self._recorder_window_ns:
            return True
        now = self._wall.now().nanoseconds
        if self._waiting_since_ns is None:
            self._waiting_since_ns = now
        else:
            wait = STARTUP_RECORDER_WAIT if not self._loop_established else \
                self.get_parameter('lockstep_timeout').value
            if now - self._waiting_since_ns > wait * 1e9:
                self.get_logger().warn(
                    f'lockstep: the recorder did not confirm sample {self._runner.index} within '
                    f'{wait:g} s; stepping without it', throttle_duration_sec=5.0)
                return True
        return False

    def _try_advance(self) -> None:
        """Lockstep: step once the current sample is answered (and recorded, with a recorder)."""
        if not self._answered or not self._recorder_has_it():
            return
        if not self._loop_established:
            self._loop_established = True
            if self._startup_timer is not None:
                self.destroy_timer(self._startup_timer)
                self._startup_timer = None
        self._lockstep_advance()

    def _on_progress(self, msg: Header) -> None:
        if not self.inputs.accept_stamps('cartpole/recorder/progress', msg.stamp,
                                         now_ns=self._now_ns()):
            return
        self._recorder_ns = msg.stamp.sec * 1_000_000_000 + msg.stamp.nanosec
        self._try_advance()

    def _publish_lockstep(self, sample: Sample) -> None:
        """Publish ``sample``; past a lost one (no command will answer it) step on at once
        with the held command, as the real-time clock would."""
        self._publish(sample)
        skipped = 0
        while sample.lost:
            if skipped >= LOST_IN_A_ROW_MAX:  # bounded: a drop near 1 must not hang the node
                self.get_logger().error(
                    f'lockstep: {skipped} samples in a row lost (drop = '
                    f'{self.get_parameter("drop").value:g}); waiting for the lockstep timeout',
                    throttle_duration_sec=5.0)
                return
            sample = self._runner.advance()
            self._publish(sample)
            skipped += 1

    def _on_lockstep_timeout(self) -> None:
        if not (self._loop_established and self._first_published):
            return  # nothing to step past: the first sample is held, or not yet answered
        self.lockstep_timeouts += 1
        what = 'no confirmation from the recorder' if self._answered else 'no force command'
        self.get_logger().warn(
            f'lockstep: {what} for sample {self._runner.index} within '
            f'{self.get_parameter("lockstep_timeout").value:g} s; stepping with the held one',
            throttle_duration_sec=5.0)
        self._lockstep_advance()

    def _republish(self) -> None:
        """Lockstep start-up: publish the first sample once its readers are matched, then
        re-publish the current sample until a controller answers."""
        if not self._first_published:
            if not self._subscribers_matched():
                return
            self._publish_first()
            if not self._loop_established:
                return
        if self._loop_established:
            self.destroy_timer(self._startup_timer)
            self._startup_timer = None
            return
        self._publish(self._runner.sample)
        self._try_advance()  # the recorder's wait may have timed out

    def _now_ns(self) -> int:
        """What input stamps are judged against: simulated time in lockstep (the samples'
        stamps, whatever the node clock), else the node clock."""
        if self._lockstep:
            return max(self._runner.stamp_ns, 1)
        return self.get_clock().now().nanoseconds

    def _on_command(self, msg: JointState) -> None:
        if not self.inputs.accept(msg, COMMAND, 'cartpole/force_command', self._now_ns()):
            self.rejected_commands += 1
            return
        force = force_from_command(msg.name, msg.effort)
        if force is None:
            self.rejected_commands += 1
            self.get_logger().warn(
                f'ignored force command without a finite effort for {CART_JOINT!r} '
                f'({self.rejected_commands} so far)', throttle_duration_sec=5.0)
            return
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if not self._lockstep:
            if stamp_ns < self._reset_stamp_ns:
                self.stale_commands += 1
                return
            self._runner.command(force, stamp_ns)
            self.commands += 1
            return
        if stamp_ns != self._runner.stamp_ns:
            self.stale_commands += 1
            return
        self._runner.command(force, stamp_ns)
        self.commands += 1
        self._answered = True
        self._try_advance()

    # -- reset service --------------------------------------------------------------------------
    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Plant back to the scenario's initial state, with the scenario parameters now set."""
        values = {name: self.get_parameter(name).value for name in SCENARIO_PARAMETERS}
        try:
            params, scenario = scenario_from(values)
            sample = self._runner.reset(params=params, scenario=scenario,
                                        integration_step=float(values['integration_step']))
        except ValueError as error:
            response.success = False
            response.message = f'reset refused: {error}'
            return response
        stamp = self._stamp(sample)
        self._reset_stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        self._pub_reset.publish(Header(stamp=stamp))
        if self._lockstep:
            self._answered = False
            self._publish_lockstep(sample)
            self._timeout_timer.reset()
        response.success = True
        response.message = (f'reset: x0 = {scenario.x0:g} m, theta0 = {scenario.theta0:g} rad, '
                            f'sample {sample.index}')
        self.get_logger().info(response.message)
        return response

    # -- health ------------------------------------------------------------------------------
    def health(self) -> Health:
        """The simulator's health with the input checks' counts (:meth:`_own_health`; WARN
        once an input was refused)."""
        return self.inputs.health(self._own_health())

    def _own_health(self) -> Health:
        """The simulator's health for ``/diagnostics`` (``sim: simulation``): OK while it
        runs or waits for a controller; STALE once the force commands stopped (the watchdog
        holds zero force); WARN when a :data:`DEGRADED` counter grew since the last report."""
        runner = self._runner
        values = {
            'lockstep': self._lockstep, 'sample': runner.index,
            'stamp': self._stamp_ns_of(runner.index) * 1e-9, 'commands': self.commands,
            'rejected_commands': self.rejected_commands, 'stale_commands': self.stale_commands,
            'lockstep_timeouts': self.lockstep_timeouts, 'late_samples': self.late_samples,
            'watchdog_trips': runner.watchdog_trips, 'watchdog_tripped': runner.watchdog_tripped,
        }
        if not self.commands:
            return Health(OK, 'waiting for a controller (no force command yet)', values)
        if runner.watchdog_tripped:
            return Health(STALE, 'no force command for command_timeout: the watchdog holds '
                                 'zero force', values)
        return Health(OK, 'lockstep' if self._lockstep else 'real time', values)

    # -- introspection for tests and bringup ----------------------------------------------------
    @property
    def runner(self) -> SimRunner:
        """The ROS-free simulation this node drives (read it, do not step it)."""
        return self._runner


def main(args=None) -> None:
    run_node(SimNode, args, name='sim_node')

if __name__ == '__main__':
    main()
