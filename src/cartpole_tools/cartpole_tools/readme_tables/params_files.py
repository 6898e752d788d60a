"""Each node's default parameters as a ``--params-file``: ``src/<package>/config/<node>.yaml``.

Generated from the same node descriptions as the README's parameter tables
(:mod:`.introspect`: the declared parameters, their defaults, descriptors and
descriptions), installed to ``share/<package>/config/`` by each ``setup.py``,
and kept current by ``python -m cartpole_tools.readme_tables --write``
(``--check`` names a stale file). A user copies one, changes what they need and
starts the node with it::

    ros2 run cartpole_estimation ekf_node --ros-args --params-file ekf.yaml

The node key is ``/**/<node>``: it applies to the node in any namespace
(``-r __ns:=/rig2``), and only to it. Values are written so that rcl's YAML
parser gives each parameter its declared type: doubles always with a decimal
point or exponent (``1.0``, ``1.0e-05``, ``.nan``, ``.inf``), strings always
quoted.
"""
from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path
from typing import Any, Iterable

from .introspect import NodeInfo, ParameterInfo
from .render import range_text

HEADER = """\
# Default parameters of the `{node}` node (package {package}), generated from its
# declarations by `python -m cartpole_tools.readme_tables --write`; installed as
# share/{package}/config/{node}.yaml. Copy it, change what you need and start the node with it:
#   ros2 run {package} {executable} --ros-args --params-file {node}.yaml
# A read-only parameter takes its value at start (here); `ros2 param set` refuses it later.
"""


def yaml_value(value: Any, type_name: str) -> str:
    """``value`` as a YAML scalar or flow sequence that rcl reads back as ``type_name``."""
    if type_name.endswith('_array'):
        item = type_name[:-len('_array')]
        return '[' + ', '.join(yaml_value(v, item) for v in value) + ']'
    if type_name == 'bool':
        return 'true' if value else 'false'
    if type_name == 'integer':
        return str(int(value))
    if type_name == 'double':
        value = float(value)
        if math.isnan(value):
            return '.nan'
        if math.isinf(value):
            return '.inf' if value > 0 else '-.inf'
        text = repr(value)
        if 'e' in text and '.' not in text.split('e')[0]:
            mantissa, exponent = text.split('e')
            text = f'{mantissa}.0e{exponent}'
        return text
    if type_name == 'string':
        return json.dumps(str(value))
    raise ValueError(f'parameter type {type_name!r} has no YAML form here')


def _comment(p: ParameterInfo) -> list[str]:
    text = p.description
    limits = range_text(p)
    if limits:
        text += f' ({limits})'
    return textwrap.wrap(text, width=94, initial_indent='    # ', subsequent_indent='    #   ',
                         break_long_words=False, break_on_hyphens=False)


def render(info: NodeInfo) -> str:
    """The parameter file of one node: a header, then each parameter with its description."""
    lines = [HEADER.format(node=info.node, package=info.package, executable=info.executable),
             f'/**/{info.node}:', '  ros__parameters:']
    for p in info.parameters:
        lines += _comment(p)
        lines.append(f'    {p.name}: {yaml_value(p.default, p.type_name)}')
    return '\n'.join(lines) + '\n'


def config_path(src: Path, info: NodeInfo) -> Path:
    """Where the file of ``info``'s node lives in the source tree ``src``."""
    return src / info.package / 'config' / f'{info.node}.yaml'


def expected(nodes: Iterable[NodeInfo], src: Path) -> dict[Path, str]:
    """Path -> content of every node's parameter file."""
    return {config_path(src, info): render(info) for info in nodes}


def stale(files: dict[Path, str]) -> list[str]:
    """One line for each file that is missing or differs from what the code declares."""
    out = []
    for path, text in files.items():
        if not path.is_file():
            out.append(f'{path}: missing')
        elif path.read_text(encoding='utf-8') != text:
            out.append(f'{path}: differs from the declarations of its node')
    return out


def write(files: dict[Path, str]) -> list[Path]:
    """Write the files that differ; the paths written."""
    written = []
    for path, text in files.items():
        if not path.is_file() or path.read_text(encoding='utf-8') != text:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding='utf-8')
            written.append(path)
    return written
