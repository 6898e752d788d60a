"""hw_bridge node in-process against the emulator over a real pty, driven through its
lifecycle services as ``ros2 lifecycle set`` calls them
(:class:`cartpole_hw.lifecycle_client.LifecycleClient`: ``get_available_transitions``,
then ``change_state`` with the transition of that label; ``get_state``).

Rates are judged against the emulator's own count of sample periods (device
time), not the wall clock. The emulator shares this process (and the GIL) with
the executor on a machine that runs other tests, so the rig uses 0.3 s for
the host's timeouts and the device watchdog, except where a watchdog is the
subject; the exact 50 ms limits are tested without a clock in
test_bridge_core.py and in the firmware's C++ test.
"""
import math
import time

import pytest

pytestmark = pytest.mark.ros


def _make_rig(ros_context, tmp_path, active):
    from diagnostic_msgs.msg import DiagnosticArray
    from lifecycle_msgs.msg import TransitionEvent
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from cartpole_emulator.emulated_rig import Emulator
    from cartpole_hw.hw_node import HwBridgeNode
    from cartpole_hw.lifecycle_client import LifecycleClient

    em = Emulator(link=str(tmp_path / 'emu'))
    em.device.watchdog_us = 300_000
    em.start()
    node = HwBridgeNode(context=ros_context, parameter_overrides=[
        Parameter('port', value=em.link), Parameter('home_on_start', value=True),
        Parameter('reconnect_period', value=0.1),
        Parameter('health_period', value=0.05), Parameter('command_timeout', value=0.3),
        Parameter('sample_timeout', value=0.3)])
    probe = Node('probe', context=ros_context)

    class Rig:
        pass

    r = Rig()
    r.em, r.node, r.probe = em, node, probe
    r.joint_states, r.health, r.events = [], [], []
    probe.create_subscription(JointState, '/joint_states', r.joint_states.append, 1000)
    probe.create_subscription(DiagnosticArray, '/cartpole/hw/health',
                              lambda m: r.health.append({kv.key: kv.value for kv in m.status[0].values}), 100)
    probe.create_subscription(TransitionEvent, '/hw_bridge/transition_event',
                              lambda m: r.events.append(m.goal_state.label), 100)
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
    r.lifecycle = LifecycleClient(probe, '/hw_bridge', lambda pred, t: spin(pred, t))

    def change(label, force=None):
        """``ros2 lifecycle set /hw_bridge <label>``, answering samples with ``force``."""
        r.lifecycle.spin_until = lambda pred, t: spin(pred, t, force=force)
        return r.lifecycle.change(label)

    def warm_and_activate():
        n = len(r.joint_states)
        assert spin(lambda: len(r.joint_states) > n + 25, force=0.0)   # a loop answering
        assert change('activate', force=0.0) == (True, ''), r.h()

    r.change, r.warm_and_activate = change, warm_and_activate
    try:
        assert r.lifecycle.state() == 'unconfigured'
        assert change('configure') == (True, ''), r.h()
        if active:
            warm_and_activate()
            assert spin(lambda: r.h().get('armed') == 'true', force=0.0), r.h()
        yield r
    finally:
        node.destroy_node()
        probe.destroy_node()
        em.stop()


@pytest.fixture
def rig(ros_context, tmp_path):
    """Configured and activated (armed), a controller answering."""
    yield from _make_rig(ros_context, tmp_path, active=True)


@pytest.fixture
def inactive_rig(ros_context, tmp_path):
    """Configured (streaming, disarmed)."""
    yield from _make_rig(ros_context, tmp_path, active=False)


def test_activate_arms_joint_states_at_the_device_rate_and_force_reaches_the_cart(rig):
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


