"""``cartpole bag repair BAG`` and ``cartpole bag info BAG``: bags after a kill, and what is in one.

``repair`` is the equivalent of ``ros2 bag reindex`` for the MCAP bags of
``cartpole run --record`` and the recorder node
(:mod:`cartpole_analysis.bags.repair`); ``info`` prints what ``ros2 bag info``
prints (for installs without the ros2 CLI). No ROS needed.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..boundary import InputError
from ..options import print_json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    verbs = parser.add_subparsers(dest='verb', metavar='VERB', required=True)
    repair = verbs.add_parser(
        'repair', help='make a bag whose recording was killed readable again',
        description='Recover the messages of a truncated MCAP file (a recorder or run killed '
                    'with SIGKILL) into a complete one and rebuild metadata.yaml; the damaged '
                    'file is kept as <file>.damaged. An intact bag is left alone.')
    repair.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='bag directories')
    repair.add_argument('--json', action='store_true', help='one JSON object a bag')
    repair.set_defaults(_prog=repair.prog)
    info = verbs.add_parser('info', help='topics, types, counts and time span of a bag',
                            description='What ros2 bag info prints: topics, types, counts, '
                                        'time span and custom_data of a bag.')
    info.add_argument('bags', nargs='+', type=Path, metavar='BAG', help='bag directories')
    info.add_argument('--json', action='store_true', help='one JSON object a bag')
    info.set_defaults(_prog=info.prog)


def _existing(bags: list[Path]) -> None:
    """Refuse (exit 2) a BAG that is not there at all, before any bag is touched."""
    for bag in bags:
        if not bag.exists():
            raise InputError(f'{bag}: no such bag directory')
        if bag.is_file() and bag.name != 'metadata.yaml' and bag.suffix != '.mcap':
            raise InputError(f'{bag}: is a file, a bag directory is needed')


def _repair(args: argparse.Namespace) -> int:
    from cartpole_analysis.bags.repair import RepairError, repair_bag

    _existing(args.bags)
    code = 0
    for bag in args.bags:
        try:
            result = repair_bag(bag)
        except (RepairError, OSError, ValueError) as error:
            text = str(error) if str(bag) in str(error) else f'{bag}: {error}'
            print(f'cartpole bag repair: {text}', file=sys.stderr)
            code = 1  # the bag could not be repaired: a failed operation, not a refused input
            continue
        if args.json:
            print_json({'bag': str(result.bag), 'action': result.action,
                              'messages': result.message_count, 'counts': result.counts,
                              'start_ns': result.start_ns, 'end_ns': result.end_ns,
                              'dropped_bytes': result.dropped_bytes,
                              'damaged_copy': (str(result.damaged_copy)
                                               if result.damaged_copy else None),
                              'metadata_problem': result.metadata_problem})
        else:
            print(result.describe())
    return code


def bag_info(bag: Path) -> dict:
    """The facts of ``metadata.yaml``, checked against the bag's files; ValueError with the
    one line "BAG: damaged: ..., run `cartpole bag repair BAG`" if they disagree."""
    from cartpole_analysis.bags.check import damage, damaged_line, read_metadata

    bag = bag.parent if bag.is_file() else bag
    problem = damage(bag)
    if problem:
        raise ValueError(damaged_line(bag, problem))
    info, _ = read_metadata(bag)
    return {
        'bag': str(bag), 'files': info['relative_file_paths'],
        'storage': info.get('storage_identifier'), 'version': info.get('version'),
        'start_ns': info['starting_time']['nanoseconds_since_epoch'],
        'duration_s': info['duration']['nanoseconds'] * 1e-9,
        'messages': info['message_count'],
        'topics': {t['topic_metadata']['name']: {'type': t['topic_metadata']['type'],
                                                 'count': t['message_count']}
                   for t in info['topics_with_message_count']},
        'custom_data': info.get('custom_data') if isinstance(info.get('custom_data'), dict)
        else {},
        'needs_repair': False,
    }


def _info(args: argparse.Namespace) -> int:
    _existing(args.bags)
    code = 0
    for bag in args.bags:
        try:
            facts = bag_info(bag)
        except (OSError, ValueError) as error:
            text = str(error) if str(bag) in str(error) else f'{bag}: {error}'
            print(f'cartpole bag info: {text}', file=sys.stderr)
            code = 1
            continue
        if args.json:
            print_json(facts)
            continue
        print(f'bag:       {facts["bag"]} ({facts["storage"]}, version {facts["version"]}, '
              f'files {", ".join(facts["files"])})')
        print(f'duration:  {facts["duration_s"]:.3f} s from {facts["start_ns"] * 1e-9:.3f} s')
        print(f'messages:  {facts["messages"]}')
        width = max((len(t) for t in facts['topics']), default=0)
        for topic, t in facts['topics'].items():
            print(f'  {topic:<{width}}  {t["count"]:>7}  {t["type"]}')
        for key, value in facts['custom_data'].items():
            print(f'custom_data {key}: {value}')
    return code


def main(args: argparse.Namespace) -> int:
    return _repair(args) if args.verb == 'repair' else _info(args)
