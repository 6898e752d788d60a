"""Recordings from rosbag2 bags written by the recorder (via ``rosbags``; no ROS)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from .recording import IdentificationError, Recording

JOINTS = '/joint_states'
FORCE = '/cartpole/force_command'



def _stamp_ns(stamp_ns: int, log_ns: int) -> int:
    return stamp_ns if stamp_ns > 0 else int(log_ns)


def sample_indices(t: np.ndarray, sample_time: float, window: int = 20) -> np.ndarray:
    """Sample numbers of samples taken every ``sample_time`` but stamped late and irregularly.

    A stamp is the true sample time plus a latency >= 0 (receipt on the host:
    serial buffering delivers lines in bursts). Counting the samples gives
    their numbers, except where samples were lost. With e_k = (t_k - t_0) / Ts
    - k, a loss raises e permanently by one, latency only for a while; the
    minimum of e over the next ``window`` samples is the latency-free part,
    and its rise since the start, rounded and never decreasing, is the number
    of samples lost so far (a loss within the last ``window`` samples goes
    unnoticed rather than a late burst at the end being taken for one).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    k = np.arange(n)
    if n < 2:
        return k
    e = (t - t[0]) / sample_time - k
    w = max(1, min(int(window), n))
    # The last window's minimum closes the series: a burst at the very end is not a loss.
    padded = np.concatenate([e, np.full(w - 1, e[-w:].min())])
    floor = np.lib.stride_tricks.sliding_window_view(padded, w).min(axis=1)
    lost = np.maximum.accumulate(np.maximum(np.round(floor - floor[0]), 0.0)).astype(np.int64)
    return k + lost


def recording_from_messages(samples: Sequence[tuple[int, float, float]],
                            commands: Sequence[tuple[int, float]], *,
                            sample_time: float = 0.005, command_timeout: float = 0.05,
                            zero_force: bool = False, label: str = '') -> Recording:
    """A :class:`Recording` from /joint_states samples and force commands.

    ``samples`` are (time [ns], x, theta), ``commands`` (time [ns], F). The
    sample times become k Ts (:func:`sample_indices`: the device samples
    every Ts exactly, the host's receipt stamps jitter and come in bursts;
    lost samples leave gaps). ``force[k]`` is the last command
    stamped at or before sample k (a command carries the stamp of the sample
    it answers, docs/architecture.md), zero before the first command and
    once the last command is older than ``command_timeout`` (the watchdogs
    of the bridge and the device then set zero current, docs/rig.md, "The Joint protocol").
    """
    name = label or 'recording'
    if not samples:
        raise IdentificationError(f'{name}: no {JOINTS} samples with cart and pendulum positions')
    if not commands and not zero_force:
        raise IdentificationError(
            f'{name}: no {FORCE} messages; an open-loop test needs its force commands '
            '(for a free swing with nothing commanding, pass --zero-force)')
    rows = np.array(sorted(set(samples)), dtype=float)  # a re-published sample counts once
    t_ns = rows[:, 0]
    grid = sample_indices(t_ns * 1e-9, sample_time)
    keep = np.concatenate([[True], np.diff(grid) > 0])
    grid, rows, t_ns = grid[keep], rows[keep], t_ns[keep]
    t = grid * sample_time
    force = np.zeros(t.size)
    if commands:
        cmd = np.array(sorted(commands), dtype=float)
        if cmd.shape[0] > 1 and cmd[0, 0] == cmd[-1, 0]:
            raise IdentificationError(
                f'{name}: all {cmd.shape[0]} {FORCE} messages carry the same time, so they '
                'cannot be placed in time (published with a zero header.stamp and recorded '
                "with log_time 'stamp'?); stamp the commands or record with log_time 'receive'")
        # A command at or before a sample's (unsnapped) time, within half a period of jitter,
        # and not older than the watchdog's hold time.
        late = t_ns + 0.5 * sample_time * 1e9
        idx = np.searchsorted(cmd[:, 0], late, side='right') - 1
        fresh = (idx >= 0) & (late - cmd[np.maximum(idx, 0), 0] <= command_timeout * 1e9)
        force = np.where(fresh, cmd[np.maximum(idx, 0), 1], 0.0)
    return Recording(t, rows[:, 1], rows[:, 2], force, label)


def load_recording(path: str | Path, *, t_start: float | None = None,
                   t_end: float | None = None, sample_time: float = 0.005,
                   command_timeout: float = 0.05, zero_force: bool = False) -> Recording:
    """Read a test from a rosbag2 bag (MCAP or sqlite3) written by the recorder.

    Uses ``/joint_states`` (names ``cart``, ``pendulum``, positions x and
    theta, ``header.stamp``) and ``/cartpole/force_command`` (``effort`` of
    ``cart``, ``header.stamp``); a zero stamp falls back to the bag's log
    time. ``t_start``/``t_end`` [s from the first sample] cut a window out.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from cartpole_analysis.analysis.analyze import parse_joint_state, root_topics
    from cartpole_analysis.bags.writer import bag_custom_data

    path = Path(path)
    label = path.name if path.name != 'bag' else path.parent.name
    if not path.exists():
        raise IdentificationError(f'{path}: no such bag')
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise IdentificationError(f'{path} is not a rosbag2 bag (no metadata.yaml)')
    samples: list[tuple[int, float, float]] = []
    commands: list[tuple[int, float]] = []
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            root = root_topics(reader, bag_custom_data(path))  # a bag of a namespace too
            connections = [c for c in reader.connections if root[c.topic] in (JOINTS, FORCE)
                           and c.msgtype == 'sensor_msgs/msg/JointState']
            messages = reader.messages(connections=connections) if connections else ()
            for connection, log_ns, raw in messages:  # (an empty list would mean all topics)
                stamp, names, position, _, effort = parse_joint_state(raw)
                when = _stamp_ns(stamp, log_ns)
                if root[connection.topic] == JOINTS:
                    try:
                        i_x, i_t = names.index('cart'), names.index('pendulum')
                    except ValueError:
                        i_x, i_t = 0, 1
                    if position.size > max(i_x, i_t):
                        samples.append((when, float(position[i_x]), float(position[i_t])))
                else:
                    i_f = names.index('cart') if 'cart' in names else 0
                    if effort.size > i_f and math.isfinite(effort[i_f]):
                        commands.append((when, float(effort[i_f])))
    except IdentificationError:
        raise
    except Exception as error:  # rosbags raises its own types for broken bags
        raise IdentificationError(f'{path}: cannot read the bag: {error}') from None
    rec = recording_from_messages(samples, commands, sample_time=sample_time,
                                  command_timeout=command_timeout, zero_force=zero_force,
                                  label=label)
    if t_start is not None or t_end is not None:
        rec = rec.window(t_start, t_end)
    return rec
