"""The simulator node ``sim``: the plant of :mod:`cartpole_sim.plant` on ROS.

Publishes the encoder samples on ``/joint_states`` (quantised, at 1/Ts =
200 Hz), the ground truth on ``/cartpole/true_state`` and, in lockstep mode,
``/clock``; applies the latest ``/cartpole/force_command`` with zero-order
hold. All numerical work is in :class:`~cartpole_sim.plant.Plant`, wrapped by
:class:`~cartpole_sim.sim_runner.SimRunner`; this module only wires ROS.

Real time (``lockstep:=false``): the plant is sampled on its own clock, as a
device would be (:class:`~cartpole_sim.sim_runner.SampleClock`): a steady wall
timer at Ts steps the plant up to the sample wall time has reached (after a
stall of the process, several steps at once, each with the held command and
the watchdog) and publishes every sample, stamped ``t_0 + k Ts`` from the node
clock at the first sample: stamps exactly Ts apart, the plant's own time.
``late_samples`` counts the samples published late (behind a stall).

Lockstep (``lockstep:=true``): stamps are simulated time k Ts, also published on
``/clock``. After sample k the node waits for the force command whose
``header.stamp`` equals sample k's stamp; its arrival (a subscription
callback, no polling) steps the plant by Ts and publishes sample k + 1. If no
such command arrives within ``lockstep_timeout`` wall seconds, the node steps
with the held command (zero once the watchdog tripped), so a missing
controller cannot hang the graph. Until the first matching command arrives
(``lockstep_startup_wait``), sample 0 is re-published every 0.1 s wall and the
timeout does not apply, so a graph whose controller starts slowly still starts
from the same sample and runs the same way every time.

With a recorder in the loop (``recorder_window`` > 0; ``cartpole run
--lockstep --record`` sets it) the node also does not step past sample k
until the recorder reports (``/cartpole/recorder/progress``, std_msgs/Header)
that it holds every sample topic up to k - ``recorder_window``: so the bag is
complete however slow the recorder is (see ``cartpole_bringup.graph.record_ledger``).
A recorder silent for ``lockstep_timeout`` (at sample 0:
:data:`STARTUP_RECORDER_WAIT`) is not waited for any longer.

Reset (service ``~/reset``): the plant goes back to the scenario's initial
state with zero force, and the node announces it on ``cartpole/plant_reset``
(std_msgs/Header, ``stamp`` = the time from which samples show the reset
plant: the reset sample's stamp in lockstep, the reset's time in real time)
before the first sample after it, so that the EKF re-initialises and the
controller manager starts a new swing-up instead of seeing the jump. Force
commands stamped before the reset (answers to the old run) are ignored.

Health: ``sim: simulation`` on ``/diagnostics`` once a second of the node clock
(:meth:`SimNode.health`, :mod:`cartpole_core.diagnostics`).

Topic names are relative (``joint_states`` is ``/joint_states`` without a
namespace), so a graph can run in a namespace; ``/clock`` stays global.
"""
from __future__ import annotations

import math
from pathlib import Path

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
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
from cartpole_core.model import CartPoleParameters
from .plant import Scenario
from .scenario import DELAY_MAX, DROP_MAX, parse_push
from .sim_runner import (CART_JOINT, PENDULUM_JOINT, Sample, SampleClock, SimRunner,
                         force_from_command)
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node

STARTUP_REPUBLISH_PERIOD = 0.1
"""Wall seconds between re-publications of sample 0 while lockstep waits for a controller."""

STARTUP_RECORDER_WAIT = 10.0
"""Lockstep: wall seconds sample 0 waits for the recorder (it may still be discovering the
graph: up to about 3 s with Fast DDS); later samples wait ``lockstep_timeout``."""

SCENARIO_PARAMETERS = ('x0', 'theta0', 'x_dot0', 'theta_dot0', 'tip_mass', 'friction_scale',
                       'encoder_offset', 'noise', 'seed', 'plant_params_file',
                       'integration_step', 'cart_mass', 'delay', 'jitter', 'drop',
                       'force_noise', 'actuator_gain', 'actuator_tau', 'pushes')
"""Parameters that take effect at the next reset (service ``~/reset``)."""


DEGRADED = ('rejected_commands', 'lockstep_timeouts', 'late_samples', 'watchdog_trips')
"""Health counters whose growth since the previous report makes it WARN."""

LOST_IN_A_ROW_MAX = 2000
"""Lockstep: samples lost in a row stepped past at once (10 s at 5 ms); beyond, the node
waits for its lockstep timeout, so it keeps answering (services, SIGTERM) whatever the drop."""


def _float_range(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=float(low), to_value=float(high), step=0.0)]


