"""The reference of the ``cartpole`` command, from its argparse tree (region ``cli``).

Every subcommand (and sub-subcommand: ``bench control``, ``bag repair``) with its usage line and
a table of its options, so the page says what ``cartpole SUB --help`` says and a new option is
in the reference without an edit.
"""
from __future__ import annotations

import argparse
import re

from .render import cell


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, help, parser) of each subcommand of ``parser``, in their order."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            return [(name, helps.get(name) or '', sub) for name, sub in action.choices.items()]
    return []


def _option_rows(parser: argparse.ArgumentParser) -> list[str]:
    rows = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if action.help == argparse.SUPPRESS:
            continue
        if action.option_strings:
            name = ', '.join(action.option_strings)
            if action.nargs != 0:
                metavar = action.metavar or action.dest.upper()
                name += f' {metavar if isinstance(metavar, str) else " ".join(metavar)}'
        else:
            name = action.metavar or action.dest
        shown = action.default not in (None, False, '', [], argparse.SUPPRESS)
        default = f'`{action.default}`' if shown else ''
        rows.append(f'| {cell(f"`{name}`")} | {cell(default)} | {cell(action.help or "")} |')
    return rows


def _section(prog: str, help_text: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    usage = ' '.join(parser.format_usage().split())[len('usage: '):]
    wrapped = ['']
    for token in re.split(r' (?=[\[(])', usage):  # break between options, never inside one
        if wrapped[-1] and len(wrapped[-1]) + 1 + len(token) > 96:
            wrapped.append('    ')
        wrapped[-1] += (' ' if wrapped[-1].strip() else '') + token
    lines = [f'{"#" * level} `{prog}`', '', help_text, '', '```text', *wrapped, '```', '']
    rows = _option_rows(parser)
    if rows:
        lines += ['| option | default | meaning |', '|---|---|---|', *rows, '']
    for name, sub_help, sub in _subparsers(parser):
        lines += _section(f'{prog} {name}', sub_help, sub, level + 1)
    return lines


def cli_reference(parser: argparse.ArgumentParser) -> str:
    """Markdown of every subcommand of ``parser`` (the ``cartpole`` parser), a section each."""
    lines = []
    for name, help_text, sub in _subparsers(parser):
        lines += _section(f'{parser.prog} {name}', help_text, sub, 3)
    return '\n'.join(lines).rstrip('\n')
