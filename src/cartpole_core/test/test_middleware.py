"""Nothing another process does holds a node's loop (:mod:`cartpole_core.middleware`).

rmw_fastrtps waits in ``send_response`` (rclpy holding the GIL) for the
caller's reply reader to be discovered, up to the reply writer's
``max_blocking_time``: 100 ms by Fast DDS's default, which stops every thread
of the process (the bridge's 50 ms watchdogs disarm the rig). A caller whose
reply reader can never match (it asks for TRANSIENT_LOCAL replies, which a
VOLATILE reply writer does not offer) makes the server wait the whole time,
every request: a lower bound, so the count of such stalls tells the two
settings apart on a noisy machine, where a stall can only be longer.
"""
import os
import subprocess
import sys
import textwrap
import xml.etree.ElementTree as ET

import pytest

from cartpole_core.middleware import (LOCALHOST_PROFILES_NAME, PROFILES_NAME, PROFILES_VARIABLE,
                                     RANGE_VARIABLE, REPLY_WAIT_S, REQUESTED_RANGE_VARIABLE,
                                     USER_VARIABLES, discovery_range, keep_on_this_host,
                                     profiles_file, set_discovery_range, use_profiles)

NS = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


@pytest.mark.parametrize('name', [PROFILES_NAME, LOCALHOST_PROFILES_NAME])
def test_the_profiles_bound_a_reply_and_use_no_shared_memory(name):
    path = profiles_file(name)
    assert path is not None and path.is_file()
    root = ET.parse(path).getroot()
    profile = root.find("p:profiles/p:data_writer[@profile_name='service']", NS)
    blocking = profile.find('p:qos/p:reliability/p:max_blocking_time', NS)
    wait = int(blocking.find('p:sec', NS).text) + int(blocking.find('p:nanosec', NS).text) * 1e-9
    assert wait == pytest.approx(REPLY_WAIT_S) and REPLY_WAIT_S <= 0.005
    participant = root.find("p:profiles/p:participant[@is_default_profile='true']", NS)
    assert participant.find('p:rtps/p:useBuiltinTransports', NS).text == 'false'
    used = {t.text for t in participant.findall('p:rtps/p:userTransports/p:transport_id', NS)}
    kinds = {d.find('p:type', NS).text
             for d in root.findall('p:profiles/p:transport_descriptors/p:transport_descriptor', NS)
             if d.find('p:transport_id', NS).text in used}
    assert kinds == {'UDPv4'}
    peers = participant.findall('p:rtps/p:builtin/p:initialPeersList/p:locator/p:udpv4/p:address',
                                NS)
    assert [a.text for a in peers] == (['127.0.0.1'] if name == LOCALHOST_PROFILES_NAME else [])


def test_use_profiles_sets_ours_and_keeps_a_users_file_or_another_rmw():
    environ = {}
    assert use_profiles(environ) == profiles_file()
    assert environ == {PROFILES_VARIABLE: str(profiles_file())}
    for variable in USER_VARIABLES:
        theirs = {variable: '/etc/lab/fastdds.xml', RANGE_VARIABLE: 'LOCALHOST'}
        assert use_profiles(theirs) is None                 # yours, kept
        assert theirs == {variable: '/etc/lab/fastdds.xml', RANGE_VARIABLE: 'LOCALHOST'}
    cyclone = {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}
    assert use_profiles(cyclone) is None
    assert PROFILES_VARIABLE not in cyclone
    fastrtps = {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}
    use_profiles(fastrtps)
    assert fastrtps[PROFILES_VARIABLE] == str(profiles_file())


def test_localhost_discovery_is_handed_to_the_profile_and_inherited():
    local = str(profiles_file(LOCALHOST_PROFILES_NAME))
    for asked in ({RANGE_VARIABLE: 'localhost'}, {'ROS_LOCALHOST_ONLY': '1'}):
        environ = dict(asked)
        assert str(use_profiles(environ)) == local
        # rmw_fastrtps would add its shared-memory transport for LOCALHOST
        assert environ == {PROFILES_VARIABLE: local, RANGE_VARIABLE: 'SYSTEM_DEFAULT',
                           REQUESTED_RANGE_VARIABLE: 'LOCALHOST'}
        assert discovery_range(environ) == 'LOCALHOST'
        child = dict(environ)                     # a child process inherits the hand-over
        assert str(use_profiles(child)) == local and child == environ
        stripped = {k: v for k, v in environ.items() if k != PROFILES_VARIABLE}
        assert str(use_profiles(stripped)) == local
    environ = {}
    assert keep_on_this_host(environ) == 'LOCALHOST' and environ[PROFILES_VARIABLE] == local
    assert set_discovery_range('subnet', environ) == 'SUBNET'      # asked again: the network
    assert environ == {PROFILES_VARIABLE: str(profiles_file()), RANGE_VARIABLE: 'SUBNET'}
    assert keep_on_this_host(environ) == 'SUBNET'                  # a range asked is kept
    peers = {RANGE_VARIABLE: 'LOCALHOST', 'ROS_STATIC_PEERS': '192.168.0.7'}
    use_profiles(peers)                                            # rmw's peers need its range
    assert peers[RANGE_VARIABLE] == 'LOCALHOST'
    assert peers[PROFILES_VARIABLE] == str(profiles_file())


