"""The feed of `cartpole run --view`: what the tap in the graph sends the viewer process.

Messages are serialized by rosbags (the CDR the graph's raw subscriptions hand over),
sent through a real Unix socket, and read back.
"""
import math

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from cartpole_analysis.bags.writer import cdr_stamp_ns
from cartpole_analysis.viewer.server import MAX_RATE_HZ
from cartpole_analysis.viewer.feed import (ESTIMATE, STATUS, TRUTH, FeedReceiver, FeedSender,
                                          FeedTap, status_has_event)

TS = get_typestore(Stores.ROS2_JAZZY)


def _stamp(ns):
    return TS.types['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9)


def joint_state(ns, x, little_endian=True):
    msg = TS.types['sensor_msgs/msg/JointState'](
        header=TS.types['std_msgs/msg/Header'](stamp=_stamp(ns), frame_id=''),
        name=['cart', 'pendulum'], position=np.array([x, math.pi]),
        velocity=np.array([0.0, 0.0]), effort=np.array([], dtype=float))
    return TS.serialize_cdr(msg, 'sensor_msgs/msg/JointState', little_endian=little_endian)


def status(ns, event='', little_endian=True):
    kv = TS.types['diagnostic_msgs/msg/KeyValue']
    values = {'mode': 'swingup', 'energy': '0.1', 'event': event, 'state_stamp': '1.0'}
    st = TS.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name='controller_manager', message='swingup', hardware_id='cartpole',
        values=[kv(key=k, value=v) for k, v in values.items()])
    msg = TS.types['diagnostic_msgs/msg/DiagnosticArray'](
        header=TS.types['std_msgs/msg/Header'](stamp=_stamp(ns), frame_id=''), status=[st])
    return TS.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray',
                            little_endian=little_endian)


@pytest.mark.parametrize('little_endian', [True, False])
def test_status_events_are_seen_without_decoding(little_endian):
    assert status_has_event(status(0, 'catch', little_endian))
    assert status_has_event(status(0, 'fault:stale state', little_endian))
    assert not status_has_event(status(0, '', little_endian))
    assert not status_has_event(joint_state(0, 0.1, little_endian))


def test_tap_sends_what_the_viewer_draws_and_every_event(tmp_path):
    path = str(tmp_path / 'feed.sock')
    receiver = FeedReceiver(path)
    tap = FeedTap(FeedSender(path))
    period = 5_000_000
    for k in range(400):  # 2 s at 200 Hz, in the graph's order: truth, estimate, status
        ns = 10**18 + k * period
        tap.plant(TRUTH, joint_state(ns, 0.001 * k))
        tap.estimate(joint_state(ns, 0.001 * k + 1e-4))
        tap.status(status(ns, 'catch' if k == 201 else ''))
    received = []
    while (message := receiver.receive(0.5)) is not None:
        received.append((message[0], cdr_stamp_ns(message[1])))
    receiver.close()
    estimates = [s for kind, s in received if kind == ESTIMATE]
    assert len(estimates) == 100  # every fourth sample: 50 Hz
    assert np.diff(estimates).min() >= 1e9 / MAX_RATE_HZ
    # Each shown sample: its truth, its estimate, its status, in that order.
    for stamp in estimates:
        kinds = [kind for kind, s in received if s == stamp]
        assert kinds == [TRUTH, ESTIMATE, STATUS]
    statuses = {s for kind, s in received if kind == STATUS}
    catch = 10**18 + 201 * period
    assert catch not in estimates and statuses == set(estimates) | {catch}
    assert len(received) == 3 * 100 + 1
    assert tap.sender.dropped == 0


def test_no_viewer_listening_drops_and_never_raises(tmp_path):
    clock = [0.0]
    path = str(tmp_path / 'late.sock')
    sender = FeedSender(path, clock=lambda: clock[0])
    sender.send(ESTIMATE, joint_state(0, 0.0))
    assert sender.dropped == 1 and sender.sent == 0
    receiver = FeedReceiver(path)          # the viewer comes up late
    sender.send(ESTIMATE, joint_state(1, 0.0))
    assert sender.dropped == 2             # not tried again within a second
    clock[0] = 1.5
    sender.send(ESTIMATE, joint_state(2, 0.0))
    assert sender.sent == 1
    assert cdr_stamp_ns(receiver.receive(1.0)[1]) == 2
    receiver.close()                       # ... and goes away again
    for k in range(3):
        sender.send(ESTIMATE, joint_state(3 + k, 0.0))
    assert sender.sent == 1 and sender.dropped == 5
    sender.close()
