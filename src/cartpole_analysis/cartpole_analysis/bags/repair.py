"""Recovering a bag whose recorder was killed (``cartpole bag repair BAG``), without ROS.

The equivalent of ``ros2 bag reindex`` for the MCAP files of
:mod:`cartpole_analysis.bags.storage`. A SIGKILL leaves a file without summary and footer and
no ``metadata.yaml``, which ``rosbags``, ``cartpole analyze`` and ``ros2 bag info`` refuse; the
file still holds every chunk written before the kill (at most
:data:`~cartpole_analysis.bags.storage.FLUSH_PERIOD` lost) and perhaps part of one record.

:func:`repair_bag`, for each file (those ``metadata.yaml`` lists, else every ``*.mcap`` in
index order): walks the records by their length fields up to the last complete one (a cut
record is dropped and counted); leaves a complete file (footer present) as it is, else copies
its records in order into a new MCAP file with summary and index and keeps the original as
``<file>.damaged``; then writes ``metadata.yaml`` (files, counts, time span, topics,
``custom_data``) unless an intact bag already has one.
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
                      TopicInfo, bagfile_information, merged_stats, write_metadata)

@dataclass
class RepairResult:
    """What :func:`repair_bag` found and did."""

    bag: Path
    file: Path
    """The bag's last file, or the last one recovered."""
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
    """Where the damaged original of :attr:`file` is kept (``recovered``)."""
    damaged_copies: list[Path] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    """Every file of the bag, in order."""
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
            kept = ', '.join(p.name for p in self.damaged_copies or [self.damaged_copy])
            out += (f'; {self.dropped_bytes} bytes of an unfinished record dropped; '
                    f'the damaged file is kept as {kept}')
        if len(self.files) > 1:
            out += f' ({len(self.files)} files)'
        return out


def _index(path: Path) -> tuple[int, str]:
    """Sort key of a bag's files: the index after the last ``_`` (rosbag2's ``<bag>_<i>``)."""
    stem, _, index = path.stem.rpartition('_')
    return (int(index), stem) if stem and index.isdigit() else (-1, path.stem)


def bag_files(bag: Path) -> list[Path]:
    """The MCAP files of a bag directory: those metadata.yaml lists if they all exist, else
    every ``*.mcap`` in the order of its index. RepairError if there is none."""
    meta = bag / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            files = [bag / p for p in info['relative_file_paths']]
        except (yaml.YAMLError, KeyError, TypeError, ValueError, OSError):
            files = []  # garbage metadata (UnicodeDecodeError is a ValueError): find the files
        if files and all(f.is_file() and f.suffix == '.mcap' for f in files):
            return files
    candidates = sorted(bag.glob('*.mcap'), key=_index)
    if not candidates:
        raise RepairError(f'{bag}: cannot repair: no .mcap file in it')
    return candidates


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
    paths = bag_files(bag)
    meta = bag / 'metadata.yaml'
    problem = damage(bag) if meta.is_file() else None
    if meta.is_file() and problem is None:
        stats = {p.name: _copy_or_refuse(p, complete_prefix(p)[0], None)[0] for p in paths}
        return _result(bag, paths, 'intact', stats)
    stats: dict[str, BagStats] = {}
    records: dict[str, dict[str, str]] = {}
    recovered: list[tuple[Path, Path, int]] = []
    for path in paths:
        limit, complete = complete_prefix(path)
        if complete:
            stats[path.name], metadata = _copy_or_refuse(path, limit, None)
        else:
            stats[path.name], metadata, damaged = _recover(path, limit, bag)
            recovered.append((path, damaged, damaged.stat().st_size - limit))
        for name, values in metadata.items():
            records.setdefault(name, values)
    custom = _custom_data_of(records, bag)
    info = bagfile_information(stats, custom)
    if problem is not None:  # metadata that does not describe the files: kept aside
        os.replace(meta, meta.with_name('metadata.yaml.damaged'))
    write_metadata(bag, info)
    result = _result(bag, paths, 'recovered' if recovered else 'metadata', stats)
    result.metadata_problem = problem
    if recovered:
        result.file, result.damaged_copy = recovered[-1][0], recovered[-1][1]
        result.damaged_copies = [d for _, d, _ in recovered]
        result.dropped_bytes = sum(n for _, _, n in recovered)
    return result


def _recover(path: Path, limit: int, bag: Path) -> tuple[BagStats, dict, Path]:
    """Copy the whole records of a truncated file into a complete one that replaces it;
    (its counts, its metadata records, where the damaged original is kept)."""
    tmp = path.with_name(path.name + '.repairing')
    tmp.unlink(missing_ok=True)
    out = McapBagFile(tmp, flush_period=float('inf'))
    try:
        stats, metadata = _copy_or_refuse(path, limit, out)
        custom = _custom_data_of(metadata, bag)
        out.set_custom_data(custom)
        out.close(bagfile_information({path.name: stats}, custom))
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
    return stats, metadata, damaged


def _result(bag: Path, paths: list[Path], action: str,
            stats: dict[str, BagStats]) -> RepairResult:
    total = merged_stats(stats.values())
    return RepairResult(bag=bag, file=paths[-1], action=action, files=list(paths),
                        counts={t.name: t.count for t in total.topics.values()},
                        start_ns=total.start_ns, end_ns=total.end_ns)


def needs_repair(bag: str | Path) -> bool:
    """True when the bag has no ``metadata.yaml`` or its MCAP file lacks the footer."""
    bag = Path(bag)
    if not (bag / 'metadata.yaml').is_file():
        return True
    try:
        return not all(complete_prefix(path)[1] for path in bag_files(bag))
    except (RepairError, OSError):
        return True
