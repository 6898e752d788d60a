"""Markdown tables from :mod:`.introspect`'s node descriptions and the plugin registry."""
from __future__ import annotations

import importlib
import math
from typing import Any, Iterable

from .introspect import Endpoint, NodeInfo, ParameterInfo
from .notes import ENDPOINT_NOTES, MENTIONED_KEYS, TOPIC_NOTES

DIRECTION = {'publishes': 'out', 'subscribes': 'in', 'service': 'service'}


class MissingNote(KeyError):
    """An endpoint the code has and :mod:`.notes` does not describe (or describes short)."""


def cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell (pipes escaped, one line)."""
    return ' '.join(str(text).split()).replace('|', '\\|')


def number(value: float) -> str:
    """A compact, exact enough number: 0.05, 1e-05, 3.14159, 115200, 1e+06."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int):
        return str(value)
    if math.isinf(value) or abs(value) >= 1e300:
        return '-inf' if value < 0 else 'inf'
    text = format(value, '.6g')
    return text if any(c in text for c in '.en') else text + '.0'


def value_text(value: Any) -> str:
    """A parameter default as a YAML-ish literal in backticks."""
    if isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, (int, float)):
        text = number(value)
    elif isinstance(value, str):
        text = value if value else "''"
    elif isinstance(value, (list, tuple)):
        text = '[' + ', '.join(value_text(v).strip('`') if not isinstance(v, str) else repr(v)
                               for v in value) + ']'
    else:
        text = repr(value)
    return f'`{text}`'


def range_text(p: ParameterInfo) -> str:
    """The descriptor's range and additional constraints, and whether it is read-only."""
    parts = []
    if p.low is not None:
        parts.append(f'[{number(p.low)}, {number(p.high)}]')
        if p.step not in (None, 0, 0.0, 1) or (p.type_name != 'integer' and p.step):
            parts[-1] += f' step {number(p.step)}'
    if p.additional_constraints:
        parts.append(p.additional_constraints)
    if p.read_only:
        parts.append('read-only')
    return '; '.join(parts)


def parameter_table(parameters: Iterable[ParameterInfo], strip_prefix: str = '') -> str:
    """| parameter | type | default | range | description | for ``parameters``."""
    rows = ['| parameter | type | default | range | description |', '|---|---|---|---|---|']
    for p in parameters:
        name = p.name[len(strip_prefix):] if strip_prefix and p.name.startswith(strip_prefix) \
            else p.name
        rows.append(f'| `{name}` | {p.type_name} | {cell(value_text(p.default))} | '
                    f'{cell(range_text(p))} | {cell(p.description)} |')
    return '\n'.join(rows)


def _note(node: str, endpoint: Endpoint) -> str:
    try:
        note = ENDPOINT_NOTES.get((node, endpoint.name)) or ENDPOINT_NOTES[(node, '*')]
    except KeyError:
        raise MissingNote(f'{node} {endpoint.kind} {endpoint.name}: no entry in '
                          'cartpole_bringup/readme_tables/notes.py ENDPOINT_NOTES') from None
    if (node, endpoint.name) in MENTIONED_KEYS:
        module, attribute = MENTIONED_KEYS[(node, endpoint.name)]
        keys = getattr(importlib.import_module(module), attribute)
        unnamed = [k for k in keys if f'`{k}`' not in note]
        if unnamed:
            raise MissingNote(f'{node} {endpoint.name}: the note in cartpole_bringup/readme_tables/'
                              f'notes.py does not name {unnamed} of {module}.{attribute}')
    return f'{endpoint.condition} only: {note}' if endpoint.condition else note


def endpoint_table(info: NodeInfo) -> str:
    """| name | type | direction | content | of one node's topics and services."""
    rows = ['| name | type | direction | content |', '|---|---|---|---|']
    for e in info.endpoints:
        rows.append(f'| `{e.name}` | {e.type_name} | {DIRECTION[e.kind]} | '
                    f'{cell(_note(info.node, e))} |')
    return '\n'.join(rows)


def topic_table(nodes: dict[str, NodeInfo], recorded: Iterable[str]) -> str:
    """| topic | type | from | to | recorded | content | over the whole graph."""
    recorded = set(recorded)
    topics: dict[str, dict[str, Any]] = {}
    for info in nodes.values():
        for e in info.endpoints:
            if e.kind == 'service':
                continue
            t = topics.setdefault(e.name, {'type': e.type_name, 'from': [], 'to': []})
            who = info.node + (f' ({e.condition})' if e.condition else '')
            t['from' if e.kind == 'publishes' else 'to'].append(who)
    rows = ['| topic | type | from | to | recorded | content |', '|---|---|---|---|---|---|']
    for name in sorted(topics, key=lambda n: (n != '/joint_states', n)):
        t = topics[name]
        if name not in TOPIC_NOTES:
            raise MissingNote(f'topic {name}: no entry in cartpole_bringup/readme_tables/notes.py '
                              'TOPIC_NOTES')
        rows.append(f"| `{name}` | {t['type']} | {', '.join(t['from']) or '(none)'} | "
                    f"{', '.join(t['to']) or '(none)'} | {'yes' if name in recorded else 'no'} | "
                    f'{cell(TOPIC_NOTES[name])} |')
    return '\n'.join(rows)


def service_table(nodes: dict[str, NodeInfo]) -> str:
    """| service | type | node | what | of every node."""
    rows = ['| service | type | node | what |', '|---|---|---|---|']
    for info in nodes.values():
        for e in info.endpoints:
            if e.kind == 'service':
                rows.append(f'| `{e.name}` | {e.type_name} | {info.node} | '
                            f'{cell(_note(info.node, e))} |')
    return '\n'.join(rows)


def plugin_table(plugins: dict[str, dict[str, type]]) -> str:
    """| kind | plugin | class | law | of every registered controller plugin."""
    rows = ['| entry-point group | plugin | class | law |', '|---|---|---|---|']
    for kind, found in plugins.items():
        for name, cls in found.items():
            doc = (cls.__doc__ or '').strip().splitlines()
            rows.append(f'| `cartpole_control.{kind}` | `{name}` | '
                        f'`{cls.__module__}.{cls.__name__}` | {cell(doc[0] if doc else "")} |')
    return '\n'.join(rows)


def names_list(names: Iterable[str]) -> str:
    """`a`, `b`, `c` (for a sentence)."""
    return ', '.join(f'`{n}`' for n in names)