def test_configure_streams_samples_with_no_force_applied(inactive_rig):
    """Inactive: samples at the device rate on /joint_states, the amplifier disabled and
    the setpoint 0 at the device however hard a controller commands; activate without a
    controller answering is refused and arms nothing."""
    rig = inactive_rig
    assert rig.lifecycle.state() == 'inactive'
    assert rig.events[:2] == ['configuring', 'inactive']
    n0, s0 = len(rig.joint_states), rig.em.samples
    outputs = set()

    def enough():
        outputs.add((rig.em.device.enabled, rig.em.device.output_setpoint(), rig.em.device.setpoint))
        return rig.em.samples - s0 >= 100

    assert rig.spin(enough, force=8.0)
    assert outputs == {(False, 0, 0)}                        # no force ever applied
    assert not any(line.startswith(b'U,') and line[:3] != b'U,0' for line in rig.em.received)
    assert rig.spin(lambda: len(rig.joint_states) - n0 >= 0.95 * (rig.em.samples - s0), timeout=5.0)
    assert rig.h()['homed'] == 'true' and rig.h()['state'] == 'inactive'
    s1 = rig.em.samples          # nobody answers the samples for 0.4 s (> command_timeout)
    assert rig.spin(lambda: rig.em.samples > s1 + 80)
    ok, reason = rig.change('activate')                        # no controller: refused
    assert not ok and 'refused activate' in reason
    assert rig.lifecycle.state() == 'inactive' and not rig.em.device.enabled
    assert rig.node.has_parameter('armed') is False


def test_deactivate_zeroes_within_one_cycle(rig):
    """``deactivate`` while a controller pushes with 5 N: the bridge writes U,0 and E,0
    before it answers the transition, so the device takes them at the latest in the
    period after the answer (the emulator reads the port before every sample), its output
    is zero from its very next sample on, and no non-zero setpoint follows; the node is
    inactive and still streaming. Counted in the device's sample sequence."""
    device = rig.em.device
    handle, step = device.handle_line, rig.em.sample_period
    arrivals, outputs, tail = [], [], []

    def handle_line(line, now_us):          # the emulator's thread
        if line.startswith(b'E,0'):
            arrivals.append(device.seq)         # the seq of the device's next sample
        if arrivals:
            tail.append(line)
        return handle(line, now_us)

    def sample_period():
        outputs.append((device.seq, device.enabled, device.output_setpoint()))
        step()

    device.handle_line, rig.em.sample_period = handle_line, sample_period
    assert rig.spin(lambda: device.output_setpoint() == round(5.0 * 56.744), force=5.0)
    assert rig.change('deactivate', force=5.0) == (True, '')
    answered = device.seq                   # the answer came no later than this sample
    assert rig.lifecycle.state() == 'inactive'
    n = len(rig.joint_states)
    assert rig.spin(lambda: len(rig.joint_states) > n + 20, force=5.0)   # still streaming
    next_seq = arrivals[0]
    assert next_seq <= answered + 1, (arrivals, answered)  # within one period of the answer
    after = [(enabled, out) for seq, enabled, out in outputs if seq >= next_seq]
    assert after and set(after) == {(False, 0)}, after[:5]
    assert all(not line.startswith(b'U,') or line.startswith(b'U,0*') for line in tail), tail
    assert rig.h()['armed'] == 'false' and rig.events[-2:] == ['deactivating', 'inactive']


def _assert_faulted_to_unconfigured(rig, *words, reachable=True):
    """The fault's path: active -> deactivating -> errorprocessing -> unconfigured; zero
    output (and the device disabled, if the device can still be reached), the port closed;
    the health says why."""
    assert rig.spin(lambda: rig.events[-1:] == ['unconfigured'], force=5.0), (rig.events, rig.h())
    assert rig.events[-3:] == ['deactivating', 'errorprocessing', 'unconfigured'], rig.events
    assert rig.lifecycle.state() == 'unconfigured'
    device = rig.em.device
    assert rig.spin(lambda: device.output_setpoint() == 0 and not (reachable and device.enabled),
                    force=5.0), device
    assert rig.node.link is None
    h0 = len(rig.health)
    assert rig.spin(lambda: len(rig.health) > h0)
    h = rig.h()
    assert h['armed'] == 'false' and h['state'] == 'unconfigured' and h['faults'] != '0'
    assert any(w in h['last_error'] for w in words), h['last_error']


def test_a_fault_while_active_goes_to_on_error_zero_disarmed_unconfigured(rig):
    """The device lost while active (the cable pulled): on_error, then configure and
    activate again bring the rig back (its encoders still homed)."""
    assert rig.spin(lambda: rig.em.device.setpoint > 0, force=5.0)
    rig.em.disconnect(0.5)
    _assert_faulted_to_unconfigured(rig, 'link lost', 'no valid sample', reachable=False)
    rig.em.device.watchdog_us = 300_000
    assert rig.spin(lambda: rig.em.connected, timeout=5.0)
    ok, _ = rig.change('configure')
    if not ok:                                    # the emulator re-opens its pty late
        assert rig.spin(lambda: False, timeout=0.5) is False
        ok, _ = rig.change('configure')
    assert ok, rig.h()
    assert rig.h().get('homed', 'true') == 'true'
    rig.warm_and_activate()
    assert rig.spin(lambda: rig.em.device.output_setpoint() == round(2.0 * 56.744), force=2.0)


