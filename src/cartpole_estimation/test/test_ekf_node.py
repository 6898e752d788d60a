"""Tests of the ``ekf`` node: in-process with an rclpy Context, and the installed executable."""
import math
import os
import signal
import subprocess
import time

import pytest

from cartpole_core.child_process import reap
from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

pytestmark = pytest.mark.ros

PARAMS = CartPoleParameters()
TS = PARAMS.sample_time


def joint_state(t, x, theta, names=('cart', 'pendulum')):
    from sensor_msgs.msg import JointState
    msg = JointState()
    msg.header.stamp.sec = int(t)
    msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))
    msg.name = list(names)
    msg.position = [x, theta] if names == ('cart', 'pendulum') else [theta, x]
    return msg


def stamp_s(stamp):
    return stamp.sec + 1e-9 * stamp.nanosec


class Harness:
    """An EkfNode plus a test node on one executor."""

    def __init__(self, context, overrides=()):
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import JointState

        from cartpole_estimation.ekf_node import EkfNode

        overrides = [('stamp_tolerance', 0.0), *overrides]   # synthetic stamps from t = 0
        self.ekf = EkfNode(context=context, parameter_overrides=[
            Parameter(name, value=value) for name, value in overrides])
        self.node = Node('ekf_test_client', context=context)
        self.states = []
        self.health = []
        self.meas_pub = self.node.create_publisher(JointState, '/joint_states', 10)
        self.force_pub = self.node.create_publisher(JointState, '/cartpole/force_command', 10)
        self.node.create_subscription(JointState, '/cartpole/state', self.states.append, 100)
        self.node.create_subscription(DiagnosticArray, '/cartpole/ekf/health',
                                      self.health.append, 10)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.ekf)
        self.executor.add_node(self.node)

    def close(self):
        self.executor.shutdown()
        self.ekf.destroy_node()
        self.node.destroy_node()


@pytest.fixture
def harness(ros_context):
    created = []

    def make(overrides=()):
        h = Harness(ros_context, overrides)
        created.append(h)
        return h
    yield make
    for h in created:
        h.close()


def connected(h, spin_until):
    return spin_until(h.executor, lambda: (
        h.meas_pub.get_subscription_count() > 0 and h.force_pub.get_subscription_count() > 0
        and h.node.count_publishers('/cartpole/state') > 0), timeout=10.0)


def test_free_swing_through_the_node(harness, spin_until):
    h = harness()
    assert connected(h, spin_until)
    plant = Plant(PARAMS, Scenario(x0=0.38, theta0=0.3))
    truth = {}
    n = 400  # 2 s
    for k in range(n):
        m = plant.measure()
        t = 100.0 + m.t  # a stamp far from zero
        truth[round(t, 6)] = plant.true_state()
        h.meas_pub.publish(joint_state(t, m.x, m.theta))
        assert spin_until(h.executor, lambda: len(h.states) > k, timeout=5.0), f'sample {k}'
        plant.step(0.0)
    assert len(h.states) == n
    errors = []
    for msg in h.states:
        assert list(msg.name) == ['cart', 'pendulum']
        state = truth[round(stamp_s(msg.header.stamp), 6)]   # same stamps
        errors.append(msg.velocity[1] - state[3])
        assert abs(msg.position[0] - state[0]) < 3 * PARAMS.cart_resolution
    tail = errors[20:]
    rms = math.sqrt(sum(e * e for e in tail) / len(tail))
    assert rms < 0.12, rms  # the numerical derivative gives about 0.27 rad/s
    assert h.ekf.filter.resets == 0 and h.ekf.counts.samples == n


