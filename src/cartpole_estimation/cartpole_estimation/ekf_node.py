"""ROS 2 node ``ekf``: the EKF of chapter 5 between the encoders and the controllers.

Subscribes ``joint_states`` (the quantised positions of ``cart`` and
``pendulum``), ``cartpole/force_command`` and ``cartpole/force_acting`` (``cart``
effort; :mod:`cartpole_estimation.prediction_force`), publishes
``cartpole/state`` (positions and velocities, the sample's stamp) at once in
the sample's callback, ``cartpole/ekf/health`` every ``health_period`` and
``ekf: estimation`` on ``/diagnostics``. The numerical work is
:class:`cartpole_estimation.ekf.ExtendedKalmanFilter`; this module only wires
it. With ``lockstep:=true`` a sample is estimated only once the command (and acting
force) computed from the previous sample has arrived (at most ``lockstep_wait``), so
the estimate does not depend on DDS's delivery order. A ``cartpole/plant_reset``
re-initialises the filter from the first sample stamped at or after it.
docs/estimation.md.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import Trigger

from cartpole_core.diagnostics import OK, Health, HealthReport, NodeDiagnostics
from cartpole_core.input_guard import InputGuard, declare_stamp_tolerance
from cartpole_core.message_checks import COMMAND, SAMPLE, RigLimits
from cartpole_core.model import CartPoleParameters
from cartpole_core.node_runner import PLANT_RESET_QOS, PUBLISH_DEPTH, run_node
from cartpole_core.realtime import CycleGapMeter

from .ekf import EkfConfig, ExtendedKalmanFilter
from .ekf_config import ROS_PARAMETERS, changes_from_parameters, q_parameter
from .prediction_force import PredictionForce

JOINT_NAMES = ('cart', 'pendulum')
HARDWARE_ID = 'cartpole'
DEGRADED = ('resets', 'missed_samples', 'bad_messages', 'bad_commands', 'rejected_samples')
"""Health counters whose growth since the previous report makes it WARN."""


@dataclass
class EkfNodeCounts:
    """The node's message counts, health keys of the same names (docs/estimation.md)."""

    samples: int = 0
    """Samples estimated (a state published)."""
    bad_messages: int = 0
    """``/joint_states`` dropped: no finite ``cart`` and ``pendulum`` positions, or
    refused by the filter (its ``rejected_samples``)."""
    duplicate_samples: int = 0
    """Repeats of the latest sample (its estimate published again)."""
    bad_commands: int = 0
    """``/cartpole/force_command`` or ``/cartpole/force_acting`` dropped: no finite ``cart`` effort."""


def _stamp_seconds(stamp) -> float:
    return stamp.sec + 1.0e-9 * stamp.nanosec


def _positive_array_reason(name: str, value, length: int) -> str:
    """'' if ``value`` is ``length`` finite numbers > 0, else why not."""
    values = list(value)
    if len(values) != length:
        return f'{name} needs {length} entries, got {len(values)}'
    if not all(math.isfinite(v) and v > 0.0 for v in values):
        return f'{name} entries must be finite and > 0, got {values}'
    return ''