def test_silent_command_source_trips_the_host_watchdog(rig):
    from rclpy.parameter import Parameter
    # the host watchdog is the subject: the device watchdog and the sample timeout,
    # which a loaded machine can trip first (one process, one GIL), are set out of its way
    rig.em.device.watchdog_us = 5_000_000
    assert rig.node.set_parameters([Parameter('sample_timeout', value=1.0)])[0].successful
    assert rig.spin(lambda: rig.em.device.setpoint == round(5.0 * 56.744), force=5.0)
    # the controller dies: no more commands
    assert rig.spin(lambda: rig.events[-1:] == ['unconfigured']), (rig.events, rig.h())
    tail = rig.em.received[-8:]
    assert b'U,0*49' in tail and b'E,0*59' in tail
    assert rig.em.device.output_setpoint() == 0
    _assert_faulted_to_unconfigured(rig, 'host watchdog')
    assert rig.h()['watchdog_trips'] == '1'


def test_link_stall_trips_the_device_watchdog_and_the_bridge_disarms(rig):
    rig.em.device.watchdog_us = 50_000                    # the firmware's
    assert rig.spin(lambda: rig.em.device.setpoint > 0, force=5.0)
    rig.em.stall(600)
    # keep commanding: the bridge still gets no samples, the device no U
    assert rig.spin(lambda: rig.em.device.watchdog_tripped or rig.node.link is None, timeout=5.0)
    assert rig.em.device.output_setpoint() == 0
    _assert_faulted_to_unconfigured(rig, 'no valid sample', 'host watchdog', 'device')


def test_corrupted_stream_is_survived_with_zero_force_while_bad(rig):
    rig.em.set_faults(corrupt=0.2)
    s0 = rig.em.samples
    assert rig.spin(lambda: rig.em.samples - s0 >= 100, force=3.0)
    h = rig.h()
    assert int(h['bad_lines']) > 5 and h['armed'] == 'true'       # 20 % bad lines survived
    rig.em.set_faults(corrupt=1.0)                                # nothing valid any more
    _assert_faulted_to_unconfigured(rig, 'no valid sample', 'host watchdog')
    rig.em.set_faults(corrupt=0.0)
    assert rig.change('configure') == (True, '')
    rig.warm_and_activate()
    assert rig.spin(lambda: rig.em.device.enabled)


def test_disconnect_while_inactive_reconnects_and_homing_is_refused_while_armed(inactive_rig):
    from std_srvs.srv import Trigger

    rig = inactive_rig
    rig.em.disconnect(0.5)
    assert rig.spin(lambda: rig.h().get('connected') == 'false', force=5.0)
    assert rig.spin(lambda: rig.h().get('connected') == 'true' and rig.h().get('reconnects') == '1')
    n = len(rig.joint_states)
    assert rig.spin(lambda: len(rig.joint_states) > n + 20)
    h = rig.h()
    assert h['state'] == 'inactive' and h['homed'] == 'true'     # counts kept
    assert not rig.em.device.enabled
    # homing is allowed while disarmed, refused while armed
    home = rig.probe.create_client(Trigger, '/hw_bridge/home')
    future = home.call_async(Trigger.Request())
    assert rig.spin(future.done) and future.result().success
    h0 = len(rig.health)
    assert rig.spin(lambda: len(rig.health) > h0 and rig.h()['homing'] == 'false')
    assert rig.h()['homed'] == 'true'
    rig.warm_and_activate()
    future = home.call_async(Trigger.Request())
    assert rig.spin(future.done, force=0.0) and not future.result().success
    assert 'armed' in future.result().message


def test_cleanup_closes_the_port_and_home_needs_a_configured_bridge(inactive_rig):
    from std_srvs.srv import Trigger

    rig = inactive_rig
    assert rig.change('cleanup') == (True, '')
    assert rig.lifecycle.state() == 'unconfigured' and rig.node.link is None
    assert not rig.em.device.streaming and not rig.em.device.enabled
    home = rig.probe.create_client(Trigger, '/hw_bridge/home')
    future = home.call_async(Trigger.Request())
    assert rig.spin(future.done) and not future.result().success
    assert 'configure' in future.result().message
    ok, reason = rig.change('activate')
    assert not ok and 'no transition' in reason and 'configure' in reason


