"""Where a graph runs: its ROS namespace, in the nodes' names and in its bags (no ROS).

Every node names its topics and services relative to its namespace, so ``--ros-args -r
__ns:=/rig2`` moves a node whole and ``cartpole run --namespace rig2`` a graph
(``/rig2/joint_states``, ``/rig2/sim/reset``); the root namespace keeps the usual names.
This module holds the name arithmetic every layer needs for that:

- :func:`ros_arguments`: a graph's remappings, ``/clock`` included (the one absolute name
  every ``use_sim_time`` node reads; two lockstep graphs must not share it);
- :func:`bag_namespace`, :func:`graph_topic`: a bag records the names the graph used and
  its namespace in ``custom_data`` (:data:`NAMESPACE_KEY`); the analysis reads it by the
  root names;
- :func:`parameters_in_namespace`: a parameters file's sections moved into the namespace.

Design notes: (docs/running.md, "Namespaces, one graph per namespace").
"""
from __future__ import annotations

import re
from typing import Any, Iterable, Mapping

ROOT = '/'
NAMESPACE_KEY = 'namespace'
"""custom_data key of a bag recorded in a namespace (absent in the root namespace)."""
CLOCK = '/clock'
_TOKEN = re.compile(r'[A-Za-z_][A-Za-z0-9_]*\Z')
_MARKERS = ('/joint_states', '/cartpole/force_command', '/cartpole/state')
"""Topics that tell a bag's namespace when its custom_data does not."""


def normalize(text: str | None) -> str:
    """``rig2``, ``/rig2``, ``/lab/rig2/`` -> ``/rig2``, ``/lab/rig2``; '' or None -> ``/``.

    ValueError naming the bad part: each token a letter or ``_`` then letters,
    digits and ``_`` (a ROS namespace; no ``~`` or substitutions).
    """
    text = (text or '').strip()
    tokens = [t for t in text.strip('/').split('/')] if text.strip('/') else []
    for token in tokens:
        if not _TOKEN.match(token):
            raise ValueError(f'namespace {text!r}: {token!r} is not a ROS name token (a letter '
                             f'or _, then letters, digits and _)')
    return ROOT + '/'.join(tokens)


def ros_arguments(namespace: str) -> list[str]:
    """The ROS arguments that put a node into ``namespace`` (none in the root): the
    namespace and the graph's own ``/clock``."""
    if namespace == ROOT:
        return []
    return ['-r', f'__ns:={namespace}', '-r', f'{CLOCK}:={namespace}{CLOCK}']


def relative(topic: str) -> str:
    """A graph topic as a node names it: relative (``cartpole/state``), ``/clock`` as it is."""
    return topic if topic == CLOCK else topic.lstrip('/')


def in_namespace(topic: str, namespace: str) -> str:
    """The absolute name of a root-namespace graph topic in ``namespace`` (``/clock`` too)."""
    return topic if namespace == ROOT else namespace + topic


def graph_topic(topic: str, namespace: str) -> str:
    """A recorded topic by its root-namespace name: ``/rig2/joint_states`` -> ``/joint_states``."""
    if namespace != ROOT and topic.startswith(namespace + '/'):
        return topic[len(namespace):]
    return topic


def bag_namespace(custom_data: Mapping[str, str], topics: Iterable[str]) -> str:
    """The namespace a bag was recorded in: its custom_data's, else the one in front of the
    graph's topics (a bag recorded with ``ros2 bag record``), else the root."""
    if custom_data.get(NAMESPACE_KEY):
        try:
            return normalize(custom_data[NAMESPACE_KEY])
        except ValueError:
            pass
    topics = list(topics)
    for marker in _MARKERS:
        if marker in topics:
            return ROOT
        for topic in topics:
            if topic.endswith(marker):
                try:
                    return normalize(topic[:-len(marker)])
                except ValueError:
                    continue
    return ROOT


def parameters_in_namespace(data: Mapping[str, Any], namespace: str,
                            nodes: Iterable[str]) -> dict[str, Any]:
    """A parameters file's mapping with the sections of ``nodes`` (``name`` or ``/name``)
    renamed ``<namespace>/name``; every other section (``/**``, other nodes) as it is."""
    nodes = set(nodes)
    out: dict[str, Any] = {}
    for key, section in data.items():
        name = str(key).lstrip('/')
        out[in_namespace('/' + name, namespace) if name in nodes else key] = section
    return out