class EkfNode(Node):
    """The ``ekf`` node (docs/architecture.md, "ROS interfaces").

    Keyword arguments go to :class:`rclpy.node.Node` (``context``,
    ``parameter_overrides``, ``namespace``, ...).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('ekf', **kwargs)
        try:
            self._start()
        except BaseException:   # refused: nothing of the node stays in the graph
            Node.destroy_node(self)
            raise

    def _start(self) -> None:
        """The rest of ``__init__``: parameters, the filter, topics, services, timers."""
        defaults = EkfConfig()
        self.declare_parameter('q', q_parameter(defaults), ParameterDescriptor(
            description='Process covariance Q_k added per sample period: its diagonal for '
                        'x [m^2], theta [rad^2], x_dot [(m/s)^2], theta_dot [(rad/s)^2] (each '
                        '> 0) and, as a fifth entry, q_force (>= 0), the variance of a random '
                        'force on the cart [N^2]; 4 entries = no force noise, the thesis (9.2) '
                        'is [1, 1, 50, 50]. Applied from the next sample.'))
        self.declare_parameter('r', list(defaults.r_diag), ParameterDescriptor(
            description='Diagonal of the measurement covariance R_k (thesis 9.1): '
                        'x [m^2], theta [rad^2]; 2 entries, each > 0. Applied from the next sample.'))
        self.declare_parameter('push_q_force', defaults.push_q_force, ParameterDescriptor(
            description='q_force of a sample whose cart innovation says push (beyond '
                        f'push_innovation and {defaults.push_ratio:g} times the recent '
                        'innovations, the pendulum within '
                        f'{math.degrees(defaults.push_angle):.0f} deg of upright): that sample '
                        'is predicted again with it, so the estimate follows a push at once; '
                        '0 = off. Applied from the next sample.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0e12)]))
        self.declare_parameter('push_innovation', defaults.push_innovation, ParameterDescriptor(
            description='Cart innovation [m] beyond which a sample may count as pushed; above '
                        'the balancing loop\'s own (0.6 mm at most on the thesis rig).',
            floating_point_range=[FloatingPointRange(from_value=1.0e-5, to_value=0.05)]))
        self.declare_parameter('plant_params_file', '', ParameterDescriptor(
            description="YAML file of the filter's plant parameters "
                        "(CartPoleParameters.to_yaml); '' = the thesis values.",
            read_only=True))
        self.declare_parameter('friction_steepness', defaults.friction_steepness,
                               ParameterDescriptor(
            description='k of tanh(k v) in the filter model\'s Coulomb friction of cart '
                        '[s/m] and pendulum [s/rad] (4.20)/(4.21). Forward Euler at Ts is '
                        'unstable near rest above 2 m_c / (c_c Ts), about 560.',
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=500.0)]))
        self.declare_parameter('angle_offset_p0', defaults.angle_offset_p0, ParameterDescriptor(
            description='Prior variance of the pendulum encoder\'s offset (Appendix H), on the '
                        'scale of P; 0 = no offset state (the thesis\'s 4-state filter). Takes '
                        'effect at the next (re)initialisation.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0e6)]))
        self.declare_parameter('angle_offset_q', defaults.angle_offset_q, ParameterDescriptor(
            description='Random walk of the encoder offset per sample period, on the scale of P.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0)]))
        gate_range = [FloatingPointRange(from_value=0.0, to_value=1.0e9)]
        self.declare_parameter('offset_gate_rate', defaults.offset_gate_rate, ParameterDescriptor(
            description='The encoder offset is corrected only while |theta_dot| [rad/s] is '
                        'below this, the encoders\' angle within offset_gate_angle of hanging or '
                        'upright and the force command below offset_gate_force: near an '
                        'equilibrium, where a plant unlike the model does not pass for an '
                        'offset. 1e9 with the other two at their maximum: always.',
            floating_point_range=gate_range))
        self.declare_parameter('offset_gate_angle', defaults.offset_gate_angle,
                               ParameterDescriptor(
            description='See offset_gate_rate [rad]; pi/2: any angle.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=math.pi / 2)]))
        self.declare_parameter('offset_gate_force', defaults.offset_gate_force,
                               ParameterDescriptor(
            description='See offset_gate_rate [N].',
            floating_point_range=gate_range))
        self.declare_parameter('offset_gate_noise', defaults.offset_gate_noise,
                               ParameterDescriptor(
            description='With R_theta at or above this times r\'s (a noisy pendulum '
                        'encoder, noise_window) the encoder offset is corrected everywhere. '
                        '1e9: never.',
            floating_point_range=gate_range))
        self.declare_parameter('noise_window', defaults.noise_window, ParameterDescriptor(
            description='Time constant [s] of the mean of the encoders\' scatter near an '
                        'equilibrium to which R is matched (never below r); 0: R fixed.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=60.0)]))
        self.declare_parameter('noise_variance_theta', defaults.noise_variance_theta,
                               ParameterDescriptor(
            description='The real variance of the pendulum angle [rad^2] that r\'s R_theta '
                        'stands for: the scale of the filter.',
            floating_point_range=[FloatingPointRange(from_value=1.0e-12, to_value=1.0)]))
        self.declare_parameter('noise_limit', defaults.noise_limit, ParameterDescriptor(
            description='R is never above this times r.',
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=1.0e6)]))
        self.declare_parameter('discretisation', defaults.discretisation, ParameterDescriptor(
            description="f_k of the prediction: 'midpoint' (explicit midpoint rule) or 'euler' "
                        '(forward Euler, thesis 5.8).'))
        self.declare_parameter('force_input', defaults.force_input, ParameterDescriptor(
            description="The force the prediction takes: 'acting', the manager's estimate of "
                        'the force the cart feels (cartpole/force_acting: the commands delayed '
                        "by the measured dead time, times the estimated gain), or 'command', "
                        'the command as sent (the thesis).'))
        self.declare_parameter('health_period', 0.1, ParameterDescriptor(
            description='Period of /cartpole/ekf/health [s] (node clock).',
            floating_point_range=[FloatingPointRange(from_value=0.01, to_value=10.0)]))
        self.declare_parameter('command_timeout', 0.05, ParameterDescriptor(
            description='A force command older than this [s of measurement time] is taken '
                        'as zero in the prediction, as the plant and the bridge do.',
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=1.0)]))

        self.declare_parameter('lockstep', False, ParameterDescriptor(
            description='Lockstep simulation: estimate a sample only once the force command of '
                        'the previous sample has arrived (deterministic whatever the delivery '
                        'order).', read_only=True))
        self.declare_parameter('lockstep_wait', 0.5, ParameterDescriptor(
            description='Lockstep: longest wait for that command [wall s].', read_only=True,
            floating_point_range=[FloatingPointRange(from_value=0.001, to_value=10.0)]))

        names = ROS_PARAMETERS
        reason = self._validate([self.get_parameter(n) for n in names])
        if reason:
            raise ValueError(f'ekf: {reason}')
        params_file = self.get_parameter('plant_params_file').value
        params = CartPoleParameters.from_yaml(params_file) if params_file \
            else CartPoleParameters()
        self.filter = ExtendedKalmanFilter(params, EkfConfig(**changes_from_parameters(
            {n: self.get_parameter(n).value for n in names})))
        self.inputs = InputGuard(self, RigLimits.from_parameters(
            params, stamp_tolerance=declare_stamp_tolerance(self)),
            ('joint_states', 'cartpole/force_command', 'cartpole/force_acting'))
        """Judges every message before it is taken (refused_inputs in the health)."""
        self.forces = PredictionForce(self.filter.config.force_input,
                                      self.get_parameter('command_timeout').value)
        """The commands and acting forces by the stamp of the sample they answer."""
        self._last_sample_t: float | None = None
        self._last_sample_stamp: tuple[int, int] | None = None
        self._last_force_used = 0.0
        self.counts = EkfNodeCounts()
        self.last_bad = ''
        self._last_estimate = None
        self._last_reset_reason = ''

        self._state_msg = JointState()
        self._state_msg.name = list(JOINT_NAMES)
        self._state_pub = self.create_publisher(JointState, 'cartpole/state', PUBLISH_DEPTH)
        self._health_pub = self.create_publisher(DiagnosticArray, 'cartpole/ekf/health', 10)
        self._health_report = HealthReport('ekf', HARDWARE_ID, ('samples',), DEGRADED)
        self.diagnostics = NodeDiagnostics(self, 'estimation', HARDWARE_ID, self.health,
                                           inputs=('samples',), degraded=DEGRADED)
        self._reset_from: float | None = None
        self.cycle_gaps = CycleGapMeter()
        # Before /joint_states: when both are ready at once, the reset is taken first.
        self.create_subscription(Header, 'cartpole/plant_reset', self._on_plant_reset,
                                 PLANT_RESET_QOS)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states, 10)
        self.create_subscription(JointState, 'cartpole/force_command', self._on_force_command, 10)
        self.create_subscription(JointState, 'cartpole/force_acting', self._on_force_acting, 10)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._health_timer = self.create_timer(self.get_parameter('health_period').value,
                                               self._publish_health)
        self._lockstep = bool(self.get_parameter('lockstep').value)
        self._pending_sample: tuple[JointState, float, float, float] | None = None
        self._pending_timer = None
        if self._lockstep:
            self._pending_timer = self.create_timer(
                float(self.get_parameter('lockstep_wait').value), self._on_pending_timeout,
                clock=Clock(clock_type=ClockType.STEADY_TIME))
            self._pending_timer.cancel()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)

    # -- parameters ---------------------------------------------------------------------
    def _validate(self, parameters) -> str:
        """'' if the filter takes these values (checked on a candidate EkfConfig), else why not."""
        for p in parameters:
            if p.name == 'q':
                values = list(p.value)
                reason = _positive_array_reason('q', values[:4], 4) if len(values) in (4, 5) \
                    else f'q needs 4 entries (the diagonal of Q) or 5 (and q_force), got {len(values)}'
                if not reason and len(values) == 5 and not (math.isfinite(values[4])
                                                             and values[4] >= 0.0):
                    reason = f'q_force (the fifth entry of q) must be finite and >= 0, got {values[4]}'
            elif p.name == 'r':
                reason = _positive_array_reason('r', p.value, 2)
            else:  # discretisation, force_input, ...: EkfConfig's own checks, below
                reason = ''
            if reason:
                return reason
        changes = changes_from_parameters({p.name: p.value for p in parameters})
        try:
            base = self.filter.config if hasattr(self, 'filter') else EkfConfig()
            base.replace(**changes)
        except (ValueError, TypeError) as error:
            return str(error)
        return ''

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        reason = self._validate(parameters)
        return SetParametersResult(successful=not reason, reason=reason)

    def _on_parameters_set(self, parameters: list[Parameter]) -> None:
        # Same callback group as the subscriptions: applied between two updates.
        changes = changes_from_parameters({p.name: p.value for p in parameters})
        for p in parameters:
            if p.name == 'command_timeout':
                self.forces.command_timeout = float(p.value)
            elif p.name == 'force_input':
                self.forces.force_input = str(p.value)
            elif p.name == 'health_period':
                self._health_timer.cancel()
                self.destroy_timer(self._health_timer)
                self._health_timer = self.create_timer(float(p.value), self._publish_health)
        if changes:
            self.filter.set_config(self.filter.config.replace(**changes))
            self.get_logger().info(f'EKF configuration changed: {changes}')

    # -- inputs -------------------------------------------------------------------------
    def _on_force_command(self, msg: JointState) -> None:
        force = self._cart_effort(msg, 'cartpole/force_command')
        if force is not None:
            self.forces.command((msg.header.stamp.sec, msg.header.stamp.nanosec), force,
                                self._last_sample_t)
            self._estimate_if_ready()

    def _on_force_acting(self, msg: JointState) -> None:
        force = self._cart_effort(msg, 'cartpole/force_acting')
        if force is not None:
            self.forces.acting((msg.header.stamp.sec, msg.header.stamp.nanosec), force)
            self._estimate_if_ready()

    def _cart_effort(self, msg: JointState, topic: str) -> float | None:
        """The finite ``cart`` effort of a command-like message, else None (counted, said)."""
        if not self.inputs.accept(msg, COMMAND, topic):
            self.counts.bad_commands += 1
            return None
        try:
            force = float(msg.effort[list(msg.name).index('cart')])
        except (ValueError, IndexError):
            force = math.nan
        if not math.isfinite(force):
            self.counts.bad_commands += 1
            self.get_logger().warning(
                f'bad /{topic} dropped (needs a finite effort for "cart"): '
                f'names {list(msg.name)}, effort {list(msg.effort)}',
                throttle_duration_sec=1.0)
            return None
        return force

    def _estimate_if_ready(self) -> None:
        """Lockstep: the sample waiting for its prediction's force gets it once all arrived."""
        if self._pending_sample is not None and self.forces.ready(self._last_sample_stamp):
            self._estimate_pending()

    def _estimate_pending(self) -> None:
        sample, self._pending_sample = self._pending_sample, None
        self._pending_timer.cancel()
        self._estimate(*sample)

    def _on_pending_timeout(self) -> None:
        if self._pending_sample is not None:
            self._estimate_pending()
        else:
            self._pending_timer.cancel()

    def _on_joint_states(self, msg: JointState) -> None:
        if not self.inputs.accept(msg, SAMPLE, 'joint_states'):
            self.counts.bad_messages += 1
            return
        names = msg.name
        try:
            i_cart = names.index('cart')
            i_pend = names.index('pendulum')
            x = msg.position[i_cart]
            theta = msg.position[i_pend]
        except (ValueError, IndexError):
            self._drop(msg, 'needs positions for "cart" and "pendulum"')
            return
        if not (math.isfinite(x) and math.isfinite(theta)):
            self._drop(msg, 'non-finite position')
            return
        t = _stamp_seconds(msg.header.stamp)
        if self._lockstep and t != self._last_sample_t:
            if self._pending_sample is not None:  # a newer sample: stop waiting for the old one
                self._estimate_pending()
            if (self._last_sample_stamp is not None
                    and not self.forces.ready(self._last_sample_stamp)):
                # The previous command is still on its way.
                self._pending_sample = (msg, x, theta, t)
                self._pending_timer.reset()
                return
        self._estimate(msg, x, theta, t)

    def _estimate(self, msg: JointState, x: float, theta: float, t: float) -> None:
        """One EKF update for a sample (its positions and time checked by the caller)."""
        if t == self._last_sample_t:
            # A repeated sample (the simulator re-publishes sample 0 until a
            # controller answers): already estimated; publish the same estimate
            # again so that a controller that missed it can still answer.
            self.counts.duplicate_samples += 1
            if self._last_estimate is not None:
                self._state_pub.publish(self._state_msg)
            return
        self.cycle_gaps.tick()
        if self._reset_from is not None and t >= self._reset_from:
            self._reset_from = None
            self.filter.request_reset('plant reset')
            self.forces.clear()  # commands of the run before the reset
        # the force over the interval that ends at this sample
        force = self.forces.for_interval(self._last_sample_stamp, self._last_sample_t)
        est = self.filter.update(t, x, theta, force)
        if est.rejected:
            self._drop(msg, est.rejected)
            return
        out = self._state_msg
        out.header.stamp = msg.header.stamp
        out.position = [est.x, est.theta]
        out.velocity = [est.x_dot, est.theta_dot]
        self._state_pub.publish(out)
        # Book-keeping after the publication (off the latency path).
        self._last_sample_t = t
        self._last_sample_stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        self._last_force_used = force
        self._last_estimate = est
        self.counts.samples += 1
        if est.reset:
            self._last_reset_reason = est.reset_reason
            if est.reset_reason != 'initialisation':
                self.get_logger().warning(f'EKF re-initialised: {est.reset_reason}')

    def _drop(self, msg: JointState, why: str) -> None:
        self.counts.bad_messages += 1
        self.last_bad = why
        self.get_logger().warning(f'/joint_states sample dropped: {why}',
                                  throttle_duration_sec=1.0)

    def _on_plant_reset(self, msg: Header) -> None:
        """The plant is back in its initial state from ``msg.stamp`` on (simulator reset)."""
        self._reset_from = _stamp_seconds(msg.stamp)
        if self._last_sample_t is not None and self._last_sample_t >= self._reset_from:
            self._reset_from = self._last_sample_t  # came late: the next sample re-initialises

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.filter.request_reset()
        response.success = True
        response.message = 'EKF will re-initialise from the next sample'
        return response

    # -- health ---------------------------------------------------------------------------
    def health(self) -> Health:
        """The filter's figures now (keys: docs/estimation.md); OK, idle before the first
        sample. The reports add WARN when a :data:`DEGRADED` counter grew, STALE when the
        samples stopped."""
        est = self._last_estimate
        f = self.filter
        if est is None:
            innovation, p_diag, dt, message = (0.0, 0.0), f.config.p0_diag, 0.0, 'no sample yet'
        else:
            innovation, p_diag, dt = est.innovation, est.covariance_diagonal, est.dt
            message = 'estimating'
        r_factor_x, r_factor_theta = f.measurement_noise_factors
        values = {
            'innovation_x': innovation[0], 'innovation_theta': innovation[1],
            'p_x': p_diag[0], 'p_theta': p_diag[1], 'p_x_dot': p_diag[2],
            'p_theta_dot': p_diag[3], 'angle_offset': f.angle_offset,
            'p_angle_offset': float(f.covariance[4, 4]),
            'resets': f.resets, 'reset_reason': self._last_reset_reason,
            'missed_samples': f.missed_samples_total, 'dt': dt, **asdict(self.counts),
            'rejected_samples': f.rejected_samples, 'pushed_samples': f.pushed_samples,
            'r_factor_x': r_factor_x, 'r_factor_theta': r_factor_theta,
            'force': self._last_force_used,
            'stamp': self._last_sample_t if self._last_sample_t is not None else 0.0,
            'longest_cycle_gap_s': self.cycle_gaps.longest,
        }
        return self.inputs.health(Health(OK, message, values))

    def health_status(self) -> DiagnosticStatus:
        """The DiagnosticStatus ``ekf`` of ``/cartpole/ekf/health`` (see the README, "State
        estimation", for the keys)."""
        return self._health_report.status(self.health())

    def _publish_health(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.health_status()]
        self._health_pub.publish(msg)


def main(args=None) -> None:
    run_node(EkfNode, args, name='ekf_node')

if __name__ == '__main__':
    main()
