"""The controller_manager node over DDS: the control cycle, status, parameters through the
standard parameter services (what `ros2 param set` sends), stale state, restart, executable."""
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from cartpole_control.controllers.lqg import LqgStabilizer  # noqa: E402
from cartpole_control.manager_node import STATUS_KEYS, ControllerManagerNode  # noqa: E402
from cartpole_core.child_process import reap  # noqa: E402
from cartpole_core.model import CartPoleParameters  # noqa: E402

P = CartPoleParameters()
ROOT = Path(__file__).resolve().parents[3]
EXECUTABLE = ROOT / 'install/cartpole_control/lib/cartpole_control/controller_manager'


class Harness:
    """A test node: publishes states, records commands and status, calls services."""

    def __init__(self, context, spin_until, target='/controller_manager'):
        self.node = Node('test_harness', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.spin_until = spin_until
        self.commands, self.status = [], []
        self.node.create_subscription(JointState, '/cartpole/force_command',
                                      self.commands.append, 10)
        self.node.create_subscription(DiagnosticArray, '/cartpole/controller_status',
                                      self.status.append, 10)
        self.acting = []
        self.node.create_subscription(JointState, '/cartpole/force_acting',
                                      self.acting.append, 10)
        self.pub = self.node.create_publisher(JointState, '/cartpole/state', 10)
        self.set_client = self.node.create_client(SetParameters, f'{target}/set_parameters')
        self.get_client = self.node.create_client(GetParameters, f'{target}/get_parameters')
        self.describe_client = self.node.create_client(DescribeParameters,
                                                       f'{target}/describe_parameters')
        self.restart_client = self.node.create_client(Trigger, f'{target}/restart_swingup')

    def call(self, client, request, timeout=20.0):
        assert self.spin_until(self.executor, client.service_is_ready, timeout)
        future = client.call_async(request)
        assert self.spin_until(self.executor, future.done, timeout)
        return future.result()

    def set(self, **values):
        msgs = []
        for name, value in values.items():
            name = name.replace('__', '.')
            if isinstance(value, bool):
                v = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
            elif isinstance(value, str):
                v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
            elif isinstance(value, list):
                v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                   double_array_value=value)
            else:
                v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
            msgs.append(ParameterMsg(name=name, value=v))
        return self.call(self.set_client, SetParameters.Request(parameters=msgs)).results

    def get(self, *names):
        values = self.call(self.get_client, GetParameters.Request(names=list(names))).values
        out = []
        for v in values:
            out.append({ParameterType.PARAMETER_DOUBLE: v.double_value,
                        ParameterType.PARAMETER_STRING: v.string_value,
                        ParameterType.PARAMETER_BOOL: v.bool_value,
                        ParameterType.PARAMETER_DOUBLE_ARRAY: list(v.double_array_value)
                        }.get(v.type))
        return out

    def send_state(self, t, x=P.x_middle, theta=0.05, x_dot=0.0, theta_dot=0.0):
        """Publish one state and wait for the command and status echoing its stamp."""
        msg = JointState()
        msg.header.stamp.sec = int(t)
        msg.header.stamp.nanosec = int(round((t - int(t)) * 1e9))
        msg.name = ['pendulum', 'cart']  # by name, not by order
        msg.position = [theta, x]
        msg.velocity = [theta_dot, x_dot]
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        same = lambda m: (m.header.stamp.sec, m.header.stamp.nanosec) == stamp  # noqa: E731

        def arrived():
            return any(same(m) for m in self.commands) and any(same(m) for m in self.status)
        # Re-publish until discovery has matched (the first message may be lost).
        for _ in range(100):
            self.pub.publish(msg)
            if self.spin_until(self.executor, arrived, 0.2):
                break
        assert arrived()
        command = [m for m in self.commands if same(m)][-1]
        status = [m for m in self.status if same(m)][-1]
        return command, status

    def destroy(self):
        self.executor.remove_node(self.node)
        self.node.destroy_node()