def test_bad_messages_are_counted_and_dropped_and_names_found_by_name(harness, spin_until):
    h = harness()
    assert connected(h, spin_until)
    h.meas_pub.publish(joint_state(1.0, 0.3, math.pi, names=('pendulum', 'cart')))
    assert spin_until(h.executor, lambda: len(h.states) == 1, timeout=5.0)
    assert tuple(h.states[0].position) == (0.3, math.pi)
    h.meas_pub.publish(joint_state(1.005, float('nan'), math.pi))
    h.meas_pub.publish(joint_state(1.010, 0.3, math.pi, names=('cart', 'wheel')))
    h.meas_pub.publish(joint_state(1.015, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 2, timeout=5.0)
    assert h.ekf.counts.bad_messages == 2
    assert stamp_s(h.states[1].header.stamp) == pytest.approx(1.015)
    assert all(math.isfinite(v) for v in h.states[1].velocity)


def test_force_command_is_used_and_zeroed_when_stale(harness, spin_until):
    from sensor_msgs.msg import JointState
    h = harness([('command_timeout', 0.05)])
    assert connected(h, spin_until)
    h.meas_pub.publish(joint_state(1.0, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 1, timeout=5.0)
    cmd = JointState(name=['cart'], effort=[10.0])
    h.force_pub.publish(cmd)
    assert spin_until(h.executor, lambda: h.ekf.forces.for_interval(None, 1.0) == 10.0,
                      timeout=5.0)  # held
    h.meas_pub.publish(joint_state(1.005, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 2, timeout=5.0)
    assert h.ekf._last_force_used == 10.0
    # A repeated sample is not an error and not a new estimate: the same estimate is
    # published again (so a controller that missed it can answer the simulator).
    h.meas_pub.publish(joint_state(1.005, 0.3, math.pi))
    assert spin_until(h.executor, lambda: h.ekf.counts.duplicate_samples == 1, timeout=5.0)
    assert spin_until(h.executor, lambda: len(h.states) == 3, timeout=5.0)
    assert h.states[2].position == h.states[1].position
    assert h.states[2].header.stamp == h.states[1].header.stamp
    # The plant holds the command while its age at the start of a period is
    # <= 50 ms: still applied over (1.005, 1.06], zero over (1.06, 1.065].
    h.meas_pub.publish(joint_state(1.06, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 4, timeout=5.0)
    assert h.ekf._last_force_used == 10.0
    h.meas_pub.publish(joint_state(1.065, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 5, timeout=5.0)
    assert h.ekf._last_force_used == 0.0
    assert h.ekf.counts.bad_messages == 0


def test_refused_q_keeps_the_old_one_with_a_reason(harness, spin_until):
    from rclpy.parameter import Parameter
    h = harness()
    default = list(h.ekf.get_parameter('q').value)
    assert len(default) == 5 and h.ekf.filter.config.q_force == default[4] > 0.0
    for bad in ([1.0, 1.0, 50.0], [1.0, 1.0, 50.0, -1.0], [1.0, 1.0, 50.0, 50.0, -1.0],
                [1.0] * 6):
        result = h.ekf.set_parameters([Parameter('q', value=bad)])[0]
        assert not result.successful and 'q' in result.reason
    assert list(h.ekf.get_parameter('q').value) == default
    assert h.ekf.filter.config.q_diag == tuple(default[:4])
    result = h.ekf.set_parameters([Parameter('r', value=[0.01])])[0]
    assert not result.successful and 'r needs 2' in result.reason
    # the thesis's Q (9.2), one parameter away: 4 entries, no force noise
    result = h.ekf.set_parameters([Parameter('q', value=[1.0, 1.0, 50.0, 50.0])])[0]
    assert result.successful
    assert h.ekf.filter.config.q_diag == (1.0, 1.0, 50.0, 50.0)
    assert h.ekf.filter.config.q_force == 0.0
    result = h.ekf.set_parameters([Parameter('q', value=[2.0, 2.0, 20.0, 30.0, 5.0])])[0]
    assert result.successful
    assert h.ekf.filter.config.q_diag == (2.0, 2.0, 20.0, 30.0)
    assert h.ekf.filter.config.q_force == 5.0
    result = h.ekf.set_parameters([Parameter('discretisation', value='rk4')])[0]
    assert not result.successful and 'midpoint' in result.reason
    result = h.ekf.set_parameters([Parameter('plant_params_file', value='x.yaml')])[0]
    assert not result.successful
    # the push's Q: a value out of range is refused and the filter keeps its own; 0 is off
    assert h.ekf.filter.config.push_q_force == h.ekf.get_parameter('push_q_force').value > 0.0
    for name, bad in (('push_q_force', -1.0), ('push_innovation', 0.0)):
        result = h.ekf.set_parameters([Parameter(name, value=bad)])[0]
        assert not result.successful and result.reason
    assert h.ekf.filter.config.push_innovation == 1.0e-3
    result = h.ekf.set_parameters([Parameter('push_q_force', value=0.0)])[0]
    assert result.successful and h.ekf.filter.config.push_q_force == 0.0
    # R matched to the encoders: a limit below 1 is refused, a window of 0 fixes R
    result = h.ekf.set_parameters([Parameter('noise_limit', value=0.5)])[0]
    assert not result.successful and h.ekf.filter.config.noise_limit == 1000.0
    result = h.ekf.set_parameters([Parameter('noise_window', value=0.0)])[0]
    assert result.successful and h.ekf.filter.config.noise_window == 0.0


def test_bad_override_is_refused_at_start(ros_context):
    from rclpy.parameter import Parameter

    from cartpole_estimation.ekf_node import EkfNode
    with pytest.raises(ValueError, match='q needs 4'):
        EkfNode(context=ros_context, parameter_overrides=[Parameter('q', value=[1.0, 2.0])])


def test_health_topic_and_reset_service(harness, spin_until):
    from std_srvs.srv import Trigger
    h = harness([('health_period', 0.05)])
    assert connected(h, spin_until)
    client = h.node.create_client(Trigger, '/ekf/reset')
    assert client.wait_for_service(timeout_sec=10.0)
    for k in range(5):
        h.meas_pub.publish(joint_state(2.0 + k * TS, 0.3, math.pi))
        assert spin_until(h.executor, lambda: len(h.states) > k, timeout=5.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(h.executor, future.done, timeout=10.0)
    assert future.result().success
    h.meas_pub.publish(joint_state(2.0 + 5 * TS, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 6, timeout=5.0)
    h.health.clear()
    assert spin_until(h.executor, lambda: len(h.health) >= 1, timeout=10.0)
    status = h.health[-1].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert status.name == 'ekf'
    for key in ('innovation_x', 'innovation_theta', 'p_x', 'p_theta', 'p_x_dot', 'p_theta_dot',
                'resets', 'reset_reason', 'missed_samples', 'dt', 'pushed_samples',
                'r_factor_x', 'r_factor_theta'):
        assert key in values
    assert float(values['resets']) == 1.0 and values['reset_reason'] == 'requested'
    assert float(values['samples']) == 6.0
    assert float(values['r_factor_theta']) == 1.0  # noiseless samples: the configured R


def test_diagnostics_idle_ok_then_stale_when_the_samples_stop_warn_when_dropped(
        harness, spin_until):
    """``ekf: estimation`` on /diagnostics: OK before any sample (idle) and while samples
    come, STALE when none came since the previous report, WARN for a dropped sample."""
    from diagnostic_msgs.msg import DiagnosticStatus as S
    h = harness()

    def report():
        (status,) = h.ekf.diagnostics.publish().status
        return status.level, status.message, {kv.key: kv.value for kv in status.values}

    level, message, values = report()
    assert (level, message, values['samples']) == (S.OK, 'no sample yet', '0')
    assert connected(h, spin_until)
    for k in range(3):
        h.meas_pub.publish(joint_state(1.0 + k * TS, 0.3, math.pi))
        assert spin_until(h.executor, lambda: len(h.states) > k, timeout=5.0)
    assert report()[:2] == (S.OK, 'estimating')
    assert report()[:2] == (S.STALE, 'estimating; no samples since the last report')
    h.meas_pub.publish(joint_state(1.0 + 3 * TS, float('nan'), math.pi))
    h.meas_pub.publish(joint_state(1.0 + 4 * TS, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 4, timeout=5.0)
    level, message, values = report()
    assert level == S.WARN and 'bad_messages +1' in message          # (and a missed sample)
    assert (values['samples'], values['bad_messages']) == ('4', '1')   # plain counts


def test_installed_executable_answers_and_stops_on_sigint(ros_context, spin_until):
    from ament_index_python import get_package_prefix
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    exe = os.path.join(get_package_prefix('cartpole_estimation'), 'lib', 'cartpole_estimation',
                       'ekf_node')
    assert os.access(exe, os.X_OK), exe
    proc = subprocess.Popen([exe], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    node = Node('ekf_exe_test', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    try:
        states = []
        pub = node.create_publisher(JointState, '/joint_states', 10)
        node.create_subscription(JointState, '/cartpole/state', states.append, 10)
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0
                          and node.count_publishers('/cartpole/state') > 0, timeout=30.0)
        k, t0 = 0, time.time()   # stamped now: the executable judges stamps
        deadline = time.monotonic() + 20.0
        while not states and time.monotonic() < deadline:
            # Discovery of our subscription by the node can lag its discovery
            # of our publisher: resend with increasing stamps until answered.
            pub.publish(joint_state(t0 + k * TS, 0.2, math.pi))
            k += 1
            spin_until(executor, lambda: bool(states), timeout=0.5)
        assert states, 'no /cartpole/state from the executable'
        assert list(states[0].name) == ['cart', 'pendulum']
        assert states[0].position[0] == pytest.approx(0.2)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=15.0) == 0
    finally:
        reap(proc, drain=False)
        executor.shutdown()
        node.destroy_node()


def test_prediction_uses_the_command_stamped_with_the_previous_sample(harness, spin_until):
    # DDS does not order two topics: the command answering sample k may arrive after a
    # later one. The prediction over (t_k, t_k+1] uses the command stamped t_k.
    from sensor_msgs.msg import JointState
    h = harness([('command_timeout', 0.05)])
    assert connected(h, spin_until)
    first = joint_state(2.0, 0.3, math.pi)
    h.meas_pub.publish(first)
    assert spin_until(h.executor, lambda: len(h.states) == 1, timeout=5.0)
    answer = JointState(name=['cart'], effort=[-5.0])
    answer.header.stamp = first.header.stamp
    stray = JointState(name=['cart'], effort=[7.0])
    stray.header.stamp = joint_state(1.5, 0.0, 0.0).header.stamp
    h.force_pub.publish(answer)
    h.force_pub.publish(stray)  # arrives last, answers an older sample
    assert spin_until(h.executor, lambda: h.ekf.forces.for_interval(None, 2.0) == 7.0,
                      timeout=5.0)  # the latest held
    h.meas_pub.publish(joint_state(2.005, 0.3, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) == 2, timeout=5.0)
    assert h.ekf._last_force_used == -5.0


def test_plant_reset_reinitialises_from_the_first_sample_after_it(harness, spin_until):
    """/sim/reset puts the cart back at the stop: the jump is not filtered as an innovation."""
    from std_msgs.msg import Header

    from cartpole_core.node_runner import PLANT_RESET_QOS
    h = harness()
    assert connected(h, spin_until)
    reset_pub = h.node.create_publisher(Header, '/cartpole/plant_reset', PLANT_RESET_QOS)
    for k in range(20):                                   # balancing in the middle
        h.meas_pub.publish(joint_state(10.0 + k * TS, 0.38, 0.01))
        assert spin_until(h.executor, lambda: len(h.states) > k, timeout=5.0)
    reset = Header()
    reset.stamp.sec, reset.stamp.nanosec = 10, 100_000_000   # t = 10.1 s, sample 20
    reset_pub.publish(reset)
    assert spin_until(h.executor, lambda: h.ekf._reset_from is not None, timeout=5.0)
    h.meas_pub.publish(joint_state(10.1, 0.0, math.pi))
    assert spin_until(h.executor, lambda: len(h.states) > 20, timeout=5.0)
    after = h.states[20]
    assert tuple(after.position) == (0.0, math.pi) and tuple(after.velocity) == (0.0, 0.0)
    assert h.ekf.filter.resets == 1 and h.ekf._last_reset_reason == 'plant reset'
    status = h.ekf.health_status()
    kv = {v.key: v.value for v in status.values}
    assert kv['reset_reason'] == 'plant reset' and float(kv['longest_cycle_gap_s']) > 0.0
