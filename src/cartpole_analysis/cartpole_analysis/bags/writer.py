"""Writing rosbag2 bags (MCAP storage) from serialized messages, without ROS.

The ROS-free half of the recorder (:mod:`cartpole_bringup.graph.recorder`): the table
of the graph's topics (docs/architecture.md), the log-time rule and a writer on top of
:class:`cartpole_analysis.bags.storage.McapBagFile` (an MCAP file that survives a kill).
Messages arrive serialized (ROS 2 CDR, from a ``raw=True`` subscription) and are written
as they are.

Log time (``log_time``): ``'stamp'`` (default) takes the message's own stamp (the first
eight bytes of the CDR payload of JointState, DiagnosticArray and Clock), so a lockstep
run is recorded in simulated time; ``'receive'`` takes the receive time the caller gives.

Splitting (as ``ros2 bag record --max-bag-duration/--max-bag-size``): a new file
``<bag>_<i>.mcap`` begins once the open one spans ``max_bag_duration`` s of log time or
holds ``max_bag_size`` bytes, and ``metadata.yaml`` is rewritten to list every file. A
closed file's index leaves memory, so the recorder's memory stays bounded
(:data:`MAX_BAG_DURATION`; docs/running.md, "Recording").
"""
from __future__ import annotations

import struct
from pathlib import Path
from typing import Mapping

import yaml

from .storage import (BAG_FORMAT_VERSION, FLUSH_PERIOD, BagStats, McapBagFile,  # noqa: F401
                      TopicInfo, bagfile_information, file_name, write_metadata)

TOPICS: dict[str, str] = {
    '/joint_states': 'sensor_msgs/msg/JointState',
    '/cartpole/state': 'sensor_msgs/msg/JointState',
    '/cartpole/force_command': 'sensor_msgs/msg/JointState',
    '/cartpole/force_acting': 'sensor_msgs/msg/JointState',
    '/cartpole/true_state': 'sensor_msgs/msg/JointState',
    '/cartpole/controller_status': 'diagnostic_msgs/msg/DiagnosticArray',
    '/cartpole/ekf/health': 'diagnostic_msgs/msg/DiagnosticArray',
    '/cartpole/hw/health': 'diagnostic_msgs/msg/DiagnosticArray',
    '/clock': 'rosgraph_msgs/msg/Clock',
}
"""Every topic of docs/architecture.md and its type: what the recorder records."""

MAX_BAG_DURATION = 300.0
"""Default log time [s] a bag file spans before the next one is begun. The MCAP writer
keeps one index entry a chunk (a chunk every :data:`FLUSH_PERIOD`) until the file is
closed, about 0.9 kB each: 0.5 MB for a 5-minute file, 6.6 MB an hour unsplit."""

LOG_TIMES = ('stamp', 'receive')
"""Choices of the log time of a recorded message."""

_STAMP_LE = struct.Struct('<iI')
_STAMP_BE = struct.Struct('>iI')


def cdr_stamp_ns(data: bytes | memoryview) -> int:
    """The stamp [ns] at the start of a CDR message (0 if the payload is too short).

    Every recorded type begins with a ``builtin_interfaces/Time`` (``header.stamp``
    or ``clock``): int32 sec, uint32 nanosec after the 4-byte encapsulation
    header, whose second byte tells the byte order (1 little, 0 big endian).
    """
    if len(data) < 12:
        return 0
    layout = _STAMP_LE if data[1] & 1 else _STAMP_BE
    sec, nanosec = layout.unpack_from(data, 4)
    return max(0, sec * 1_000_000_000 + nanosec)