def values_of(status_array):
    (status,) = status_array.status
    return status, {kv.key: kv.value for kv in status.values}


@pytest.fixture
def graph(ros_context, spin_until):
    from rclpy.parameter import Parameter
    node = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('stamp_tolerance', value=0.0)])   # synthetic stamps from t = 0
    harness = Harness(ros_context, spin_until)
    harness.executor.add_node(node)
    try:
        yield node, harness
    finally:
        harness.executor.remove_node(node)
        node.destroy_node()
        harness.destroy()


def test_cycle_publishes_force_and_status_with_the_state_stamp(graph):
    node, h = graph
    command, status_array = h.send_state(12.345, theta=0.05)
    assert command.name == ['cart'] and len(command.effort) == 1
    assert math.isfinite(command.effort[0]) and command.effort[0] != 0.0
    status, kv = values_of(status_array)
    assert status.name == 'controller_manager'
    assert status.level == DiagnosticStatus.OK and status.message == 'stabilizing'
    assert list(kv) == list(STATUS_KEYS)
    assert kv['mode'] == 'stabilizing' and kv['event'] == 'catch'
    assert (kv['swingup'], kv['stabilizer'], kv['enabled']) == ('pendulum_energy', 'lqg', 'true')
    assert float(kv['force']) == command.effort[0]
    assert float(kv['state_stamp']) == pytest.approx(12.345)
    assert float(kv['catch_count']) == 1.0
    assert kv['swingup_law'] == 'pendulum_energy'  # the law of the swing-up that was caught
    assert float(kv['energy_error']) == pytest.approx(
        P.upright_energy - float(kv['energy']), abs=1e-12)


def test_each_command_comes_with_the_force_acting_by_the_plant_estimate(graph):
    """cartpole/force_acting, for the EKF: the command itself on the model's actuator; with
    actuator.gain 0.8 and 7.5 ms of actuator dead time (no latency reported), 0.8 times the
    mean over the next 5 ms of the commands each acting 7.5 ms after its state."""
    node, h = graph

    def acting_of(command):
        stamp = command.header.stamp
        assert h.spin_until(h.executor, lambda: any(m.header.stamp == stamp for m in h.acting),
                            5.0)
        (msg,) = [m for m in h.acting if m.header.stamp == stamp]
        assert msg.name == ['cart'] and len(msg.effort) == 1
        return msg.effort[0]
    command, _ = h.send_state(12.0, theta=0.05)
    assert acting_of(command) == command.effort[0]
    results = h.set(actuator__gain=0.8, actuator__delay=0.0075)
    assert all(r.successful for r in results), [r.reason for r in results]
    commands = [h.send_state(12.005 + 0.005 * k, theta=0.05 - 0.01 * k)[0] for k in range(3)]
    c0, c1, c2 = (c.effort[0] for c in commands)
    assert acting_of(commands[2]) == pytest.approx(0.8 * 0.5 * (c0 + c1))


def test_set_parameters_service_switches_the_stabiliser_within_one_cycle(graph):
    node, h = graph
    h.send_state(1.0)
    (result,) = h.set(stabilizer='smc')
    assert result.successful, result.reason
    _, status_array = h.send_state(1.005)
    _, kv = values_of(status_array)
    assert kv['stabilizer'] == 'smc' and kv['event'] == 'switch:stabilizer=smc'
    assert h.get('stabilizer') == ['smc']


