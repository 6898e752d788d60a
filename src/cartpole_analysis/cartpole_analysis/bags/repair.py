"""Recovering a bag whose recorder was killed (``cartpole bag repair BAG``), without ROS.

The equivalent of ``ros2 bag reindex``, for the MCAP files of
:mod:`cartpole_analysis.bags.storage`. A recorder killed with SIGKILL (or a run
whose process was) leaves an MCAP file without its summary and footer, and no
``metadata.yaml``: ``rosbags``, ``cartpole analyze`` and ``ros2 bag info``
refuse it. The file holds every chunk written before the kill (at most
:data:`~cartpole_analysis.bags.storage.FLUSH_PERIOD` is lost), and possibly the
beginning of one more record.

:func:`repair_bag`:

1. walks the file's records by their length fields up to the last complete
   one (a record cut short by the kill is dropped, and counted);
2. a complete file (footer present) is left as it is; otherwise its records
   (schemas, channels, messages, the ``custom_data`` record) are copied, in
   order, into a new MCAP file with summary and index, which replaces the
   original; the original is kept next to it as ``<file>.damaged``;
3. writes ``metadata.yaml`` (counts, time span, topics, ``custom_data`` from
   the old ``metadata.yaml`` or from the file) unless an intact bag already
   has one.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import yaml

from .check import damage
from .framing import RepairError, complete_prefix
from .storage import (CUSTOM_DATA_RECORD, NO_QOS, ROSBAG2_RECORD, BagStats, McapBagFile,
                          TopicInfo, bagfile_information, write_metadata)

@dataclass
class RepairResult:
    """What :func:`repair_bag` found and did."""

    bag: Path
    file: Path
    action: str
    """``intact`` (nothing to do), ``metadata`` (metadata.yaml rebuilt) or ``recovered``
    (a truncated file rewritten)."""
    counts: dict[str, int] = field(default_factory=dict)
    """Messages per topic in the repaired bag."""
    start_ns: int | None = None
    end_ns: int | None = None
    dropped_bytes: int = 0
    """Bytes at the end of the damaged file that held no complete record."""
    damaged_copy: Path | None = None
    metadata_problem: str | None = None
    """What was wrong with the ``metadata.yaml`` that was replaced (None: there was none)."""

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def describe(self) -> str:
        span = ('' if self.start_ns is None else
                f', {(self.end_ns - self.start_ns) * 1e-9:.3f} s of log time')
        text = {'intact': 'intact, nothing to repair',
                'metadata': 'metadata.yaml rebuilt' + (
                    f' (the old one, {self.metadata_problem}, kept as metadata.yaml.damaged)'
                    if self.metadata_problem else ''),
                'recovered': 'truncated MCAP recovered'}[self.action]
        out = f'{self.bag}: {text}: {self.message_count} messages{span}'
        if self.action == 'recovered':
            out += (f'; {self.dropped_bytes} bytes of an unfinished record dropped; '
                    f'the damaged file is kept as {self.damaged_copy.name}')
        return out


def _bag_file(bag: Path) -> Path:
    """The MCAP file of a bag directory (from metadata.yaml, else the one ``*.mcap``)."""
    meta = bag / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            files = [bag / p for p in info['relative_file_paths']]
        except (yaml.YAMLError, KeyError, TypeError, ValueError, OSError):
            files = []  # garbage metadata (UnicodeDecodeError is a ValueError): find the file
        if len(files) == 1 and files[0].is_file() and files[0].suffix == '.mcap':
            return files[0]
    candidates = sorted(bag.glob('*.mcap'))
    if len(candidates) != 1:
        raise RepairError(f'{bag}: cannot repair: expected one .mcap file, found '
                          f'{", ".join(p.name for p in candidates) or "none"}')
    return candidates[0]


class _Prefix:
    """A read-only file view that ends at ``limit`` (the complete records)."""

    def __init__(self, path: Path, limit: int) -> None:
        self._f = path.open('rb')
        self._left = limit

    def read(self, n: int = -1) -> bytes:
        n = self._left if n is None or n < 0 else min(n, self._left)
        data = self._f.read(n)
        self._left -= len(data)
        return data

    def close(self) -> None:
        self._f.close()


def _records(path: Path, limit: int) -> Iterator:
    """The records of the first ``limit`` bytes, chunks opened (mcap's stream reader)."""
    from mcap.exceptions import EndOfFile
    from mcap.stream_reader import StreamReader

    view = _Prefix(path, limit)
    try:
        yield from StreamReader(view, validate_crcs=True).records
    except EndOfFile:
        return
    finally:
        view.close()


def _custom_data_of(metadata_records: dict[str, dict[str, str]],
                    bag: Path) -> dict[str, str] | None:
    meta = bag / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            if info.get('custom_data'):
                return {str(k): str(v) for k, v in info['custom_data'].items()}
        except (yaml.YAMLError, KeyError, TypeError, AttributeError, ValueError, OSError):
            pass
    serialized = metadata_records.get(ROSBAG2_RECORD, {}).get('serialized_metadata')
    if serialized:
        try:
            custom = (yaml.safe_load(serialized) or {}).get('custom_data')
            if custom:
                return {str(k): str(v) for k, v in custom.items()}
        except (yaml.YAMLError, AttributeError):
            pass
    return metadata_records.get(CUSTOM_DATA_RECORD) or None


def _type_hash(msgtype: str, given: str) -> str:
    if given:
        return given
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    return store.hash_rihs01(msgtype) if msgtype in store.types else ''


def _copy(path: Path, limit: int, out: McapBagFile | None) -> tuple[BagStats, dict]:
    """Read the complete records; write them into ``out`` (None: count only)."""
    from mcap.records import Channel, Message, Metadata, Schema

    schemas: dict[int, Schema] = {}
    topics: dict[int, str] = {}
    stats = BagStats()
    metadata: dict[str, dict[str, str]] = {}
    for record in _records(path, limit):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel) and record.id not in topics:
            schema = schemas.get(record.schema_id)
            msgtype = schema.name if schema is not None else ''
            info = TopicInfo(record.topic, msgtype,
                             _type_hash(msgtype, record.metadata.get('topic_type_hash', '')),
                             record.metadata.get('offered_qos_profiles', NO_QOS))
            topics[record.id] = record.topic
            stats.topics[record.topic] = TopicInfo(info.name, info.msgtype, info.type_hash,
                                                   info.offered_qos_profiles)
            if out is not None:
                out.add_topic(info, schema.data if schema is not None else b'',
                              schema.encoding if schema is not None else '')
        elif isinstance(record, Message) and record.channel_id in topics:
            topic = topics[record.channel_id]
            stats.add(topic, record.log_time)
            if out is not None:
                out.write(topic, record.log_time, record.data, record.publish_time)
        elif isinstance(record, Metadata):
            metadata[record.name] = dict(record.metadata)
    return stats, metadata