class BagWriter:
    """A rosbag2 bag (MCAP storage, metadata version 9) being written.

    Connections are added on a topic's first message in a file, so the bag lists
    the topics that carried data. Use as a context manager, or call
    :meth:`close`; closing twice is harmless, and :meth:`close` writes the
    MCAP summary and ``metadata.yaml`` (without it ``ros2 bag info`` cannot
    read the bag). Until then each file is written in chunks of at most
    ``flush_period`` (:mod:`cartpole_analysis.bags.storage`), so a killed
    recorder loses at most that much and ``cartpole bag repair`` recovers
    the rest.

    Parameters
    ----------
    path
        The bag directory to create; it must not exist.
    topics
        Topic name -> message type (``pkg/msg/Type``) of the topics that may
        be written.
    custom_data
        Strings stored in the bag's ``custom_data`` (run description: x*,
        controllers, scenario); written at the start of every file.
    log_time
        ``'stamp'`` (the message's stamp) or ``'receive'`` (the receive time).
    flush_period
        Longest time [s] a message waits in memory before it is in the file.
    max_bag_duration
        Log time [s] a file spans before the next is begun (0: never split by time).
    max_bag_size
        Bytes a file holds before the next is begun (0: never split by size).
    """

    def __init__(self, path: str | Path, topics: Mapping[str, str] = TOPICS,
                 custom_data: Mapping[str, str] | None = None, log_time: str = 'stamp',
                 flush_period: float = FLUSH_PERIOD, max_bag_duration: float = MAX_BAG_DURATION,
                 max_bag_size: int = 0) -> None:
        from rosbags.typesys import Stores, get_typestore

        if log_time not in LOG_TIMES:
            raise ValueError(f'log_time must be one of {LOG_TIMES}, got {log_time!r}')
        if not (max_bag_duration >= 0.0 and max_bag_size >= 0):  # NaN fails too
            raise ValueError(f'max_bag_duration and max_bag_size must be >= 0 (0: no split), '
                             f'got {max_bag_duration} and {max_bag_size}')
        self._use_stamp = log_time == 'stamp'
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f'bag {self.path} already exists; choose a new directory')
        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        unknown = [t for t in topics.values() if t not in self._typestore.types]
        if unknown:
            raise ValueError(f'unknown message types {unknown}')
        self._topics = dict(topics)
        self._schemas: dict[str, tuple[TopicInfo, bytes]] = {}
        self._custom_data = dict(custom_data) if custom_data else None
        self._flush_period = flush_period
        self._max_duration_ns = int(max_bag_duration * 1e9)
        self._max_size = int(max_bag_size)
        self.files: dict[str, BagStats] = {}
        """File name -> its counts, every file begun so far (the open one last)."""
        self.path.mkdir(parents=True)
        self._file = self._begin_file()
        self.counts: dict[str, int] = {}
        """Messages written per topic."""
        self.closed = False

    def _begin_file(self) -> McapBagFile:
        name = file_name(self.path.name, len(self.files))
        new = McapBagFile(self.path / name, self._custom_data, flush_period=self._flush_period)
        self.files[name] = new.stats
        return new

    def _split_due(self, log_time_ns: int) -> bool:
        stats = self._file.stats
        if stats.start_ns is None:
            return False  # an empty file is never closed for a new one
        if self._max_duration_ns and log_time_ns - stats.start_ns >= self._max_duration_ns:
            return True
        return bool(self._max_size) and self._file.size >= self._max_size

    def split(self) -> None:
        """Close the open file (summary, index released) and begin the next; rewrite
        ``metadata.yaml`` to list every file (the new one empty until it gets a message)."""
        self._file.close(self._information())
        self._file = self._begin_file()
        write_metadata(self.path, self._information())

    def _information(self) -> dict:
        return bagfile_information(self.files, self._custom_data)

    def _add_topic(self, topic: str) -> None:
        if topic not in self._topics:
            raise KeyError(f'topic {topic!r} is not recorded')
        if topic not in self._schemas:
            msgtype = self._topics[topic]
            msgdef, _ = self._typestore.generate_msgdef(msgtype, ros_version=2)
            self._schemas[topic] = (TopicInfo(topic, msgtype,
                                              self._typestore.hash_rihs01(msgtype)),
                                    msgdef.encode())
        self._file.add_topic(*self._schemas[topic])

    def write(self, topic: str, data: bytes | memoryview, receive_time_ns: int) -> int:
        """Write one serialized message; returns the log time used [ns]."""
        if self.closed:
            raise RuntimeError(f'bag {self.path} is closed')
        stamp = cdr_stamp_ns(data) if self._use_stamp else int(receive_time_ns)
        if self._split_due(stamp):
            self.split()
        if not self._file.has_topic(topic):
            self._add_topic(topic)
        self._file.write(topic, stamp, bytes(data), int(receive_time_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1
        return stamp

    def flush_if_due(self) -> bool:
        """Write the open chunk if it is ``flush_period`` old (call when idle)."""
        return self._file.flush_if_due()

    def close(self) -> None:
        """Finish the open MCAP file and write ``metadata.yaml``."""
        if not self.closed:
            self.closed = True
            info = self._information()
            self._file.close(info)
            write_metadata(self.path, info)

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bag_custom_data(path: str | Path) -> dict[str, str]:
    """The ``custom_data`` of a bag's ``metadata.yaml`` ({} if none)."""
    meta = Path(path) / 'metadata.yaml'
    if not meta.is_file():
        return {}
    info = (yaml.safe_load(meta.read_text()) or {}).get('rosbag2_bagfile_information', {})
    return {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}


def update_custom_data(path: str | Path, values: Mapping[str, str | None]) -> dict[str, str]:
    """Add (or, with None, remove) entries of a closed bag's ``custom_data``; returns the new one.

    ``cartpole run`` stores there what is known only at the end of a run
    (why it stopped, when), so that ``cartpole analyze`` of the bag reports
    what the run reported. Raises FileNotFoundError without ``metadata.yaml``.
    """
    meta = Path(path) / 'metadata.yaml'
    doc = yaml.safe_load(meta.read_text()) or {}
    info = doc.setdefault('rosbag2_bagfile_information', {})
    custom = {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    for key, value in values.items():
        if value is None:
            custom.pop(key, None)
        else:
            custom[str(key)] = str(value)
    info['custom_data'] = custom or None
    write_metadata(path, info)
    return custom