def test_the_parameter_service_builds_the_new_instance_once_and_the_cycle_only_swaps(graph):
    """`ros2 param set`: the on-set check builds and configures the instance, the post-set
    queues that one (no second copy), the cycle builds nothing; its compute time is reported."""
    node, h = graph
    h.send_state(1.0)
    built = node.manager.plugin_constructions
    (result,) = h.set(lqg__r=0.02)                 # a gain of the running stabiliser
    assert result.successful, result.reason
    assert node.manager.plugin_constructions == built + 1
    old = node.manager.active_plugins()['stabilizer']
    assert old.gains['r'] == 0.01 and old.active     # the new one waits for the cycle
    h.send_state(1.005)
    assert node.manager.plugin_constructions == built + 1
    new = node.manager.active_plugins()['stabilizer']
    assert new.gains['r'] == 0.02 and new.active and not old.active
    (result,) = h.set(stabilizer='pid')
    assert result.successful and node.manager.plugin_constructions == built + 2
    _, status_array = h.send_state(1.010)
    _, kv = values_of(status_array)
    assert kv['event'] == 'switch:stabilizer=pid' and node.manager.plugin_constructions == built + 2
    last, longest = float(kv['cycle_compute_s']), float(kv['max_cycle_compute_s'])
    assert 0.0 < last <= longest


def test_bad_values_are_refused_with_reasons_and_old_values_kept(graph):
    node, h = graph
    (result,) = h.set(stabilizer='lqr')
    assert not result.successful
    assert 'lqr' in result.reason and "'mpc'" in result.reason
    assert "'lqg'" in result.reason and "'smc'" in result.reason
    (result,) = h.set(lqg__r=-1.0)  # out of the descriptor's range: rclpy refuses
    assert not result.successful and 'lqg.r' in result.reason
    (result,) = h.set(lqg__q=[-1.0, 400.0, 100.0, 400.0])  # element out of range: we refuse
    assert not result.successful and 'below its minimum' in result.reason
    (result,) = h.set(lqg__q=[1.0, 2.0])
    assert not result.successful and 'needs 4 entries' in result.reason
    (result,) = h.set(fall__angle_deg=10.0)
    assert not result.successful and 'catch angle' in result.reason
    (result,) = h.set(x_ref='middle')  # wrong type: rclpy refuses
    assert not result.successful
    assert h.get('stabilizer', 'lqg.r', 'lqg.q', 'fall.angle_deg', 'x_ref') == [
        'lqg', 0.01, list(LqgStabilizer.defaults()['q']), 45.0, pytest.approx(P.travel / 2)]
    _, status_array = h.send_state(2.0)
    assert values_of(status_array)[1]['stabilizer'] == 'lqg'
    # A good gain is taken.
    (result,) = h.set(lqg__r=0.02)
    assert result.successful
    assert h.get('lqg.r') == [0.02]


def test_describe_parameters_shows_descriptions_and_ranges(graph):
    node, h = graph
    names = ['catch.angle_deg', 'stabilizer', 'lqg.q', 'sample_time', 'pendulum_energy.k_e',
             'pid.cart_gains']
    descriptors = h.call(h.describe_client,
                         DescribeParameters.Request(names=names)).descriptors
    d = dict(zip(names, descriptors))
    assert '(6.4)' in d['catch.angle_deg'].description
    (rng,) = d['catch.angle_deg'].floating_point_range
    assert (rng.from_value, rng.to_value) == (1.0, 90.0)
    assert 'lqg' in d['stabilizer'].additional_constraints
    assert 'smc' in d['stabilizer'].additional_constraints
    assert '3 numbers' in d['pid.cart_gains'].additional_constraints
    assert '4 entries' in d['lqg.q'].description and '5' in d['lqg.q'].description
    assert d['sample_time'].read_only and not d['catch.angle_deg'].read_only
    assert d['pendulum_energy.k_e'].description
    assert not any(x.dynamic_typing for x in descriptors)


