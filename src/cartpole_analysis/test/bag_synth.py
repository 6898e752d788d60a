"""Synthetic runs written as bags without ROS (rosbags serialisation), for the tests."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cartpole_analysis.bags.writer import BagWriter

TS = 0.01
X_REF = 0.3845
CATCH_TIME = 5.0
DURATION = 20.0


def _types():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _stamp(ts, t):
    ns = int(round(t * 1e9))
    return ts.types['builtin_interfaces/msg/Time'](sec=ns // 1_000_000_000,
                                                   nanosec=ns % 1_000_000_000)


def joint_state(ts, t, position, velocity=(), effort=(), names=('cart', 'pendulum')):
    js = ts.types['sensor_msgs/msg/JointState']
    header = ts.types['std_msgs/msg/Header'](stamp=_stamp(ts, t), frame_id='')
    msg = js(header=header, name=list(names), position=np.array(position, dtype=float),
             velocity=np.array(velocity, dtype=float), effort=np.array(effort, dtype=float))
    return ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState')


def diagnostic(ts, t, name, values, message=''):
    kv = ts.types['diagnostic_msgs/msg/KeyValue']
    status = ts.types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=b'\x00'[0], name=name, message=message, hardware_id='',
        values=[kv(key=k, value=v) for k, v in values.items()])
    header = ts.types['std_msgs/msg/Header'](stamp=_stamp(ts, t), frame_id='')
    msg = ts.types['diagnostic_msgs/msg/DiagnosticArray'](header=header, status=[status])
    return ts.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray')


def read_log_times(bag: Path) -> dict[str, list[int]]:
    """Log times [ns] of every message per topic, as ``rosbags`` reads the bag back."""
    from rosbags.highlevel import AnyReader
    out: dict[str, list[int]] = {}
    with AnyReader([bag]) as reader:
        for connection, log_time, _ in reader.messages():
            out.setdefault(connection.topic, []).append(log_time)
    return out


def trajectory(duration=DURATION, x_offset=0.0):
    """Known run: theta falls linearly from pi to 0 over 6 s, then 0.01 sin(2 pi t);
    x = x* + 0.05 sin(2 pi t / 5) + x_offset. Times from 0 (lockstep)."""
    t = np.arange(int(round(duration / TS)) + 1) * TS
    theta = np.where(t < 6.0, math.pi * (1.0 - t / 6.0), 0.01 * np.sin(2 * math.pi * t))
    theta_dot = np.gradient(theta, TS)
    x = X_REF + 0.05 * np.sin(2 * math.pi * t / 5.0) + x_offset
    x_dot = np.gradient(x, TS)
    force = 2.0 * np.sin(t)
    return t, x, theta, x_dot, theta_dot, force


def write_run(path: Path, *, truth=True, estimate=True, hw_limits=None, x_offset=0.0,
              t_origin=0.0, clock=True, custom_data=None, switch=None, events=None,
              cycle_gap=None, swingup_laws=None, max_bag_duration=None):
    """Write the known trajectory as a bag; returns the arrays.

    ``switch=(t, name)``: the stabiliser is ``name`` from ``t`` on (a ``ros2 param
    set``); ``events={t: 'fault:...'}``: extra status events; ``cycle_gap(t)``: the
    status key ``longest_cycle_gap_s``; ``swingup_laws``: (before the catch, from the
    catch on) values of the status's ``swingup_law``; None leaves the key out (a bag
    from before it existed); ``max_bag_duration``: split the bag (None: the writer's
    default).
    """
    ts = _types()
    t, x, theta, x_dot, theta_dot, force = trajectory(x_offset=x_offset)
    split = {} if max_bag_duration is None else {'max_bag_duration': max_bag_duration}
    with BagWriter(path, custom_data=custom_data, **split) as bag:
        for k in range(t.size):
            tk = t[k] + t_origin
            state = ([x[k], theta[k]], [x_dot[k], theta_dot[k]])
            if clock:
                clock_cls = ts.types['rosgraph_msgs/msg/Clock']
                bag.write('/clock', ts.serialize_cdr(clock_cls(clock=_stamp(ts, tk)),
                                                     'rosgraph_msgs/msg/Clock'), 0)
            bag.write('/joint_states', joint_state(ts, tk, state[0]), 0)
            if truth:
                bag.write('/cartpole/true_state',
                          joint_state(ts, tk, *state, effort=[force[k], 0.0]), 0)
            if estimate:
                bag.write('/cartpole/state', joint_state(ts, tk, *state), 0)
            bag.write('/cartpole/force_command',
                      joint_state(ts, tk, [], [], [force[k]], names=('cart',)), 0)
            mode = 'stabilising' if t[k] >= CATCH_TIME else 'swing-up'
            stabilizer = switch[1] if switch and t[k] >= switch[0] - TS / 2 else 'lqg'
            event = 'catch' if abs(t[k] - CATCH_TIME) < TS / 2 else ''
            for when, text in (events or {}).items():
                if abs(t[k] - when) < TS / 2:
                    event = ';'.join(e for e in (event, text) if e)
            values = {'mode': mode, 'swingup': 'pendulum_energy', 'stabilizer': stabilizer,
                      'event': event, 'state_stamp': repr(float(tk))}
            if cycle_gap is not None:
                values['longest_cycle_gap_s'] = repr(float(cycle_gap(t[k])))
            if swingup_laws is not None:
                values['swingup_law'] = swingup_laws[int(t[k] >= CATCH_TIME + TS / 2)]
            bag.write('/cartpole/controller_status',
                      diagnostic(ts, tk, 'controller_manager', values, mode), 0)
            if hw_limits is not None and k % 20 == 0:
                # The left switch is closed at the start (cart at the left stop), then opens.
                left = 'true' if k < 40 else 'false'
                right = 'true' if hw_limits and k > t.size // 2 else 'false'
                bag.write('/cartpole/hw/health',
                          diagnostic(ts, tk, 'hw_bridge', {'limit_left': left,
                                                           'limit_right': right,
                                                           'limit_inhibits': '3'}), 0)
    return t, x, theta
