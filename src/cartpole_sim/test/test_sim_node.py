"""The simulator node on ROS: the installed executable, lockstep, parameters, reset.

Every wait is on an event with a timeout (the timeout only bounds a failing test).
"""
import math
import os
import signal
import subprocess
import time

import pytest

from cartpole_core.child_process import interrupt

pytestmark = pytest.mark.ros

TS_NS = 5_000_000


def stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Probe:
    """A test node: records /joint_states, /cartpole/true_state, /clock; sends commands."""

    def __init__(self, context, echo_force=None):
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        self.node = Node('sim_probe', context=context)
        self.joints, self.truth, self.clock = [], [], []
        self.echo_force = echo_force
        self.commands_sent = 0
        self.max_commands = None
        self._last_echoed = None
        self.pub = self.node.create_publisher(JointState, '/cartpole/force_command', 10)
        self.node.create_subscription(JointState, '/joint_states', self._on_joints, 10)
        self.node.create_subscription(JointState, '/cartpole/true_state', self.truth.append, 10)
        self.node.create_subscription(
            Clock, '/clock', self.clock.append,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))

    def stamps(self):
        """Distinct /joint_states stamps in arrival order."""
        out = []
        for msg in self.joints:
            s = stamp_ns(msg.header.stamp)
            if not out or out[-1] != s:
                out.append(s)
        return out

    def send(self, force, stamp=None, names=('cart',)):
        from sensor_msgs.msg import JointState
        msg = JointState()
        if stamp is not None:
            msg.header.stamp = stamp
        msg.name = list(names)
        msg.effort = [] if force is None else [float(force)]
        self.pub.publish(msg)

    def _on_joints(self, msg):
        self.joints.append(msg)
        s = stamp_ns(msg.header.stamp)
        if self.echo_force is None or s == self._last_echoed:
            return
        if self.max_commands is not None and self.commands_sent >= self.max_commands:
            return
        self._last_echoed = s
        self.commands_sent += 1
        force = self.echo_force(msg) if callable(self.echo_force) else self.echo_force
        self.send(force, msg.header.stamp)