def test_stale_state_gives_zero_force_and_fault_then_restart(graph, spin_until):
    node, h = graph
    h.send_state(3.0)
    # No further state: the stale timer commands zero and reports the fault.
    def stale_reported():
        return any(values_of(s)[1]['event'] == 'fault:stale state' for s in h.status)
    assert spin_until(h.executor, stale_reported, 10.0)
    stale = [s for s in h.status if values_of(s)[1]['event'] == 'fault:stale state'][-1]
    status, kv = values_of(stale)
    assert status.level == DiagnosticStatus.ERROR and kv['mode'] == 'fault'
    assert float(kv['force']) == 0.0 and h.commands[-1].effort[0] == 0.0
    # stamped in the states' clock (3 s and the silence), not the wall clock's 2026
    zero = h.commands[-1].header.stamp
    assert 3.05 <= zero.sec + 1e-9 * zero.nanosec < 13.0
    (report,) = node.diagnostics.publish().status            # /diagnostics: the input stopped
    assert report.level == DiagnosticStatus.STALE and 'stale state' in report.message
    command, status_array = h.send_state(3.5)
    assert command.effort[0] == 0.0 and values_of(status_array)[1]['mode'] == 'fault'
    (report,) = node.diagnostics.publish().status            # states again, still the fault
    assert (report.name, report.level) == ('controller_manager: control', DiagnosticStatus.ERROR)
    assert report.message.startswith('fault: stale state')
    reply = h.call(h.restart_client, Trigger.Request())
    assert reply.success and 'swing-up' in reply.message
    command, status_array = h.send_state(3.505)
    assert values_of(status_array)[1]['mode'] in ('swingup', 'stabilizing')


def test_a_stall_of_the_manager_is_not_silence_of_the_ekf(graph):
    """Only time this process ran counts towards state_timeout (50 ms): a check 200 ms
    after the last one means this process was stalled (the states may be queued), so
    it counts one slack (20 ms); timely checks then fault once 50 ms of running time
    passed without a state. Check times are injected: no wall clock in the verdict."""
    from cartpole_control.manager_node import STALE_CHECK_SLACK
    node, h = graph
    h.send_state(3.0)
    slack = int(STALE_CHECK_SLACK * 1e9)

    def check_after(interval_ns):
        node._last_check_ns = node.get_clock().now().nanoseconds - interval_ns
        node._check_stale()

    node._last_state_ns = node.get_clock().now().nanoseconds - 200_000_000
    check_after(200_000_000)                  # stalled 200 ms: 20 ms counted
    check_after(slack)                        # 40 ms
    assert not node._stale and node.manager.mode != 'fault'
    check_after(slack)                        # 60 ms > 50 ms of running without a state
    assert node._stale and node.manager.mode == 'fault'


def test_in_lockstep_silence_up_to_lockstep_wait_is_not_stale(ros_context):
    """Lockstep promises the same run however the processes are scheduled: an EKF that a
    loaded machine deschedules for 60 ms is not a stale state; silence beyond lockstep_wait
    (0.5 s) still is."""
    from rclpy.parameter import Parameter
    from rclpy.time import Time

    from cartpole_control.manager_node import STALE_CHECK_SLACK
    node = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('stamp_tolerance', value=0.0), Parameter('lockstep', value=True)])
    try:
        for timer in node.timers:  # the check runs by hand here
            if timer.callback == node._check_stale:
                timer.cancel()
        node._last_stamp = Time(seconds=3).to_msg()
        node._last_state_ns = node.get_clock().now().nanoseconds - 10_000_000_000
        for _ in range(20):                   # 20 timely checks: 400 ms of running, no state
            node._last_check_ns = node.get_clock().now().nanoseconds - int(STALE_CHECK_SLACK * 1e9)
            node._check_stale()
        assert not node._stale and node.manager.mode != 'fault'
        for _ in range(6):                    # 120 ms more: beyond lockstep_wait
            node._last_check_ns = node.get_clock().now().nanoseconds - int(STALE_CHECK_SLACK * 1e9)
            node._check_stale()
        assert node._stale and node.manager.mode == 'fault'
    finally:
        node.destroy_node()


def test_a_state_after_a_stall_clears_the_count(graph):
    node, h = graph
    for timer in node.timers:  # the check runs by hand here: its 10 ms timer would race it
        if timer.callback == node._check_stale:
            timer.cancel()
    h.send_state(3.0)
    node._last_state_ns = node.get_clock().now().nanoseconds - 200_000_000
    node._last_check_ns = node._last_state_ns
    node._check_stale()
    h.send_state(3.005)                       # the queued state got its turn
    assert node._silent_ns == 0 and not node._stale and node.manager.mode != 'fault'


