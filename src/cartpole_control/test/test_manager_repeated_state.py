"""A repeated state is answered with the same command, not with a second control cycle.

The lockstep simulator re-publishes its first sample until a command for it
arrives, and the EKF re-publishes its estimate for it; a second cycle on the
same sample would advance the swing-up's integral action once more, so the
run would depend on how often the sample was repeated (it did: two identical
`--processes --lockstep` runs differed).
"""
import math

import pytest

pytestmark = pytest.mark.ros


def _state(t):
    from sensor_msgs.msg import JointState
    msg = JointState(name=['cart', 'pendulum'], position=[0.0, math.pi], velocity=[0.0, 0.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 10**9)
    return msg


def test_the_same_stamp_twice_gets_the_same_command_once_computed(ros_context, spin_until):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_control.manager_node import ControllerManagerNode

    manager = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('stamp_tolerance', value=0.0)])   # synthetic stamps from t = 0
    node = Node('repeat_test', context=ros_context)
    commands, statuses = [], []
    node.create_subscription(JointState, '/cartpole/force_command', commands.append, 100)
    node.create_subscription(DiagnosticArray, '/cartpole/controller_status', statuses.append, 100)
    pub = node.create_publisher(JointState, '/cartpole/state', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (manager, node):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() == 1, 10.0)
        for i, k in enumerate((0, 0, 0, 1)):
            pub.publish(_state(k * 0.005))
            assert spin_until(executor, lambda: len(commands) == i + 1, 5.0), f'state {i}'
        # Two control cycles (two samples), so two statuses: the repeats ran none.
        assert spin_until(executor, lambda: len(statuses) == 2, 5.0)
    finally:
        executor.shutdown()
        manager.destroy_node()
        node.destroy_node()
    first = [c.effort[0] for c in commands[:3]]
    assert first[0] != 0.0 and first == [first[0]] * 3  # one cycle, answered three times
    assert [c.header.stamp.nanosec for c in commands] == [0, 0, 0, 5_000_000]


def _sample(t):
    from sensor_msgs.msg import JointState
    msg = JointState(name=['cart', 'pendulum'], position=[0.0, math.pi])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 10**9)
    return msg


@pytest.fixture
def lockstep_manager(ros_context, spin_until):
    """A ``lockstep:=true`` controller manager (``lockstep_wait`` 0.5 s) and a test node that
    publishes states and samples to it: ``(manager, executor, states, samples, commands)``."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_control.manager_node import ControllerManagerNode

    manager = ControllerManagerNode(context=ros_context, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('lockstep_wait', value=0.5),
        Parameter('state_timeout', value=1.0),  # on the wall clock here: longer than the wait
        Parameter('stamp_tolerance', value=0.0)])  # synthetic stamps from t = 0
    node = Node('hold_test', context=ros_context)
    commands = []
    node.create_subscription(JointState, '/cartpole/force_command', commands.append, 100)
    states = node.create_publisher(JointState, '/cartpole/state', 10)
    samples = node.create_publisher(JointState, '/joint_states', 10)
    executor = SingleThreadedExecutor(context=ros_context)
    for n in (manager, node):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: states.get_subscription_count() == 1
                          and samples.get_subscription_count() == 1
                          and node.count_publishers('/cartpole/force_command') == 1, 10.0)
        yield manager, executor, states, samples, commands
    finally:
        executor.shutdown()
        manager.destroy_node()
        node.destroy_node()


def test_in_lockstep_a_state_waits_for_its_own_sample(lockstep_manager, spin_until):
    """``lockstep:=true``: the cycle of the state at t runs once the encoders' sample at t
    has arrived on joint_states (so the samples and reports before it are taken first,
    whatever the delivery order); a sample that never comes holds it ``lockstep_wait``."""
    manager, executor, states, samples, commands = lockstep_manager
    states.publish(_state(0.0))
    assert spin_until(executor, lambda: manager._held_state is not None, 5.0)
    assert commands == [] and manager.manager.catch_count == 0
    samples.publish(_sample(0.0))
    assert spin_until(executor, lambda: len(commands) == 1, 5.0)
    assert manager._held_state is None and manager.lockstep_timeouts == 0
    # The sample of 5 ms never comes: the state runs after lockstep_wait, counted.
    states.publish(_state(0.005))
    assert spin_until(executor, lambda: len(commands) == 2, 5.0)
    assert manager.lockstep_timeouts == 1
    assert [c.header.stamp.nanosec for c in commands] == [0, 5_000_000]


def test_in_lockstep_a_repeated_state_keeps_waiting_for_its_sample(lockstep_manager, spin_until):
    """The simulator re-publishes sample 0 until the loop answers, and the EKF its estimate:
    a second state 0 that arrives before the manager's joint_states subscription has matched
    keeps waiting, and sample 0 is taken once, so that the natural-frequency estimate of every
    lockstep run starts from the same samples (docs/running.md, "`cartpole run`")."""
    manager, executor, states, samples, commands = lockstep_manager
    states.publish(_state(0.0))
    assert spin_until(executor, lambda: manager._held_state is not None, 5.0)
    first = manager._held_state
    states.publish(_state(0.0))
    assert spin_until(executor, lambda: manager._held_state is not first, 5.0)
    assert manager._last_command is None  # no cycle ran without sample 0
    for _ in range(2):  # sample 0, then its re-publication (taken once)
        samples.publish(_sample(0.0))
    assert spin_until(executor, lambda: len(commands) == 1, 5.0)
    samples.publish(_sample(0.005))
    states.publish(_state(0.005))
    assert spin_until(executor, lambda: len(commands) == 2, 5.0)
    assert manager.lockstep_timeouts == 0
    window = manager.manager.plant_estimate.natural_frequency.window
    assert list(window.t) == [0.0]  # sample 0 taken once, by the cycle at 5 ms