@pytest.fixture
def graph(ros_context):
    """graph(**overrides) -> (sim node, probe, executor); all destroyed afterwards."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from cartpole_sim.sim_node import SimNode

    made = []
    executor = SingleThreadedExecutor(context=ros_context)

    def make(echo_force=None, **overrides):
        overrides.setdefault('stamp_tolerance', 0.0)   # the probe's commands are stamped 0
        sim = SimNode(context=ros_context, parameter_overrides=[
            Parameter(name, value=value) for name, value in overrides.items()])
        probe = Probe(ros_context, echo_force)
        made.extend([sim, probe.node])
        executor.add_node(sim)
        executor.add_node(probe.node)
        return sim, probe, executor

    try:
        yield make
    finally:
        for node in made:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()


# -- the installed executable in real time --------------------------------------------------------
def test_installed_executable_publishes_joint_states_in_real_time(ros_context, spin_until):
    from ament_index_python.packages import get_package_prefix
    from rclpy.executors import SingleThreadedExecutor

    exe = os.path.join(get_package_prefix('cartpole_sim'), 'lib', 'cartpole_sim', 'sim_node')
    assert os.access(exe, os.X_OK), exe
    started_ns = time.time_ns()
    proc = subprocess.Popen([exe, '--ros-args', '-p', 'lockstep:=false'],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env=os.environ.copy())
    probe = Probe(ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe.node)
    try:
        assert spin_until(executor, lambda: len(probe.joints) >= 400, timeout=30.0), \
            f'{len(probe.joints)} samples received'
        msgs = probe.joints
        assert all(list(m.name) == ['cart', 'pendulum'] for m in msgs)
        # Default scenario: cart at the left stop, pendulum hanging.
        assert all(abs(m.position[0]) < 1e-3 for m in msgs)
        assert all(abs(m.position[1] - math.pi) < 0.01 for m in msgs)
        # Real time: the stamps are the node clock's (the wall clock, not simulated time
        # from 0), taken while it ran, in order, one sample each; the rate itself is the
        # timer's business, measured by `cartpole bench loop`, not asserted here.
        stamps = [stamp_ns(m.header.stamp) for m in msgs]
        assert started_ns < stamps[0] and stamps[-1] <= time.time_ns()
        assert all(b > a for a, b in zip(stamps, stamps[1:]))       # none repeated or reordered
        assert len(probe.truth) > 0 and list(probe.truth[-1].effort) == [0.0, 0.0]
        assert probe.clock == []  # /clock only in lockstep
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=15.0)
        assert code in (0, -signal.SIGINT, 130), proc.stdout.read().decode(errors='replace')
    finally:
        interrupt(proc, 5.0, drain=False)
        proc.stdout.close()
        executor.remove_node(probe.node)
        probe.node.destroy_node()
        executor.shutdown()


def test_real_time_applies_command_then_watchdog_zeroes_it(graph, spin_until):
    sim, probe, executor = graph(lockstep=False, x0=0.3)
    assert spin_until(executor, lambda: len(probe.truth) >= 3, timeout=10.0)
    probe.send(20.0)
    assert spin_until(executor, lambda: any(m.effort[0] > 19.0 for m in probe.truth),
                      timeout=10.0)
    pushed = next(i for i, m in enumerate(probe.truth) if m.effort[0] > 19.0)
    # No further command: after 50 ms of simulated time the force falls back to zero.
    assert spin_until(executor, lambda: any(abs(m.effort[0]) < 1e-3
                                            for m in probe.truth[pushed:]), timeout=10.0)
    assert sim.runner.watchdog_trips == 1
    # The command acts from the sample it arrived after (t_k) and shows in samples
    # k+1..k+9; sample k+10, 50 ms after t_k, shows zero force.
    pushed_samples = sum(1 for m in probe.truth[pushed:] if m.effort[0] > 1.0)
    assert pushed_samples == 9
    assert probe.truth[-1].position[0] > 0.3


def test_real_time_stamps_are_the_plants_clock_and_a_stall_is_caught_up(graph, spin_until):
    """Real time, as a rig samples on its own clock: stamps exactly Ts apart, and when
    the process stalls (here nothing spins it for 0.1 s) the plant moves on and every
    sample it took meanwhile is published at once, stamped with its own time."""
    sim, probe, executor = graph(lockstep=False)
    assert spin_until(executor, lambda: len(probe.joints) >= 20, timeout=10.0)
    before, late_before = sim.runner.index, sim.late_samples
    time.sleep(0.1)  # the stall under test, not a wait for anything
    assert spin_until(executor, lambda: sim.runner.index > before, timeout=10.0)
    assert sim.runner.index - before >= 19 and sim.late_samples - late_before >= 18
    n = len(probe.joints)
    assert spin_until(executor, lambda: len(probe.joints) >= n + 20, timeout=10.0)
    stamps = probe.stamps()
    assert all(b - a == TS_NS for a, b in zip(stamps, stamps[1:]) if b - a <= TS_NS)
    assert all((b - a) % TS_NS == 0 for a, b in zip(stamps, stamps[1:]))  # whole periods
    # the plant's time is the stamps' time: index and stamp advance together
    truth = [stamp_ns(m.header.stamp) for m in probe.truth]
    assert (truth[-1] - truth[0]) % TS_NS == 0 and truth[-1] > truth[0]


def test_lockstep_watchdog_zero_force_sample_within_50_ms_of_the_last_command(graph,
                                                                             spin_until):
    """The watchdog by simulated stamps: the last command answers sample 2 (it arrives at t_2);
    the controller then falls silent and the sim steps on its lockstep timeout."""
    from rclpy.parameter import Parameter

    sim, probe, executor = graph(echo_force=20.0, lockstep=True, lockstep_timeout=30.0,
                                 x0=0.3)
    probe.max_commands = 3
    assert spin_until(executor, lambda: 3 * TS_NS in probe.stamps(), timeout=30.0)
    # All three answered in lockstep; from now on the sim steps without commands.
    assert sim.set_parameters([Parameter('lockstep_timeout', value=0.001)])[0].successful
    assert spin_until(executor, lambda: len(probe.truth) >= 20, timeout=30.0)
    last_command_ns = 2 * TS_NS
    pushed = [m for m in probe.truth if m.effort[0] > 19.0]
    zero = next(m for m in probe.truth
                if stamp_ns(m.header.stamp) > last_command_ns and abs(m.effort[0]) < 1e-9)
    assert stamp_ns(zero.header.stamp) - last_command_ns == 50_000_000
    assert stamp_ns(pushed[-1].header.stamp) - last_command_ns == 45_000_000
    assert sim.runner.watchdog_trips == 1


# -- lockstep -------------------------------------------------------------------------------------
def test_lockstep_does_not_advance_without_commands(graph, spin_until):
    sim, probe, executor = graph(lockstep=True, lockstep_timeout=30.0)
    # Sample 0 is re-published every 0.1 s while the controller is missing.
    assert spin_until(executor, lambda: len(probe.joints) >= 2, timeout=10.0)
    assert probe.stamps() == [0]
    # An event that must not happen: a second distinct stamp within 1 s.
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 2, timeout=1.0)
    assert sim.runner.steps == 0
    # A command for another stamp, or without a finite effort for 'cart', does not step it.
    from builtin_interfaces.msg import Time
    probe.send(5.0, stamp=Time(sec=7))
    probe.send(None, stamp=Time(sec=0))
    probe.send(float('nan'), stamp=Time(sec=0))
    probe.send(5.0, stamp=Time(sec=0), names=('pendulum',))
    assert spin_until(executor, lambda: sim.rejected_commands == 3 and sim.stale_commands == 1,
                      timeout=10.0)
    assert sim.runner.steps == 0
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 2, timeout=0.3)
    # The awaited command (stamp 0) steps it exactly once.
    probe.send(5.0, stamp=Time(sec=0))
    assert spin_until(executor, lambda: len(probe.stamps()) >= 2, timeout=10.0)
    assert probe.stamps() == [0, TS_NS]
    assert sim.runner.steps == 1


@pytest.mark.parametrize('force,x0', [(10.0, 0.2), (-10.0, 0.5)])
def test_lockstep_steps_once_per_command_and_clock_follows(graph, spin_until, force, x0):
    n = 40
    sim, probe, executor = graph(echo_force=force, lockstep=True, lockstep_timeout=30.0, x0=x0)
    probe.max_commands = n
    assert spin_until(executor, lambda: len(probe.stamps()) >= n + 1, timeout=30.0), \
        probe.stamps()
    # No extra step beyond the n commands (the timeout is 30 s).
    assert not spin_until(executor, lambda: len(probe.stamps()) > n + 1, timeout=0.3)
    assert probe.stamps() == [k * TS_NS for k in range(n + 1)]
    assert sim.runner.steps == n and sim.stale_commands == 0 and sim.lockstep_timeouts == 0
    assert stamp_ns(probe.clock[-1].clock) == n * TS_NS
    clock = [stamp_ns(c.clock) for c in probe.clock]
    assert clock == sorted(clock)
    # The cart moved in the commanded direction (10 N > 3.4 N friction) for 0.2 s.
    truth = [m for m in probe.truth if stamp_ns(m.header.stamp) == n * TS_NS][-1]
    displacement = truth.position[0] - x0
    assert math.copysign(1.0, displacement) == math.copysign(1.0, force)
    assert 0.01 < abs(displacement) < 0.1
    assert truth.effort[0] == pytest.approx(force * 1.065e4 / 1.058e4, rel=1e-3)
    measured = [m for m in probe.joints if stamp_ns(m.header.stamp) == n * TS_NS][-1]
    assert measured.position[0] == pytest.approx(truth.position[0], abs=1e-4)


def test_lockstep_graph_is_deterministic_and_matches_the_offline_runner(graph, spin_until):
    # A measurement-feedback controller in the loop, noise on: the ROS graph in lockstep gives
    # bit for bit the samples of the ROS-free SimRunner driven by the same law.
    from cartpole_core.model import CartPoleParameters
    from cartpole_sim.plant import Scenario
    from cartpole_sim.sim_runner import SimRunner

    def law(x, theta):
        return -40.0 * (x - 0.3) + 2.0 * (theta - math.pi)

    n = 60
    sim, probe, executor = graph(echo_force=lambda m: law(m.position[0], m.position[1]),
                                 lockstep=True, lockstep_timeout=30.0, x0=0.2, theta0=2.9,
                                 noise=True, seed=11)
    probe.max_commands = n
    assert spin_until(executor, lambda: len(probe.stamps()) >= n + 1, timeout=30.0)
    seen = {}
    for m in probe.joints:
        seen.setdefault(stamp_ns(m.header.stamp), tuple(m.position))
    runner = SimRunner(CartPoleParameters(), Scenario(x0=0.2, theta0=2.9, noise=True, seed=11))
    offline = {}
    for _ in range(n):
        meas = runner.sample.measurement
        offline[runner.stamp_ns] = (meas.x, meas.theta)
        runner.command(law(meas.x, meas.theta))
        runner.advance()
    offline[runner.stamp_ns] = (runner.sample.measurement.x, runner.sample.measurement.theta)
    assert seen == offline
    assert tuple(sim.runner.plant.state) == tuple(runner.plant.state)


def test_lockstep_timeout_steps_with_the_held_command(graph, spin_until):
    from rclpy.parameter import Parameter

    sim, probe, executor = graph(echo_force=10.0, lockstep=True, lockstep_timeout=30.0, x0=0.3)
    probe.max_commands = 3
    assert spin_until(executor, lambda: len(probe.stamps()) >= 4, timeout=30.0)
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 5, timeout=0.3)
    result = sim.set_parameters([Parameter('lockstep_timeout', value=0.05)])[0]
    assert result.successful, result.reason
    # With the controller gone, the graph does not hang: one step per timeout.
    assert spin_until(executor, lambda: len(probe.stamps()) >= 8, timeout=20.0)
    assert probe.stamps()[:8] == [k * TS_NS for k in range(8)]
    assert sim.lockstep_timeouts >= 4


# -- parameters and reset -------------------------------------------------------------------------
def test_invalid_parameters_refused_with_reason(graph, tmp_path):
    from rclpy.parameter import Parameter

    sim, _, _ = graph(lockstep=True, lockstep_timeout=30.0)
    cases = [
        (Parameter('x0', value=0.9), 'travel'),
        (Parameter('friction_scale', value=-1.0), ''),       # range, refused by rclpy
        (Parameter('tip_mass', value=-0.1), ''),             # range
        (Parameter('command_timeout', value=20.0), ''),      # range
        (Parameter('plant_params_file', value=str(tmp_path / 'missing.yaml')), 'does not exist'),
    ]
    bad = tmp_path / 'bad.yaml'
    bad.write_text('cartpole_plant:\n  m_c: -1.0\n')
    cases.append((Parameter('plant_params_file', value=str(bad)), 'm_c'))
    garbled = tmp_path / 'garbled.yaml'
    garbled.write_text('cartpole_plant: [m_c: {\n')
    cases.append((Parameter('plant_params_file', value=str(garbled)), 'cannot be read'))
    for parameter, word in cases:
        before = sim.get_parameter(parameter.name).value
        result = sim.set_parameters([parameter])[0]
        assert not result.successful, parameter.name
        assert result.reason and word in result.reason, result.reason
        assert sim.get_parameter(parameter.name).value == before
    # lockstep is read-only.
    result = sim.set_parameters([Parameter('lockstep', value=False)])[0]
    assert not result.successful and 'read-only' in result.reason, result.reason
    assert sim.get_parameter('lockstep').value is True
    # A good file is accepted.
    good = tmp_path / 'good.yaml'
    good.write_text('cartpole_plant:\n  m_c: 5.0\n')
    assert sim.set_parameters([Parameter('plant_params_file', value=str(good))])[0].successful


def test_set_parameters_service_refuses_x0_outside_travel(graph, spin_until):
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    sim, probe, executor = graph(lockstep=True, lockstep_timeout=30.0)
    client = probe.node.create_client(SetParameters, '/sim/set_parameters')
    assert spin_until(executor, client.service_is_ready, timeout=10.0)
    request = SetParameters.Request(parameters=[Parameter('x0', value=-0.5).to_parameter_msg(),
                                                Parameter('x0', value=0.8).to_parameter_msg()])
    future = client.call_async(request)
    assert spin_until(executor, future.done, timeout=10.0)
    results = future.result().results
    assert [r.successful for r in results] == [False, False]
    assert all(r.reason for r in results)
    assert sim.get_parameter('x0').value == 0.0


def test_reset_service_returns_plant_to_initial_state(graph, spin_until):
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from std_msgs.msg import Header

    sim, probe, executor = graph(echo_force=15.0, lockstep=True, lockstep_timeout=30.0, x0=0.3,
                                 theta0=3.0)
    announced = []
    probe.node.create_subscription(
        Header, '/cartpole/plant_reset',
        lambda msg: announced.append((stamp_ns(msg.stamp), len(probe.truth))), 10)
    probe.max_commands = 30
    assert spin_until(executor, lambda: len(probe.stamps()) >= 31, timeout=30.0)
    moved = sim.runner.plant.state
    assert moved[0] > 0.31 and moved[2] > 0.1
    # Scenario changes wait for the reset.
    assert sim.set_parameters([Parameter('x0', value=0.35)])[0].successful
    assert sim.runner.plant.state == moved
    client = probe.node.create_client(Trigger, '/sim/reset')
    assert spin_until(executor, client.service_is_ready, timeout=10.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(executor, future.done, timeout=10.0)
    assert future.result().success, future.result().message
    assert sim.runner.plant.state == [0.35, 3.0, 0.0, 0.0]
    assert sim.runner.plant.force == 0.0
    # The reset state goes out as a new, later sample.
    assert spin_until(executor, lambda: any(stamp_ns(m.header.stamp) == 31 * TS_NS
                                            for m in probe.truth), timeout=10.0)
    after = [m for m in probe.truth if stamp_ns(m.header.stamp) == 31 * TS_NS][0]
    assert list(after.position) == [0.35, 3.0]
    assert list(after.velocity) == [0.0, 0.0]
    # Announced with the reset sample's stamp.
    assert spin_until(executor, lambda: announced, timeout=10.0)
    assert [stamp for stamp, _ in announced] == [31 * TS_NS]


# -- scenario disturbances (cartpole_sim.scenario) ------------------------------------------------
def test_disturbance_parameters_make_the_scenario_and_bad_ones_are_refused(graph):
    from rclpy.parameter import Parameter

    from cartpole_sim.plant import Push

    sim, _, _ = graph(lockstep=True, lockstep_timeout=30.0, delay=0.0075, jitter=0.002,
                      drop=0.1, force_noise=0.5, actuator_gain=0.8, actuator_tau=0.003,
                      cart_mass=5.2, pushes='12:cart:10:0.1, 15:pendulum:-0.3:0.02')
    scenario = sim.runner.plant.scenario
    assert (scenario.delay, scenario.jitter, scenario.drop, scenario.force_noise,
            scenario.actuator_gain, scenario.actuator_tau, scenario.cart_mass) == \
        (0.0075, 0.002, 0.1, 0.5, 0.8, 0.003, 5.2)
    assert scenario.pushes == (Push(12.0, 'cart', 10.0, 0.1), Push(15.0, 'pendulum', -0.3, 0.02))
    assert sim.runner.plant.true_params.m_c == 5.2
    for parameter, word in [(Parameter('drop', value=1.0), 'drop'),
                            (Parameter('pushes', value='12:hand:1:1'), 'target'),
                            (Parameter('pushes', value='12:cart:1'), 'T:TARGET'),
                            (Parameter('actuator_gain', value=0.0), 'actuator_gain')]:
        before = sim.get_parameter(parameter.name).value
        result = sim.set_parameters([parameter])[0]
        assert not result.successful and word in result.reason, result.reason
        assert sim.get_parameter(parameter.name).value == before


def test_lockstep_skips_lost_samples_without_waiting_for_their_command(graph, spin_until):
    # drop: a lost sample is not published and lockstep does not wait for a command that
    # cannot come; the published ones are exactly the SimRunner's samples that are not lost.
    from cartpole_core.model import CartPoleParameters
    from cartpole_sim.plant import Scenario
    from cartpole_sim.sim_runner import SimRunner

    n = 40
    sim, probe, executor = graph(echo_force=5.0, lockstep=True, lockstep_timeout=30.0, x0=0.3,
                                 drop=0.3, seed=4)
    probe.max_commands = n
    assert spin_until(executor, lambda: len(probe.stamps()) >= n + 1, timeout=30.0)
    assert not spin_until(executor, lambda: len(probe.stamps()) > n + 1, timeout=0.3)
    runner = SimRunner(CartPoleParameters(), Scenario(x0=0.3, drop=0.3, seed=4))
    delivered = [] if runner.sample.lost else [runner.stamp_ns]
    while len(delivered) < n + 1:
        sample = runner.advance()
        if not sample.lost:
            delivered.append(sample.stamp_ns)
    assert probe.stamps() == delivered
    assert len(delivered) < delivered[-1] // TS_NS  # some were lost
    assert sim.runner.plant.lost_samples == runner.plant.lost_samples > 0
    assert sim.lockstep_timeouts == 0
    # /clock and the ground truth still carry every sample.
    assert {stamp_ns(m.header.stamp) for m in probe.truth} >= set(range(0, delivered[-1] + 1,
                                                                        TS_NS))


def test_lockstep_with_a_recorder_waits_for_its_progress(graph, spin_until):
    """recorder_window (docs/architecture.md, complete bags): sample k + 1 only once the recorder holds sample k - window."""
    from builtin_interfaces.msg import Time
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Header

    sim, probe, executor = graph(echo_force=1.0, lockstep=True, lockstep_timeout=30.0,
                                 recorder_window=2)
    progress = probe.node.create_publisher(
        Header, '/cartpole/recorder/progress',
        QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    assert spin_until(executor, lambda: probe.commands_sent >= 1, timeout=10.0)
    # Answered, but no recorder progress yet: sample 0 is not left.
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 2, timeout=0.5)
    assert sim.runner.steps == 0
    assert spin_until(executor, lambda: progress.get_subscription_count() >= 1, timeout=10.0)
    progress.publish(Header(stamp=Time(sec=0)))
    # The recorder holds sample 0: the simulator steps past samples 0, 1, 2 (up to 2
    # ahead of it) and waits at sample 3.
    assert spin_until(executor, lambda: len(probe.stamps()) >= 4, timeout=10.0)
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 5, timeout=0.5)
    assert probe.stamps() == [k * TS_NS for k in range(4)] and sim.lockstep_timeouts == 0
    progress.publish(Header(stamp=Time(nanosec=3 * TS_NS)))
    assert spin_until(executor, lambda: len(probe.stamps()) >= 7, timeout=10.0)
    assert not spin_until(executor, lambda: len(probe.stamps()) >= 8, timeout=0.5)
    assert probe.stamps()[-1] == 6 * TS_NS
