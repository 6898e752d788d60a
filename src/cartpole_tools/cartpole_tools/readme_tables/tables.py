"""Every generated reference table by region key, from the nodes, the registry and the bag."""
from __future__ import annotations

from .introspect import NodeInfo, describe_nodes
from .render import (endpoint_table, names_list, parameter_table, plugin_table, service_table,
                     topic_table)

MANAGER = 'controller_manager'
NO_INTERFACE_TABLE = frozenset({'recorder'})
"""Nodes without an interface table: the recorder's subscriptions are the bag's topic list
(region ``recorded-topics``, and the ``recorded`` column of ``topics``)."""


def load_plugins() -> dict[str, dict[str, type]]:
    """The registered controller plugins, by kind (entry-point group) and name."""
    from cartpole_control.controller import KINDS
    from cartpole_control.registry import load_controllers
    return {kind: load_controllers(kind) for kind in KINDS}


def generate(nodes: dict[str, NodeInfo], plugins: dict[str, dict[str, type]],
             recorded: list[str]) -> dict[str, str]:
    """Region key -> Markdown for every node, every plugin and the graph's topics.

    Keys: ``parameters <node>``, ``interfaces <node>``, ``plugin-parameters`` (a section a
    plugin, so a plugin installed later has its table without a new region), ``plugins``,
    ``topics``, ``services``, ``recorded-topics``.
    """
    names = {name for found in plugins.values() for name in found}
    out = {}
    for node, info in nodes.items():
        own = [p for p in info.parameters
               if node != MANAGER or p.name.split('.', 1)[0] not in names]
        out[f'parameters {node}'] = parameter_table(own)
        if node not in NO_INTERFACE_TABLE:
            out[f'interfaces {node}'] = endpoint_table(info)
    manager = nodes[MANAGER]
    sections = []
    for kind, found in plugins.items():
        for name in sorted(found):
            specs = [p for p in manager.parameters if p.name.startswith(name + '.')]
            sections.append(f'### `{name}` ({kind})\n\n' + parameter_table(specs))
    out['plugin-parameters'] = '\n\n'.join(sections)
    out['plugins'] = plugin_table(plugins)
    out['topics'] = topic_table(nodes, recorded)
    out['services'] = service_table(nodes)
    out['recorded-topics'] = names_list(recorded)
    return out


def generate_all() -> dict[str, str]:
    """:func:`generate` for the installed nodes, plugins and the recorder's topics."""
    from cartpole_analysis.bags.writer import TOPICS
    return generate(describe_nodes(), load_plugins(), list(TOPICS))
