"""The EKF in lockstep: the estimate does not depend on the order DDS delivers sample and command.

With one process a node, sample k can reach the EKF before the command that
answered sample k-1 (it comes from another process); without waiting, the
EKF would predict with the older command, and two identical lockstep runs
would differ (they did: theta amplitude 0.29 vs 0.46 deg).
"""
import math

import pytest

pytestmark = pytest.mark.ros


def _js(t, names, position=(), effort=()):
    from sensor_msgs.msg import JointState
    msg = JointState(name=list(names), position=list(position), effort=list(effort))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 10**9)
    return msg


def sample(t, x, theta):
    return _js(t, ('cart', 'pendulum'), (x, theta))


def command(t, force):
    return _js(t, ('cart',), effort=(force,))


def test_a_sample_waits_for_the_previous_command(ros_context, spin_until):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_estimation.ekf_node import EkfNode

    lockstep = EkfNode(context=ros_context, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('lockstep_wait', value=0.3),
        Parameter('stamp_tolerance', value=0.0)])   # synthetic stamps from t = 0
    node = Node('ekf_order_test', context=ros_context)
    states = []
    node.create_subscription(JointState, '/cartpole/state', states.append, 100)
    meas = node.create_publisher(JointState, '/joint_states', 10)
    force = node.create_publisher(JointState, '/cartpole/force_command', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (lockstep, node):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: meas.get_subscription_count() == 1
                          and force.get_subscription_count() == 1
                          and node.count_publishers('/cartpole/state') == 1, 10.0)
        meas.publish(sample(0.0, 0.0, math.pi))
        assert spin_until(executor, lambda: len(states) == 1, 5.0)
        # Sample 1 overtakes the command of sample 0: no estimate until the command is there.
        meas.publish(sample(0.005, 0.0001, math.pi))
        assert not spin_until(executor, lambda: len(states) == 2, 0.15)
        force.publish(command(0.0, 8.0))
        assert spin_until(executor, lambda: len(states) == 2, 5.0)
        used = {kv.key: kv.value for kv in lockstep.health_status().values}['force']
        assert used == repr(8.0)  # the prediction used u_0, the command of sample 0
        # A command that never comes (the simulator stepped on its own timeout) is not
        # waited for beyond lockstep_wait: the estimate comes with the held command.
        meas.publish(sample(0.010, 0.0002, math.pi))
        assert spin_until(executor, lambda: len(states) == 3, 5.0)
        assert [m.header.stamp.nanosec for m in states] == [0, 5_000_000, 10_000_000]
    finally:
        executor.shutdown()
        lockstep.destroy_node()
        node.destroy_node()


@pytest.mark.parametrize('force_input, used', [('acting', 6.0), ('command', 8.0)])
def test_the_prediction_takes_the_force_acting_once_it_has_come(ros_context, spin_until,
                                                                force_input, used):
    """With ``force_input`` ``acting`` the interval after a sample is predicted with the
    manager's estimate of the force the cart feels (``cartpole/force_acting``), and in
    lockstep, once such estimates come, a sample waits for it as for the command; with
    ``command`` the command as sent, whatever else comes."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_estimation.ekf_node import EkfNode

    ekf = EkfNode(context=ros_context, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('lockstep_wait', value=0.3),
        Parameter('stamp_tolerance', value=0.0), Parameter('force_input', value=force_input)])
    node = Node('ekf_acting_test', context=ros_context)
    states = []
    node.create_subscription(JointState, '/cartpole/state', states.append, 100)
    meas = node.create_publisher(JointState, '/joint_states', 10)
    force = node.create_publisher(JointState, '/cartpole/force_command', 10)
    acting = node.create_publisher(JointState, '/cartpole/force_acting', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (ekf, node):
        executor.add_node(n)

    def used_force():
        return float({kv.key: kv.value for kv in ekf.health_status().values}['force'])
    try:
        assert spin_until(executor, lambda: meas.get_subscription_count() == 1
                          and acting.get_subscription_count() == 1
                          and node.count_publishers('/cartpole/state') == 1, 10.0)
        meas.publish(sample(0.0, 0.0, math.pi))
        assert spin_until(executor, lambda: len(states) == 1, 5.0)
        force.publish(command(0.0, 8.0))
        acting.publish(command(0.0, 6.0))
        assert spin_until(executor, lambda: ekf.forces.acting_seen, 5.0)
        meas.publish(sample(0.005, 0.0001, math.pi))
        assert spin_until(executor, lambda: len(states) == 2, 5.0)
        assert used_force() == used
        # Sample 2 overtakes the acting force of sample 1 (its command is there): acting
        # waits for it, command does not.
        force.publish(command(0.005, 9.0))
        # (ready: with command its command is there; with acting it waits for its acting force)
        assert spin_until(executor, lambda: ekf.forces.ready((0, 5_000_000)),
                          0.3) == (force_input == 'command')
        meas.publish(sample(0.010, 0.0002, math.pi))
        assert spin_until(executor, lambda: len(states) == 3, 0.15) == (force_input == 'command')
        acting.publish(command(0.005, 7.0))
        assert spin_until(executor, lambda: len(states) == 3, 5.0)
        assert used_force() == (7.0 if force_input == 'acting' else 9.0)
    finally:
        executor.shutdown()
        ekf.destroy_node()
        node.destroy_node()


def test_a_force_input_that_is_neither_is_refused(ros_context):
    from rclpy.parameter import Parameter

    from cartpole_estimation.ekf_node import EkfNode

    ekf = EkfNode(context=ros_context)
    try:
        result = ekf.set_parameters([Parameter('force_input', value='applied')])[0]
        assert not result.successful and 'force_input must be one of' in result.reason
        assert ekf.get_parameter('force_input').value == 'acting'
        assert ekf.forces.force_input == 'acting'
        assert ekf.set_parameters([Parameter('force_input', value='command')])[0].successful
        assert ekf.forces.force_input == 'command'
    finally:
        ekf.destroy_node()
