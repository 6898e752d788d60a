"""A service's reply never holds a node's loop (:mod:`cartpole_core.middleware`).

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

from cartpole_core.middleware import (PROFILES_VARIABLE, REPLY_WAIT_S, USER_VARIABLES,
                                     profiles_file, use_profiles)

NS = {'p': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}


def test_the_service_profile_bounds_a_reply_to_one_sample_period():
    path = profiles_file()
    assert path is not None and path.is_file()
    profile = ET.parse(path).getroot().find("p:profiles/p:data_writer[@profile_name='service']",
                                            NS)
    blocking = profile.find('p:qos/p:reliability/p:max_blocking_time', NS)
    wait = int(blocking.find('p:sec', NS).text) + int(blocking.find('p:nanosec', NS).text) * 1e-9
    assert wait == pytest.approx(REPLY_WAIT_S) and REPLY_WAIT_S <= 0.005


def test_use_profiles_sets_ours_and_keeps_a_users_file_or_another_rmw():
    environ = {}
    assert use_profiles(environ) == profiles_file()
    assert environ == {PROFILES_VARIABLE: str(profiles_file())}
    for variable in USER_VARIABLES:
        theirs = {variable: '/etc/lab/fastdds.xml'}
        assert use_profiles(theirs) is None                 # yours, kept
        assert theirs == {variable: '/etc/lab/fastdds.xml'}
    cyclone = {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'}
    assert use_profiles(cyclone) is None
    assert PROFILES_VARIABLE not in cyclone
    fastrtps = {'RMW_IMPLEMENTATION': 'rmw_fastrtps_cpp'}
    use_profiles(fastrtps)
    assert fastrtps[PROFILES_VARIABLE] == str(profiles_file())


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
    assert profile == str(profiles_file())       # run_node set it before rclpy.init
    assert 'failed to send response (timeout)' in err   # the callers were never discovered
    assert int(stalls) < 3, line