def test_configure_of_a_missing_port_is_refused_and_stays_unconfigured(ros_context, tmp_path,
                                                                       spin_until):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    from cartpole_hw.hw_node import HwBridgeNode
    from cartpole_hw.lifecycle_client import LifecycleClient

    node = HwBridgeNode(context=ros_context, parameter_overrides=[
        Parameter('port', value=str(tmp_path / 'no-such-port'))])
    probe = Node('probe', context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(probe)
    try:
        client = LifecycleClient(probe, 'hw_bridge', lambda p, t: spin_until(executor, p, t))
        ok, reason = client.change('configure')
        assert not ok and 'refused configure' in reason
        assert client.state() == 'unconfigured' and node.link is None
    finally:
        node.destroy_node()
        probe.destroy_node()


def test_bad_parameter_values_are_refused_with_reasons(rig):
    from rclpy.parameter import Parameter

    results = rig.node.set_parameters([Parameter('command_timeout', value=-1.0),
                                       Parameter('cart_sign', value=1)])
    assert [r.successful for r in results] == [False, False]
    assert all(r.reason for r in results)
    assert rig.node.get_parameter('command_timeout').value == 0.3     # unchanged


def test_nothing_is_published_from_the_reader_thread(rig):
    """Every /joint_states publication runs in the thread that spins the executor."""
    import threading

    spinner, threads = threading.get_ident(), set()
    publish = rig.node._joint_pub.publish

    def recording(msg):
        threads.add(threading.get_ident())
        publish(msg)

    rig.node._joint_pub.publish = recording
    n = len(rig.joint_states)
    assert rig.spin(lambda: len(rig.joint_states) > n + 50, force=0.0)
    assert threads == {spinner}


def test_a_command_s_age_counts_from_the_receipt_of_its_sample(rig):
    """The stamp is the device's sampling time; a sample read 80 ms late (a USB burst, a
    stalled reader) and answered at once is fresh, an unknown stamp 80 ms old is not."""
    node = rig.node
    now = node.get_clock().now().nanoseconds
    sampled = now - 80_000_000                 # device time of a sample read just now
    node.receipts.note(sampled, now, 12345)
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
    # each the same latency as the device's record, up to what the stamps may move between
    # the two samples: the offset's slew over the sample periods between (the report comes
    # with the sample after the application: at most ceil(latency / 5 ms) + 1) and the
    # drift estimate over the latency (both bounded by DeviceClockConfig)
    from cartpole_hw.device_clock import DeviceClockConfig
    clock = DeviceClockConfig()

    def bound(device):
        return (math.ceil(device / 0.005) + 1) * clock.max_slew + clock.max_drift * device + 1e-8

    assert all(abs(measured - device) <= bound(device) for measured, device in pairs), \
        [(m, d) for m, d in pairs if abs(m - d) > bound(d)]
    h = rig.h()
    assert int(h['actuation_reports']) >= 40 and 0.0 < float(h['actuation_latency_s']) < 0.3


def test_a_force_command_the_rig_cannot_produce_is_dropped_and_counted(rig):
    """NaN, 1e308, no joint name, a zero stamp: none reaches the device; the setpoint of
    the good commands around them does, and the health says WARN with the count."""
    import math

    from sensor_msgs.msg import JointState
    bad = []
    for effort, names, zero in ((math.nan, ['cart'], False), (1e308, ['cart'], False),
                                (5.0, [], False), (5.0, ['cart'], True)):
        msg = JointState(name=names, effort=[effort])
        if not zero:
            msg.header.stamp = rig.node.get_clock().now().to_msg()
        bad.append(msg)
    assert rig.spin(lambda: rig.em.device.setpoint == round(2.0 * 56.744), force=2.0)
    for msg in bad:
        rig.pub.publish(msg)
    assert rig.spin(lambda: int(rig.h().get('refused_inputs', '0')) == len(bad), force=2.0), \
        rig.h()
    health = rig.h()
    assert health['armed'] == 'true' and rig.em.device.setpoint == round(2.0 * 56.744)
    assert (health['refused_inputs.non_finite'], health['refused_inputs.effort_range'],
            health['refused_inputs.joint_names'], health['refused_inputs.zero_stamp']) == \
        ('1', '1', '1', '1'), health
