"""`cartpole run --sim --view` in real time: a Foxglove WebSocket client sees the running rig.

The run also records (``--record``): the real-time run with a recorder, whose misses are
counted, and whose bag reads back.

A client (``websockets``) connects to the viewer the run starts in its own process;
this test process also subscribes to ``/cartpole/state`` and ``/cartpole/true_state``
over DDS. The scene and plot channels must be advertised; the scene updates must come
at 30-60 Hz by their own stamps (never two closer than 1/60 s); the estimate they
draw must be the ``/cartpole/state`` published with the same stamp (within 1 mm) and
the plant the ``/cartpole/true_state`` of that stamp. The run with its viewer must
still succeed (the run summary's verdict).
"""
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cartpole_core.child_process import reap

from cartpole_analysis.viewer.server import TOPICS
from cartpole_analysis.viewer.client import ViewerClient

_spec = importlib.util.spec_from_file_location(
    'foxglove_support', Path(__file__).resolve().parents[1] / 'src' / 'cartpole_analysis' / 'test'
    / 'foxglove_support.py')
foxglove_support = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(foxglove_support)

pytestmark = [pytest.mark.ros, pytest.mark.slow]

RUN_S = 16.0
"""Long enough for the run summary's verdict (catch at about 5 s, then 10 s of stabilising)."""
SCENES = 150
"""Scene updates the client checks (3 s at 50 Hz)."""


def _stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_client_sees_the_running_rig(tmp_path, ros_context, spin_until):
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState

    probe = Node('viewer_probe', context=ros_context)
    estimates, truths = {}, {}
    qos = QoSProfile(depth=200)
    probe.create_subscription(JointState, '/cartpole/state',
                              lambda m: estimates.__setitem__(_stamp_ns(m.header.stamp),
                                                              tuple(m.position)), qos)
    probe.create_subscription(JointState, '/cartpole/true_state',
                              lambda m: truths.__setitem__(_stamp_ns(m.header.stamp),
                                                           tuple(m.position)), qos)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(probe)
    proc = subprocess.Popen([sys.executable, '-m', 'cartpole_bringup.cli', 'run', '--sim',
                             '--duration', str(RUN_S), '--view', '127.0.0.1:0',
                             '--record', str(tmp_path / 'runs'), '--json'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    client = None
    try:
        url = foxglove_support.read_view_url(proc.stderr)
        assert url, 'cartpole run printed no viewer address'
        client = ViewerClient(url, TOPICS.values(), timeout=30.0)
        # The window checked: the scenes from the probe's first samples on (the probe's
        # DDS discovery may take a moment after the run has started).
        def window():
            if not estimates or not truths:
                return []
            start = max(min(estimates), min(truths))
            return [m for m in client.received(TOPICS['scene']) if m.log_time_ns >= start]
        assert spin_until(executor, lambda: len(window()) >= SCENES, 60.0), \
            f'too few scene updates: {client.counts}'
        scenes = window()[:SCENES]
        # Let the probe take the states of the stamps the client has.
        last = scenes[-1].log_time_ns
        assert spin_until(executor, lambda: max(estimates, default=0) > last
                          and max(truths, default=0) > last, 10.0)
        out, err = proc.communicate(timeout=RUN_S + 60)
    finally:
        reap(proc)
        if client is not None:
            client.close()
        executor.shutdown()
        probe.destroy_node()
    assert proc.returncode == 0, err[-3000:]
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary['success'] is True, summary
    assert summary['catch_time_s'] < 10.0 and summary['end_stop_contact'] is False, summary
    assert summary['swingup_law'] == 'pendulum_energy', summary
    # In real time nobody waits for the recorder: what it missed is counted.
    assert isinstance(summary['recorder_missed'], int) and summary['recorder_missed'] >= 0
    bags = list((tmp_path / 'runs').glob('*/bag'))
    assert len(bags) == 1 and (bags[0] / 'metadata.yaml').is_file(), bags
    from rosbags.highlevel import AnyReader
    with AnyReader(bags) as reader:  # the recorded run reads back
        topics = {c.topic for c in reader.connections}
    assert {'/joint_states', '/cartpole/state', '/cartpole/force_command'} <= topics, topics

    channels = client.channels
    assert set(TOPICS.values()) <= set(channels)
    assert channels[TOPICS['scene']]['schemaName'] == 'foxglove.SceneUpdate'
    assert client.counts[TOPICS['state']] > 0 and client.counts[TOPICS['control']] > 0

    stamps = np.array([m.log_time_ns for m in scenes], dtype=np.int64)
    gaps = np.diff(stamps) * 1e-9
    rate = (len(stamps) - 1) / ((stamps[-1] - stamps[0]) * 1e-9)
    assert 30.0 <= rate <= 60.0, rate
    assert gaps.min() >= 1.0 / 60.0 - 1e-9, gaps.min()

    schema = foxglove_support.Schema.from_advertised(channels[TOPICS['scene']])
    matched, drawn = 0, []
    for message in scenes:
        entities = {e['id']: e for e in
                    schema.decode('foxglove.SceneUpdate', message.payload)['entities']}
        stamp = message.log_time_ns
        if stamp not in estimates or stamp not in truths:
            continue
        matched += 1
        drawn_estimate = entities['estimate']['lines'][1]['points'][0]['x']  # the rod's joint
        assert abs(drawn_estimate - estimates[stamp][0]) <= 1e-3
        drawn_plant = entities['plant']['cubes'][0]['pose']['position']['x']
        assert abs(drawn_plant - truths[stamp][0]) <= 1e-3
        drawn.append(drawn_estimate)
    assert matched >= 0.9 * SCENES, f'only {matched} of {SCENES} stamps seen on DDS'
    assert np.ptp(drawn) > 0.05  # the cart moved: the match is not of a cart at rest
