"""hw_bridge node in-process against the emulator over a real pty.

Rates are judged against the emulator's own count of sample periods (device
time), not the wall clock. The emulator shares this process (and the GIL) with
the executor on a machine that runs other tests, so the rig uses 0.3 s for
the host's timeouts and the device watchdog, except where a watchdog is the
subject; the exact 50 ms limits are tested without a clock in
test_bridge_core.py and in the firmware's C++ test.
"""
import time

import pytest

pytestmark = pytest.mark.ros


@pytest.fixture
def rig(ros_context, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_hw.emulator import Emulator
    from cartpole_hw.hw_node import HwBridgeNode

    em = Emulator(link=str(tmp_path / 'emu'))
    em.device.watchdog_us = 300_000
    em.start()
    node = HwBridgeNode(context=ros_context, parameter_overrides=[
        Parameter('port', value=em.link), Parameter('home_on_start', value=True),
        Parameter('armed', value=True), Parameter('reconnect_period', value=0.1),
        Parameter('health_period', value=0.05), Parameter('command_timeout', value=0.3),
        Parameter('sample_timeout', value=0.3)])
    probe = Node('probe', context=ros_context)

    class Rig:
        pass

    r = Rig()
    r.em, r.node, r.probe = em, node, probe
    r.joint_states, r.health = [], []
    probe.create_subscription(JointState, '/joint_states', r.joint_states.append, 1000)
    probe.create_subscription(DiagnosticArray, '/cartpole/hw/health',
                              lambda m: r.health.append({kv.key: kv.value for kv in m.status[0].values}), 100)
    r.pub = probe.create_publisher(JointState, '/cartpole/force_command', 10)
    r.executor = SingleThreadedExecutor(context=ros_context)
    r.executor.add_node(node)
    r.executor.add_node(probe)

    def command(force):
        msg = JointState()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.name = ['cart']
        msg.effort = [float(force)]
        r.pub.publish(msg)

    def spin(predicate, timeout=10.0, force=None):
        """Spin until predicate(); publish ``force`` after every new sample if given."""
        deadline = time.monotonic() + timeout
        seen = len(r.joint_states)
        while not predicate():
            if time.monotonic() > deadline:
                return False
            r.executor.spin_once(timeout_sec=0.002)
            if force is not None and len(r.joint_states) > seen:
                seen = len(r.joint_states)
                command(force)
        return True

    r.command, r.spin = command, spin
    r.h = lambda: r.health[-1] if r.health else {}
    try:
        # armed:=true at start arms once the loop is warm: a controller answering (0 N)
        assert spin(lambda: r.h().get('armed') == 'true', force=0.0), r.h()
        yield r
    finally:
        node.destroy_node()
        probe.destroy_node()
        em.stop()


def test_joint_states_at_the_device_rate_and_force_reaches_the_cart(rig):
    n0, s0 = len(rig.joint_states), rig.em.samples
    setpoints = set()

    def enough():
        setpoints.add(rig.em.device.setpoint)
        return rig.em.samples - s0 >= 200

    assert rig.spin(enough, force=8.0)
    periods = rig.em.samples - s0
    # ~200 Hz: one message a device period (late ones still arrive on a loaded machine)
    assert rig.spin(lambda: len(rig.joint_states) - n0 >= 0.95 * periods, timeout=5.0), \
        (len(rig.joint_states) - n0, periods)
    assert round(8.0 * 56.744) in setpoints                 # U,454 reached the amplifier
    last = rig.joint_states[-1]
    assert list(last.name) == ['cart', 'pendulum']
    assert max(m.position[0] for m in rig.joint_states) > 0.02   # pushed right by +8 N
    ticks = last.position[0] / (0.769 / 8737)
    assert ticks == pytest.approx(round(ticks), abs=1e-6)   # quantised encoder counts (2.4)
    assert rig.spin(lambda: rig.h().get('latency_p50', 'nan') != 'nan')
    h = rig.h()
    assert h['bad_lines'] == '0' and h['homed'] == 'true'
    assert float(h['latency_p50']) < 0.05


def test_silent_command_source_trips_the_host_watchdog(rig):
    from rclpy.parameter import Parameter
    # the host watchdog is the subject: the device watchdog and the sample timeout,
    # which a loaded machine can trip first (one process, one GIL), are set out of its way
    rig.em.device.watchdog_us = 5_000_000
    assert rig.node.set_parameters([Parameter('sample_timeout', value=1.0)])[0].successful
    assert rig.spin(lambda: rig.em.device.setpoint == round(5.0 * 56.744), force=5.0)
    # the controller dies: no more commands
    assert rig.spin(lambda: rig.h().get('watchdog_trips') == '1' and rig.h().get('armed') == 'false'), \
        rig.h()
    assert not rig.em.device.enabled and rig.em.device.output_setpoint() == 0
    tail = rig.em.received[-6:]
    assert b'U,0*49' in tail and b'E,0*59' in tail
    assert rig.spin(lambda: rig.node.get_parameter('armed').value is False)
    rig.command(5.0)                       # a late command does not re-arm anything
    assert rig.spin(lambda: rig.h().get('ignored_commands') not in (None, '0'))
    assert rig.em.device.output_setpoint() == 0


def test_link_stall_trips_the_device_watchdog_and_the_bridge_disarms(rig):
    rig.em.device.watchdog_us = 50_000                    # the firmware's
    assert rig.spin(lambda: rig.em.device.setpoint > 0, force=5.0)
    rig.em.stall(600)
    # keep commanding: the bridge still gets no samples, the device no U
    assert rig.spin(lambda: rig.em.device.watchdog_tripped, timeout=5.0)
    assert rig.em.device.output_setpoint() == 0
    assert rig.spin(lambda: rig.h().get('armed') == 'false' and rig.h().get('faults') != '0')
    assert any(w in rig.h()['last_error'] for w in ('no valid sample', 'host watchdog'))


def test_corrupted_stream_is_survived_with_zero_force_while_bad(rig):
    from std_srvs.srv import SetBool

    rig.em.set_faults(corrupt=0.2)
    s0 = rig.em.samples
    assert rig.spin(lambda: rig.em.samples - s0 >= 100, force=3.0)
    h = rig.h()
    assert int(h['bad_lines']) > 5 and h['armed'] == 'true'       # 20 % bad lines survived
    rig.em.set_faults(corrupt=1.0)                                # nothing valid any more
    assert rig.spin(lambda: rig.h().get('armed') == 'false', force=3.0)
    assert rig.em.device.output_setpoint() == 0 and not rig.em.device.enabled
    rig.em.set_faults(corrupt=0.0)
    n = len(rig.joint_states)
    assert rig.spin(lambda: len(rig.joint_states) > n + 20)
    client = rig.probe.create_client(SetBool, '/hw_bridge/arm')
    future = client.call_async(SetBool.Request(data=True))
    assert rig.spin(future.done)
    assert future.result().success, future.result().message
    assert rig.spin(lambda: rig.em.device.enabled)


def test_disconnect_and_reconnect_with_zero_force_while_down(rig):
    from std_srvs.srv import SetBool, Trigger

    assert rig.spin(lambda: rig.em.device.setpoint > 0, force=5.0)
    rig.em.disconnect(0.5)
    assert rig.spin(lambda: rig.h().get('connected') == 'false', force=5.0)
    assert rig.spin(lambda: rig.em.device.watchdog_tripped)       # device: no U -> zero current
    assert rig.em.device.output_setpoint() == 0
    assert rig.spin(lambda: rig.h().get('connected') == 'true' and rig.h().get('reconnects') == '1')
    n = len(rig.joint_states)
    assert rig.spin(lambda: len(rig.joint_states) > n + 20)
    h = rig.h()
    assert h['armed'] == 'false' and h['homed'] == 'true'         # counts kept, explicit re-arm
    assert not rig.em.device.enabled
    # homing is refused while armed, allowed while disarmed
    home = rig.probe.create_client(Trigger, '/hw_bridge/home')
    future = home.call_async(Trigger.Request())
    assert rig.spin(future.done) and future.result().success
    h0 = len(rig.health)
    assert rig.spin(lambda: len(rig.health) > h0 and rig.h()['homing'] == 'false')
    assert rig.h()['homed'] == 'true'
    arm = rig.probe.create_client(SetBool, '/hw_bridge/arm')
    future = arm.call_async(SetBool.Request(data=True))
    assert rig.spin(future.done) and future.result().success, future.result().message
    future = home.call_async(Trigger.Request())
    assert rig.spin(future.done) and not future.result().success
    assert 'armed' in future.result().message


def test_bad_parameter_values_are_refused_with_reasons(rig):
    from rclpy.parameter import Parameter

    results = rig.node.set_parameters([Parameter('command_timeout', value=-1.0),
                                       Parameter('cart_sign', value=1),
                                       Parameter('armed', value='yes')])
    assert [r.successful for r in results] == [False, False, False]
    assert all(r.reason for r in results)
    assert rig.node.get_parameter('command_timeout').value == 0.3     # unchanged


def test_a_command_s_age_counts_from_the_receipt_of_its_sample(rig):
    """The stamp is the device's sampling time; a sample read 80 ms late (a USB burst, a
    stalled reader) and answered at once is fresh, an unknown stamp 80 ms old is not."""
    node = rig.node
    now = node.get_clock().now().nanoseconds
    sampled = now - 80_000_000                 # device time of a sample read just now
    node._note_receipt(sampled, now, 12345)
    assert node.command_age(sampled, now) < 0.01
    assert node.command_age(sampled - 5_000_000, now) == pytest.approx(0.085)
    assert rig.spin(lambda: len(rig.joint_states) > 3, force=1.0)
    stale_before = int(rig.h().get('stale_commands', '0'))
    msg_stamp = rig.joint_states[-1].header.stamp      # a real sample: answered promptly
    from sensor_msgs.msg import JointState
    late = JointState(name=['cart'], effort=[1.0])
    late.header.stamp.sec, late.header.stamp.nanosec = divmod(
        msg_stamp.sec * 10**9 + msg_stamp.nanosec - 500_000_000, 10**9)  # older than the 0.3 s
    rig.pub.publish(late)
    assert rig.spin(lambda: int(rig.h().get('stale_commands', '0')) > stale_before,
                    force=1.0), rig.h()
    assert rig.h().get('armed') == 'true'


def test_commands_answering_samples_go_tagged_and_their_application_is_published(rig):
    """Protocol version 2 end to end in one process: a controller answering each sample
    with its stamp; the bridge tags the setpoints with the samples' seq, the emulator
    reports when each took effect (in device time), and ``/cartpole/command_applied``
    pairs the sample's stamp with that time on the same clock: the latency it shows is
    the device's own record of it."""
    from sensor_msgs.msg import JointState, TimeReference

    reports = []
    rig.probe.create_subscription(TimeReference, '/cartpole/command_applied', reports.append, 1000)
    answered = [0]

    def answer():
        for msg in rig.joint_states[answered[0]:]:
            out = JointState(name=['cart'], effort=[0.5])
            out.header.stamp = msg.header.stamp
            rig.pub.publish(out)
        answered[0] = len(rig.joint_states)

    def ns(t):
        return t.sec * 10**9 + t.nanosec

    assert rig.spin(lambda: answer() or len(reports) >= 60, timeout=20.0), rig.h()
    stamps = {ns(m.header.stamp) for m in rig.joint_states}
    assert all(r.source == 'hw_bridge' and ns(r.time_ref) in stamps for r in reports)
    assert any(line.count(b',') == 2 for line in rig.em.received if line.startswith(b'U,'))
    truth = {tag: ((applied - sampled) % 2**32) * 1e-6 for tag, sampled, applied in rig.em.applied}
    pairs = [((ns(r.header.stamp) - ns(r.time_ref)) * 1e-9,
              truth[rig.node.sample_seq(ns(r.time_ref))]) for r in reports[-40:]]
    assert all(0.0 <= measured < 0.3 for measured, _ in pairs), pairs
    # each the same latency as the device's record, up to the stamps' slew and clock reads
    assert all(measured == pytest.approx(device, abs=2e-4) for measured, device in pairs), pairs
    h = rig.h()
    assert int(h['actuation_reports']) >= 40 and 0.0 < float(h['actuation_latency_s']) < 0.3
