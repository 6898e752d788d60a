"""The storage of a rosbag2 bag: MCAP files that survive a kill, and ``metadata.yaml``.

The layout ROS 2 Jazzy's ``rosbag2_storage_mcap`` writes (``ros2 bag info|play``, Foxglove
and ``rosbags`` read it): ``<bag>/<bag name>_<i>.mcap`` (:func:`file_name`; i counts the
files of a split bag), MCAP profile ``ros2``, one ``ros2msg`` schema a type, one ``cdr``
channel a topic (with ``offered_qos_profiles`` and ``topic_type_hash``), a ``rosbag2``
metadata record, summary and index at the end; and ``<bag>/metadata.yaml``
(``rosbag2_bagfile_information`` version 9, every file listed: :func:`bagfile_information`).

Surviving a kill: messages go into MCAP chunks, and a chunk is flushed to the operating
system once it is :data:`FLUSH_PERIOD` old in wall time or spans that much log time, so a
SIGKILL loses at most that much. The run description (``custom_data``) is a metadata record
at the start of the file. A kill loses the summary and ``metadata.yaml``;
:mod:`cartpole_analysis.bags.repair` (``cartpole bag repair BAG``) rebuilds both.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Mapping

import yaml

BAG_FORMAT_VERSION = 9
"""rosbag2 metadata version written by ROS 2 Jazzy."""
FLUSH_PERIOD = 0.5
"""A chunk is written to the file once it is this old [wall s] or spans this much log time [s]."""
CUSTOM_DATA_RECORD = 'custom_data'
"""Name of the MCAP metadata record with the bag's custom_data (written at the start)."""
ROSBAG2_RECORD = 'rosbag2'
"""Name of the MCAP metadata record with the serialized bag metadata (written at the end)."""
NO_QOS = '[]'
"""``offered_qos_profiles`` of a channel whose publishers' QoS is not known (players use defaults)."""


@dataclass
class TopicInfo:
    """One topic of a bag: its type, hash, QoS text and message count."""

    name: str
    msgtype: str
    type_hash: str = ''
    offered_qos_profiles: str = NO_QOS
    count: int = 0


@dataclass
class BagStats:
    """Message counts and the time span of a bag [ns of log time]."""

    topics: dict[str, TopicInfo] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None

    def add(self, topic: str, log_time_ns: int) -> None:
        self.topics[topic].count += 1
        self.start_ns = log_time_ns if self.start_ns is None else min(self.start_ns, log_time_ns)
        self.end_ns = log_time_ns if self.end_ns is None else max(self.end_ns, log_time_ns)

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())


def file_name(bag_name: str, index: int) -> str:
    """The name of a bag's ``index``-th file, as rosbag2 names it: ``<bag name>_<index>.mcap``."""
    return f'{bag_name}_{index}.mcap'


def merged_stats(parts: Iterable[BagStats]) -> BagStats:
    """The counts and time span of several files together (the topics in order of appearance)."""
    total = BagStats()
    for part in parts:
        for name, topic in part.topics.items():
            if name not in total.topics:
                total.topics[name] = TopicInfo(topic.name, topic.msgtype, topic.type_hash,
                                               topic.offered_qos_profiles)
            total.topics[name].count += topic.count
        for ns in (part.start_ns, part.end_ns):
            if ns is not None:
                total.start_ns = ns if total.start_ns is None else min(total.start_ns, ns)
                total.end_ns = ns if total.end_ns is None else max(total.end_ns, ns)
    return total


def _span(stats: BagStats) -> tuple[int, int]:
    start = stats.start_ns or 0
    return start, max(0, (stats.end_ns or 0) - start)


def bagfile_information(files: Mapping[str, BagStats],
                        custom_data: Mapping[str, str] | None) -> dict:
    """The ``rosbag2_bagfile_information`` mapping of ``metadata.yaml`` (version 9) of a bag
    made of ``files`` (file name -> its counts, in order)."""
    stats = merged_stats(files.values())
    start, duration = _span(stats)
    count = stats.message_count
    return {
        'version': BAG_FORMAT_VERSION,
        'storage_identifier': 'mcap',
        'relative_file_paths': list(files),
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype, 'serialization_format': 'cdr',
                                'offered_qos_profiles': yaml.safe_load(t.offered_qos_profiles) or [],
                                'type_description_hash': t.type_hash},
             'message_count': t.count}
            for t in stats.topics.values()],
        'compression_format': '',
        'compression_mode': '',
        'files': [{'path': name, 'starting_time': {'nanoseconds_since_epoch': _span(part)[0]},
                   'duration': {'nanoseconds': _span(part)[1]},
                   'message_count': part.message_count}
                  for name, part in files.items()],
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': 'jazzy',
    }