SERVER = textwrap.dedent('''
    import os, time
    from rclpy.node import Node
    from std_msgs.msg import Empty
    from cartpole_core.node_runner import run_node

    class Loop(Node):
        """A 200 Hz loop that counts its stalls of 95 ms or more; its parameter
        services are the ones a caller asks."""

        def __init__(self):
            super().__init__('loop')
            self.last = None
            self.stalls = 0
            self.pub = self.create_publisher(Empty, 'loop_alive', 10)
            self.create_timer(0.005, self.tick)

        def tick(self):
            now = time.monotonic()
            if self.last is not None and now - self.last >= 0.095:
                self.stalls += 1
            self.last = now
            self.pub.publish(Empty())

        def destroy_node(self):
            print('stalls', self.stalls, os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE'),
                  flush=True)
            super().destroy_node()

    run_node(Loop, name='loop')
''')


@pytest.mark.ros
def test_a_caller_that_is_never_discovered_does_not_stall_a_node(ros_context, spin_until):
    """Four such callers: with Fast DDS's 100 ms the loop stalls at least once for each."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Empty

    from cartpole_core.child_process import interrupt

    env = {k: v for k, v in os.environ.items() if k not in USER_VARIABLES}
    server = subprocess.Popen([sys.executable, '-c', SERVER], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    caller = Node('_late_caller', context=ros_context)
    alive = []
    caller.create_subscription(Empty, '/loop_alive', lambda m: alive.append(1), 10)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(caller)
    never = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                       reliability=ReliabilityPolicy.RELIABLE)
    try:
        assert spin_until(executor, lambda: len(alive) > 10, 60.0), 'the loop did not start'
        for _ in range(4):
            client = caller.create_client(GetParameters, '/loop/get_parameters',
                                          qos_profile=never)
            for _ in range(10):  # a request every 10 of the loop's ticks, for 100 ticks
                client.call_async(GetParameters.Request(names=['use_sim_time']))
                seen = len(alive)
                spin_until(executor, lambda: len(alive) >= seen + 10, 30.0)
            caller.destroy_client(client)
    finally:
        executor.shutdown(timeout_sec=1.0)
        caller.destroy_node()
        interrupt(server, 10.0, drain=False)
    out, err = server.communicate()
    line = [ln for ln in out.splitlines() if ln.startswith('stalls')]
    assert line, (out[-1000:], err[-2000:])
    _, stalls, profile = line[0].split(maxsplit=2)
    assert profile == str(profiles_file(LOCALHOST_PROFILES_NAME))  # run_node, before rclpy.init
    assert 'failed to send response (timeout)' in err   # the callers were never discovered
    assert int(stalls) < 3, line


PLAIN = textwrap.dedent('''
    import sys, time
    import rclpy
    from std_msgs.msg import Empty

    rclpy.init()
    node = rclpy.create_node('plain_listener')
    got = []
    node.create_subscription(Empty, '/loop_alive', lambda m: got.append(1), 10)
    deadline = time.monotonic() + 60.0
    while len(got) < 20 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    with open('/proc/self/maps') as maps:
        shared = any('/dev/shm/fastrtps_' in line for line in maps)
    print('received', len(got), 'shared_memory', shared, flush=True)
    node.destroy_node()
    rclpy.shutdown()
''')


def _maps_shared_memory(pid: int) -> bool:
    with open(f'/proc/{pid}/maps') as maps:
        return any('/dev/shm/fastrtps_' in line for line in maps)


@pytest.mark.ros
def test_a_node_maps_no_shared_memory_and_talks_to_a_plain_localhost_process():
    """Ours: UDP only. A process with rmw_fastrtps's own LOCALHOST settings (shared memory
    and UDP, as a user's ``ros2 topic echo``) maps a segment and still gets the topic."""
    from cartpole_core.child_process import interrupt

    ours = {k: v for k, v in os.environ.items() if k not in USER_VARIABLES}
    plain = {k: v for k, v in ours.items() if k != REQUESTED_RANGE_VARIABLE}
    plain[RANGE_VARIABLE] = 'LOCALHOST'
    server = subprocess.Popen([sys.executable, '-c', SERVER], env=ours, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        listener = subprocess.run([sys.executable, '-c', PLAIN], env=plain, text=True,
                                  capture_output=True, timeout=120)
        assert server.poll() is None, server.communicate()[1][-2000:]
        assert not _maps_shared_memory(server.pid)
    finally:
        interrupt(server, 10.0, drain=False)
        server.communicate()
    words = listener.stdout.split()
    assert words[:1] == ['received'], (listener.stdout, listener.stderr[-2000:])
    assert int(words[1]) >= 20 and words[3] == 'True'
