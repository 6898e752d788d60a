"""Is a bag whole? Its files checked against its ``metadata.yaml``, without ROS.

:func:`damage` is the one check behind ``cartpole bag info`` (exit 1 with
"damaged: ..., run `cartpole bag repair BAG`"), ``cartpole analyze`` and
``cartpole identify`` (which refuse such a bag with the same line) and
``cartpole bag repair`` (which rewrites metadata that does not match the file).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .framing import MAGIC, RepairError, complete_prefix

SQLITE_MAGIC = b'SQLite format 3\x00'


def damaged_line(bag: Path, what: str) -> str:
    """The one line that says a bag is damaged and what to do."""
    return f'{bag}: damaged: {what}, run `cartpole bag repair {bag}`'


def read_metadata(bag: Path) -> tuple[dict | None, str | None]:
    """(``rosbag2_bagfile_information``, None) or (None, what is wrong with metadata.yaml)."""
    import yaml

    meta = bag / 'metadata.yaml'
    if not meta.is_file():
        return None, 'no metadata.yaml (a recording cut short?)'
    try:
        data = yaml.safe_load(meta.read_text())
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as error:
        return None, f'metadata.yaml is not readable YAML ({type(error).__name__})'
    info = data.get('rosbag2_bagfile_information') if isinstance(data, dict) else None
    if not isinstance(info, dict):
        return None, 'metadata.yaml holds no rosbag2_bagfile_information'
    files = info.get('relative_file_paths')
    topics = info.get('topics_with_message_count')
    if not (isinstance(files, list) and files and all(isinstance(f, str) for f in files)):
        return None, 'metadata.yaml names no bag file (relative_file_paths)'
    if not isinstance(topics, list) or not all(_topic_entry(t) for t in topics):
        return None, 'metadata.yaml has no valid topics_with_message_count'
    if not _count(info.get('message_count')):
        return None, 'metadata.yaml has no valid message_count'
    for key, inner in (('starting_time', 'nanoseconds_since_epoch'), ('duration', 'nanoseconds')):
        if not (isinstance(info.get(key), dict) and _count(info[key].get(inner))):
            return None, f'metadata.yaml has no valid {key}'
    return info, None


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _topic_entry(entry: Any) -> bool:
    return (isinstance(entry, dict) and _count(entry.get('message_count'))
            and isinstance(entry.get('topic_metadata'), dict)
            and isinstance(entry['topic_metadata'].get('name'), str)
            and isinstance(entry['topic_metadata'].get('type'), str))


def damage(bag: str | Path) -> str | None:
    """What is wrong with a bag directory (a phrase), None if its files agree with its metadata.

    Checked: ``metadata.yaml`` is rosbag2 metadata; every file it names exists
    and is of its storage; an MCAP file ends with its footer (not cut short by
    a kill) and its summary's message counts, total and per topic, are those
    of the metadata.
    """
    bag = Path(bag)
    info, problem = read_metadata(bag)
    if problem:
        return problem
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    storage = info.get('storage_identifier', 'mcap')
    seen: dict[str, int] = {}
    for name in info['relative_file_paths']:
        path = bag / name
        if not path.is_file():
            return f'its file {name} is missing'
        if path.stat().st_size == 0:
            return f'its file {name} is empty'
        with path.open('rb') as f:
            head = f.read(len(SQLITE_MAGIC))
        if storage == 'sqlite3':
            if not head.startswith(SQLITE_MAGIC):
                return f'its file {name} is not an SQLite database'
            return None  # sqlite3 bags (ros2 bag record): no deeper check here
        if not head.startswith(MAGIC):
            return f'its file {name} is not an MCAP file'
        problem = _mcap_counts(path, seen)
        if problem:
            return f'its file {name} {problem}'
    total = sum(seen.values())
    if total != info['message_count']:
        return f'its files hold {total} messages, metadata.yaml says {info["message_count"]}'
    for topic, n in counts.items():
        if seen.get(topic, 0) != n:
            return (f'{topic} has {seen.get(topic, 0)} messages in the file, metadata.yaml '
                    f'says {n}')
    extra = sorted(t for t in seen if t not in counts and seen[t])
    if extra:
        return f'metadata.yaml lacks the topic(s) {", ".join(extra)} of the file'
    return None


def _mcap_counts(path: Path, seen: dict[str, int]) -> str | None:
    """Add the MCAP file's messages per topic (from its summary) to ``seen``; a problem or None."""
    try:
        _, complete = complete_prefix(path)
    except (RepairError, OSError) as error:
        return f'cannot be read ({error})'
    if not complete:
        return 'is truncated (no footer: the recording was cut short)'
    try:
        from mcap.reader import make_reader
        with path.open('rb') as f:
            summary = make_reader(f).get_summary()
    except Exception as error:  # mcap raises its own types for a broken summary
        return f'has an unreadable summary ({type(error).__name__})'
    if summary is None or summary.statistics is None:
        return 'has no summary statistics'
    for channel_id, n in summary.statistics.channel_message_counts.items():
        channel = summary.channels.get(channel_id)
        if channel is None:
            return f'counts messages of an unknown channel {channel_id}'
        seen[channel.topic] = seen.get(channel.topic, 0) + n
    return None
