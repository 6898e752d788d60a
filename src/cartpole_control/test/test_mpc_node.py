"""The controller_manager node switches lqg -> mpc -> smc while balancing, through the standard
parameter service (what `ros2 param set /controller_manager stabilizer mpc` sends), over DDS.

The test closes the loop itself, in lockstep: the simulated plant's state goes out on
/cartpole/state, the node's force command with that stamp comes back and steps the plant
(no sleeps: each step waits on the executor for the answer, with a timeout)."""
import math

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rcl_interfaces.msg import Parameter as ParameterMsg  # noqa: E402
from rcl_interfaces.msg import ParameterType, ParameterValue  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from cartpole_control.manager_node import ControllerManagerNode  # noqa: E402
from cartpole_core.model import CartPoleParameters  # noqa: E402
from cartpole_sim.plant import Plant, Scenario  # noqa: E402

P = CartPoleParameters()


class LockstepLoop:
    """Plant <-> controller_manager over DDS, one sample at a time."""

    def __init__(self, context, spin_until, manager):
        self.node = Node('mpc_switch_test', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(manager)
        self.manager = manager
        self.spin_until = spin_until
        self.commands, self.status = {}, {}
        self.node.create_subscription(JointState, '/cartpole/force_command', self._on_command, 10)
        self.node.create_subscription(DiagnosticArray, '/cartpole/controller_status',
                                      self._on_status, 10)
        self.pub = self.node.create_publisher(JointState, '/cartpole/state', 10)
        self.set_client = self.node.create_client(SetParameters,
                                                  '/controller_manager/set_parameters')
        self.plant = Plant(P, Scenario(x0=P.x_middle, theta0=0.03))
        self.t = 0.0

    @staticmethod
    def _key(stamp):
        return stamp.sec, stamp.nanosec

    def _on_command(self, msg):
        self.commands[self._key(msg.header.stamp)] = msg.effort[0]

    def _on_status(self, msg):
        (status,) = msg.status
        self.status[self._key(msg.header.stamp)] = {kv.key: kv.value for kv in status.values}

    def step(self):
        """Send the plant's state, wait for its command and status, step the plant with it."""
        x, theta, x_dot, theta_dot = (float(v) for v in self.plant.state)
        msg = JointState()
        msg.header.stamp.sec = int(self.t)
        msg.header.stamp.nanosec = int(round((self.t - int(self.t)) * 1e9))
        msg.name = ['cart', 'pendulum']
        msg.position = [x, theta]
        msg.velocity = [x_dot, theta_dot]
        key = self._key(msg.header.stamp)

        def answered():
            return key in self.commands and key in self.status
        for _ in range(100):  # re-publish until discovery has matched (the first may be lost)
            self.pub.publish(msg)
            if self.spin_until(self.executor, answered, 0.2):
                break
        assert answered(), f'no command for the state at t = {self.t:.3f} s'
        self.plant.step(self.commands[key])
        self.t = round(self.t + P.sample_time, 9)
        return theta, self.status[key]

    def set_stabilizer(self, name):
        assert self.spin_until(self.executor, self.set_client.service_is_ready, 20.0)
        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=name)
        future = self.set_client.call_async(SetParameters.Request(
            parameters=[ParameterMsg(name='stabilizer', value=value)]))
        assert self.spin_until(self.executor, future.done, 20.0)
        (result,) = future.result().results
        assert result.successful, result.reason

    def destroy(self):
        self.executor.remove_node(self.manager)
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()


@pytest.fixture
def loop(ros_context, spin_until):
    from rclpy.parameter import Parameter
    manager = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('stamp_tolerance', value=0.0)])   # synthetic stamps from t = 0
    loop = LockstepLoop(ros_context, spin_until, manager)
    try:
        yield loop
    finally:
        loop.destroy()
        manager.destroy_node()


def test_switching_lqg_mpc_smc_through_the_parameter_service_keeps_the_pendulum_up(loop):
    seen = []
    worst = 0.0
    for name, steps in (('lqg', 200), ('mpc', 300), ('smc', 200)):
        if name != 'lqg':
            loop.set_stabilizer(name)
        for _ in range(steps):
            theta, status = loop.step()
            seen.append((status['stabilizer'], status['mode']))
            worst = max(worst, abs(math.remainder(theta, 2.0 * math.pi)))
        assert status['stabilizer'] == name and status['mode'] == 'stabilizing'
    stabilizers = [s for s, _ in seen]
    assert stabilizers[0] == 'lqg' and 'mpc' in stabilizers and stabilizers[-1] == 'smc'
    # each switch once, in order, and the pendulum never left stabilisation
    changes = [b for a, b in zip(stabilizers, stabilizers[1:]) if a != b]
    assert changes == ['mpc', 'smc']
    assert all(mode == 'stabilizing' for _, mode in seen)
    assert worst < math.radians(3.0), math.degrees(worst)
    final_x = float(loop.plant.state[0])
    assert abs(final_x - P.x_middle) < 0.05