_START_PARAMETERS = (
    ('x0', 0.0, 'Initial cart position from the left end stop [m]; within the travel.',
     0.0, 10.0),
    ('theta0', math.pi, 'Initial pendulum angle [rad]; 0 upright, pi hanging.', -20.0, 20.0),
    ('x_dot0', 0.0, 'Initial cart velocity [m/s].', -5.0, 5.0),
    ('theta_dot0', 0.0, 'Initial pendulum angular velocity [rad/s].', -50.0, 50.0),
    ('tip_mass', 0.0, 'Tip mass of the plant [kg]; 0 keeps the nominal m_p (0.251 kg).',
     0.0, 10.0),
    ('friction_scale', 1.0, 'Multiplies every cart and pendulum friction coefficient.',
     0.0, 10.0),
    ('encoder_offset', 0.0, 'Pendulum angle minus pi when the encoders were reset [rad] '
     '(Appendix H); biases the measured angle.', -math.pi, math.pi),
)
"""The start and the plant's uncertainties: (name, default, description, low, high)."""

_DISTURBANCE_PARAMETERS = (
    ('cart_mass', 0.0, 'Equivalent cart mass of the plant [kg]; 0 keeps the nominal m_c '
     '(4.75 kg).', 0.0, 100.0),
    ('delay', 0.0, 'Sensor-to-actuator latency [s]: a command takes effect this long after '
     'the sample it was computed from (inside the hold).', 0.0, DELAY_MAX),
    ('jitter', 0.0, 'Extra latency per sample, uniform in [0, jitter] [s].', 0.0, DELAY_MAX),
    ('drop', 0.0, f'Probability in [0, {DROP_MAX:g}] that a sample is lost: not published on '
     '/joint_states (/cartpole/true_state and /clock still are); lockstep steps on at once '
     'with the held command.', 0.0, DROP_MAX),
    ('force_noise', 0.0, 'Std of Gaussian force noise on the cart [N], one draw per sample.',
     0.0, 100.0),
    ('actuator_gain', 1.0, 'Amplifier gain error: the current is this times the commanded '
     'one.', 0.0, 10.0),
    ('actuator_tau', 0.0, 'Time constant of an extra first-order amplifier lag [s]; 0 = none.',
     0.0, 1.0),
)
"""The scenario's disturbances (cartpole_sim.scenario): (name, default, description, low, high)."""


def load_plant_parameters(path: str) -> CartPoleParameters:
    """The nominal plant parameters: the thesis values, or a YAML file's."""
    if not path:
        return CartPoleParameters()
    if not Path(path).is_file():
        raise ValueError(f'plant_params_file {path!r} does not exist')
    try:
        return CartPoleParameters.from_yaml(path)
    except ValueError as error:
        raise ValueError(f'plant_params_file {path!r}: {error}') from error
    except Exception as error:  # unreadable or not YAML (yaml.YAMLError, OSError, ...)
        raise ValueError(f'plant_params_file {path!r} cannot be read: {error}') from error