def test_enabled_false_is_idle_with_zero_force(graph):
    node, h = graph
    (result,) = h.set(enabled=False)
    assert result.successful
    command, status_array = h.send_state(4.0)
    status, kv = values_of(status_array)
    assert command.effort[0] == 0.0 and status.level == DiagnosticStatus.OK  # idle: no trouble
    assert kv['mode'] == 'idle' and kv['enabled'] == 'false'
    (report,) = node.diagnostics.publish().status
    assert report.level == DiagnosticStatus.OK and 'control disabled' in report.message
    # No fault to clear: the answer says there is nothing to restart, and nothing changes.
    reply = h.call(h.restart_client, Trigger.Request())
    assert not reply.success and 'nothing to restart' in reply.message
    assert 'fault' not in reply.message
    _, status_array = h.send_state(4.005)
    assert values_of(status_array)[1]['mode'] == 'idle'


def test_plant_reset_starts_a_new_swingup_from_the_first_state_after_it(graph):
    from std_msgs.msg import Header

    from cartpole_core.node_runner import PLANT_RESET_QOS
    node, h = graph
    _, status_array = h.send_state(5.0, theta=0.05)                  # caught: stabilising
    assert values_of(status_array)[1]['mode'] == 'stabilizing'
    pub = h.node.create_publisher(Header, '/cartpole/plant_reset', PLANT_RESET_QOS)
    reset = Header()
    reset.stamp.sec, reset.stamp.nanosec = 5, 10_000_000              # from t = 5.01 s on
    pub.publish(reset)
    assert h.spin_until(h.executor, lambda: node._reset_from is not None, 10.0)
    _, status_array = h.send_state(5.005, theta=0.06)                 # before it: unchanged
    assert values_of(status_array)[1]['mode'] == 'stabilizing'
    _, status_array = h.send_state(5.01, x=0.0, theta=math.pi)        # the reset state
    kv = values_of(status_array)[1]
    assert (kv['mode'], kv['event'], kv['catch_count']) == ('swingup', 'plant_reset', '0')
    assert float(kv['longest_cycle_gap_s']) >= 0.0


def test_parameters_from_overrides_and_bad_overrides_refuse_to_start(ros_context):
    from rclpy.parameter import Parameter
    node = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('stabilizer', value='pid'), Parameter('catch.angle_deg', value=20.0)])
    try:
        values = node.manager.get_parameters()
        assert values['stabilizer'] == 'pid' and values['catch.angle_deg'] == 20.0
    finally:
        node.destroy_node()
    with pytest.raises(Exception, match='fall angle'):
        ControllerManagerNode(context=ros_context, parameter_overrides=[
            Parameter('catch.angle_deg', value=50.0)])


@pytest.mark.skipif(not EXECUTABLE.exists(), reason='run `make build` first')
def test_installed_executable_takes_a_params_file_and_stops_on_sigint(
        ros_context, spin_until, tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text('controller_manager:\n  ros__parameters:\n    stabilizer: smc\n'
                      '    lqg:\n      r: 0.02\n')
    proc = subprocess.Popen([sys.executable, str(EXECUTABLE), '--ros-args', '--params-file',
                             str(params)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ))
    h = Harness(ros_context, spin_until)
    try:
        assert h.get('stabilizer', 'lqg.r') == ['smc', 0.02]
        # stamped now, as the EKF stamps: the executable judges stamps against its clock
        command, status_array = h.send_state(time.time())
        assert values_of(status_array)[1]['stabilizer'] == 'smc'
        assert command.effort[0] != 0.0
        proc.send_signal(signal.SIGINT)
        # Zero force on the way out.
        assert spin_until(h.executor, lambda: h.commands[-1].effort[0] == 0.0, 20.0)
        assert proc.wait(timeout=20) == 0
        _, err = proc.communicate(timeout=5)
        assert b'Traceback' not in err, err.decode()
    finally:
        reap(proc, drain=False)
        h.destroy()