def _copy_or_refuse(path: Path, limit: int, out: McapBagFile | None) -> tuple[BagStats, dict]:
    """:func:`_copy`; a record that cannot be parsed is a RepairError saying so."""
    try:
        return _copy(path, limit, out)
    except (RepairError, OSError):
        raise
    except Exception as error:  # mcap's own errors (bad CRC, a garbled record)
        raise RepairError(f'{path}: cannot repair: a record in it is garbled ({error}); the '
                          'records after it cannot be recovered by this tool') from None


def repair_bag(bag: str | Path) -> RepairResult:
    """Make a bag readable again; see the module docstring. Raises RepairError."""
    bag = Path(bag)
    if bag.is_file():
        bag = bag.parent
    if not bag.is_dir():
        raise RepairError(f'{bag}: no such bag directory')
    path = _bag_file(bag)
    limit, complete = complete_prefix(path)
    size = path.stat().st_size
    if complete:
        meta = bag / 'metadata.yaml'
        problem = damage(bag) if meta.is_file() else None
        if meta.is_file() and problem is None:
            return _result(bag, path, 'intact', *_copy_or_refuse(path, limit, None)[:1])
        stats, metadata = _copy_or_refuse(path, limit, None)
        info = bagfile_information(path.name, stats, _custom_data_of(metadata, bag))
        if problem is not None:  # metadata that does not describe the file: kept aside
            os.replace(meta, meta.with_name('metadata.yaml.damaged'))
        write_metadata(bag, info)
        result = _result(bag, path, 'metadata', stats)
        result.metadata_problem = problem
        return result
    tmp = path.with_name(path.name + '.repairing')
    tmp.unlink(missing_ok=True)
    out = McapBagFile(tmp, flush_period=float('inf'))
    try:
        stats, metadata = _copy_or_refuse(path, limit, out)
        custom = _custom_data_of(metadata, bag)
        out.set_custom_data(custom)
        info = bagfile_information(path.name, stats, custom)
        out.close(info)
    except BaseException:
        out.abort()
        tmp.unlink(missing_ok=True)
        raise
    damaged = path.with_name(path.name + '.damaged')
    n = 1
    while damaged.exists():
        n += 1
        damaged = path.with_name(f'{path.name}.damaged{n}')
    os.replace(path, damaged)
    os.replace(tmp, path)
    write_metadata(bag, info)
    result = _result(bag, path, 'recovered', stats)
    result.dropped_bytes = size - limit
    result.damaged_copy = damaged
    return result


def _result(bag: Path, path: Path, action: str, stats: BagStats) -> RepairResult:
    return RepairResult(bag=bag, file=path, action=action,
                        counts={t.name: t.count for t in stats.topics.values()},
                        start_ns=stats.start_ns, end_ns=stats.end_ns)


def needs_repair(bag: str | Path) -> bool:
    """True when the bag has no ``metadata.yaml`` or its MCAP file lacks the footer."""
    bag = Path(bag)
    if not (bag / 'metadata.yaml').is_file():
        return True
    try:
        return not complete_prefix(_bag_file(bag))[1]
    except (RepairError, OSError):
        return True