class SimNode(Node):
    """Simulated cart-pendulum rig (node name ``sim``); see the module docstring.

    Why one class of about 360 lines: a node adapter, most of it the declaration of
    the scenario's parameters and their validation, and the lockstep handshake with
    the recorder, which shares the node's publishers and timers; the sample clock and
    watchdog are :mod:`cartpole_sim.sim_runner`, the plant :class:`cartpole_sim.plant.Plant`.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('sim', **kwargs)
        self._declare_parameters()
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
        params, scenario = self._scenario_from(values)  # raises on a bad start-up value
        self._runner = SimRunner(params, scenario,
                                 integration_step=values['integration_step'],
                                 command_timeout=self.get_parameter('command_timeout').value)
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
        self._timeout_timer = None
        self._startup_timer = None
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
            if not self._loop_established:
                self._startup_timer = self.create_timer(
                    STARTUP_REPUBLISH_PERIOD, self._republish, clock=self._wall)
            self._publish_lockstep(self._runner.sample)
        else:
            self._step_timer = self.create_timer(period, self._on_step_timer, clock=self._wall)
        self.get_logger().info(
            f'sim: {"lockstep" if self._lockstep else "real time"}, Ts = {period * 1e3:g} ms, '
            f'x0 = {scenario.x0:g} m, theta0 = {scenario.theta0:g} rad')

    # -- parameters ------------------------------------------------------------------
    def _declare_parameters(self) -> None:
        declare = self.declare_parameter
        declare('lockstep', False, ParameterDescriptor(
            description='Lockstep: advance one Ts per force command echoing the sample stamp, '
                        'publish /clock; false: real time on a wall timer.', read_only=True))
        declare('lockstep_startup_wait', True, ParameterDescriptor(
            description='Lockstep: until the first matching command, re-publish sample 0 every '
                        '0.1 s wall and do not apply lockstep_timeout.', read_only=True))
        declare('recorder_window', 0, ParameterDescriptor(
            description='Lockstep: step past sample k only once the recorder holds every sample '
                        'topic up to sample k - recorder_window; 0 = do not wait for a recorder.',
            read_only=True, integer_range=[IntegerRange(from_value=0, to_value=90, step=1)]))
        declare('lockstep_timeout', 1.0, ParameterDescriptor(
            description='Lockstep: wall seconds to wait for the awaited command before stepping '
                        'with the held one [s]; takes effect at once.',
            floating_point_range=_float_range(0.001, 3600.0)))
        declare('command_timeout', 0.05, ParameterDescriptor(
            description='Watchdog: zero force when no command arrived for this much simulated '
                        'time [s]; takes effect at once.',
            floating_point_range=_float_range(0.0, 10.0)))
        self._declare_ranged(_START_PARAMETERS)
        declare('noise', False, ParameterDescriptor(
            description='Add Gaussian measurement noise before quantisation.'))
        declare('seed', 0, ParameterDescriptor(
            description='Seed of the measurement noise.',
            integer_range=[IntegerRange(from_value=0, to_value=2**31 - 1, step=1)]))
        self._declare_disturbances()
        declare('plant_params_file', '', ParameterDescriptor(
            description="YAML of CartPoleParameters (must exist and have the node's "
                        "sample_time); '' = the thesis values."))
        declare('integration_step', 0.001, ParameterDescriptor(
            description='RK4 step of the plant [s]; at most the sample time.',
            floating_point_range=_float_range(1e-5, 0.005)))

    def _declare_ranged(self, table) -> None:
        """Declare the float parameters of ``table``: (name, default, description, low, high)."""
        for name, default, description, low, high in table:
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, floating_point_range=_float_range(low, high)))

    def _declare_disturbances(self) -> None:
        """The scenario's disturbances (cartpole_sim.scenario), at the next reset like the rest."""
        declare = self.declare_parameter
        self._declare_ranged(_DISTURBANCE_PARAMETERS)
        declare('pushes', '', ParameterDescriptor(
            description="Pushes 'T:TARGET:AMPLITUDE:WIDTH' separated by commas or spaces, "
                        "TARGET cart [N] or pendulum [N m]; '' = none."))

    @staticmethod
    def _scenario_from(values: dict) -> tuple[CartPoleParameters, Scenario]:
        """Nominal parameters and scenario from parameter values; ValueError if invalid."""
        params = load_plant_parameters(values['plant_params_file'])
        x0 = float(values['x0'])
        if not 0.0 <= x0 <= params.travel:
            raise ValueError(f'x0 = {x0:g} m is outside the travel [0, {params.travel:g}] m')
        tip_mass = float(values['tip_mass'])
        if not (tip_mass >= 0.0 and math.isfinite(tip_mass)):
            raise ValueError(f'tip_mass must be 0 (nominal) or a positive mass, got {tip_mass!r}')
        step = float(values['integration_step'])
        if not 0.0 < step <= params.sample_time:
            raise ValueError(f'integration_step = {step:g} s must be in (0, sample_time = '
                             f'{params.sample_time:g} s]')
        scenario = Scenario(
            x0=x0, theta0=float(values['theta0']), x_dot0=float(values['x_dot0']),
            theta_dot0=float(values['theta_dot0']),
            tip_mass=tip_mass if tip_mass > 0.0 else None,
            friction_scale=float(values['friction_scale']),
            encoder_offset=float(values['encoder_offset']),
            noise=bool(values['noise']), seed=int(values['seed']),
            cart_mass=float(values['cart_mass']) or None, delay=float(values['delay']),
            jitter=float(values['jitter']), drop=float(values['drop']),
            force_noise=float(values['force_noise']),
            actuator_gain=float(values['actuator_gain']),
            actuator_tau=float(values['actuator_tau']),
            pushes=tuple(parse_push(text) for text in
                         str(values['pushes']).replace(',', ' ').split()))
        scenario.plant_parameters(params)  # validates the scenario's plant (e.g. masses)
        return params, scenario

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
            params, _ = self._scenario_from(values)
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
        if not self._loop_established:
            return
        self.lockstep_timeouts += 1
        what = 'no confirmation from the recorder' if self._answered else 'no force command'
        self.get_logger().warn(
            f'lockstep: {what} for sample {self._runner.index} within '
            f'{self.get_parameter("lockstep_timeout").value:g} s; stepping with the held one',
            throttle_duration_sec=5.0)
        self._lockstep_advance()

    def _republish(self) -> None:
        """Lockstep start-up: re-publish the current sample until a controller answers."""
        if self._loop_established:
            self.destroy_timer(self._startup_timer)
            self._startup_timer = None
            return
        self._publish(self._runner.sample)
        self._try_advance()  # the recorder's wait may have timed out

    def _on_command(self, msg: JointState) -> None:
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
            params, scenario = self._scenario_from(values)
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