def write_metadata(directory: str | Path, info: dict) -> Path:
    """Write ``metadata.yaml`` atomically (a temporary file, then a rename)."""
    path = Path(directory) / 'metadata.yaml'
    tmp = path.with_suffix('.yaml.tmp')
    tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info},
                                  default_flow_style=False, sort_keys=False))
    os.replace(tmp, path)
    return path


class McapBagFile:
    """The MCAP file of a rosbag2 bag, written so that a kill loses at most :data:`FLUSH_PERIOD`.

    Parameters
    ----------
    path
        The ``.mcap`` file to create (it must not exist).
    custom_data
        Written at once as the metadata record ``custom_data``.
    flush_period
        See :data:`FLUSH_PERIOD`; 0 writes every message at once.
    clock
        Wall clock [s] of the flush rule (a parameter for tests).
    """

    def __init__(self, path: str | Path, custom_data: Mapping[str, str] | None = None,
                 flush_period: float = FLUSH_PERIOD,
                 clock: Callable[[], float] = time.monotonic) -> None:
        from importlib.metadata import version

        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        self._stream = self.path.open('xb')
        self.size = 0
        """Bytes handed to the operating system so far (at each chunk's flush)."""
        self._writer = Writer(self._stream, compression=CompressionType.NONE)
        self._writer.start(profile='ros2', library=f'cartpole_bringup (mcap {version("mcap")})')
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        if self.custom_data:
            self._writer.add_metadata(CUSTOM_DATA_RECORD, self.custom_data)
        self._stream.flush()
        self.stats = BagStats()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._flush_period = float(flush_period)
        self._clock = clock
        self._chunk_since: float | None = None
        """Wall time of the first message of the open chunk (None: no open chunk)."""
        self._chunk_first_log = 0
        self.closed = False

    def add_topic(self, topic: TopicInfo, schema: bytes, schema_encoding: str = 'ros2msg') -> None:
        """Register a topic (and its type's schema, once a type)."""
        if topic.name in self._channels:
            raise ValueError(f'topic {topic.name} is registered already')
        schema_id = self._schemas.get(topic.msgtype)
        if schema_id is None:
            schema_id = self._writer.register_schema(topic.msgtype, schema_encoding, schema)
            self._schemas[topic.msgtype] = schema_id
        metadata = {'offered_qos_profiles': topic.offered_qos_profiles}
        if topic.type_hash:
            metadata['topic_type_hash'] = topic.type_hash
        self._channels[topic.name] = self._writer.register_channel(
            topic.name, 'cdr', schema_id, metadata)
        self._sequence[topic.name] = 0
        self.stats.topics[topic.name] = TopicInfo(topic.name, topic.msgtype, topic.type_hash,
                                                  topic.offered_qos_profiles)

    def has_topic(self, topic: str) -> bool:
        return topic in self._channels

    def write(self, topic: str, log_time_ns: int, data: bytes, publish_time_ns: int) -> None:
        """Add one message of a registered topic; finishes the chunk when it is due."""
        self._sequence[topic] += 1
        self._writer.add_message(self._channels[topic], int(log_time_ns), data,
                                 int(publish_time_ns), self._sequence[topic])
        self.stats.add(topic, int(log_time_ns))
        if self._chunk_since is None:
            self._chunk_since = self._clock()
            self._chunk_first_log = int(log_time_ns)
        self.flush_if_due(log_time_ns)

    def flush_if_due(self, log_time_ns: int | None = None) -> bool:
        """Finish the open chunk if it is :data:`FLUSH_PERIOD` old (wall or log time)."""
        if self._chunk_since is None or self.closed:
            return False
        old = self._clock() - self._chunk_since >= self._flush_period
        long = (log_time_ns is not None
                and (log_time_ns - self._chunk_first_log) * 1e-9 >= self._flush_period)
        if old or long:
            self.flush()
            return True
        return False

    def flush(self) -> None:
        """Finish the open chunk and hand everything to the operating system."""
        if not self.closed:
            self._writer.flush()
            self._chunk_since = None
            self.size = self._stream.tell()

    def set_custom_data(self, custom_data: Mapping[str, str] | None) -> None:
        """Write the ``custom_data`` record now (a file created without one)."""
        if custom_data and not self.custom_data and not self.closed:
            self.custom_data = {str(k): str(v) for k, v in custom_data.items()}
            self._writer.add_metadata(CUSTOM_DATA_RECORD, self.custom_data)

    def abort(self) -> None:
        """Close the file without summary and footer (it is then what a kill leaves)."""
        if not self.closed:
            self.closed = True
            self._stream.close()

    def close(self, info: dict) -> None:
        """Write the ``rosbag2`` metadata record, the summary and the footer; close the file."""
        if self.closed:
            return
        self._writer.flush()
        self._writer.add_metadata(ROSBAG2_RECORD, {
            'serialized_metadata': yaml.safe_dump(info, default_flow_style=False,
                                                  sort_keys=False)})
        self._writer.finish()
        self._stream.close()
        self.closed = True
