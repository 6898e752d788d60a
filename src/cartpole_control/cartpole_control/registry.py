"""Controller plugins found through Python entry points (no pluginlib).

Groups: ``cartpole_control.swingup`` and ``cartpole_control.stabilizer``. A
third party adds a controller by installing a package that declares, in its
setup.py, e.g.::

    entry_points={'cartpole_control.stabilizer': ['mine = my_pkg.mine:MyStabilizer']}

As in ros2cli's ``entry_points.py``, a plugin that fails to import or has the
wrong API version is logged and skipped, never fatal.
"""
from __future__ import annotations

import logging
from importlib.metadata import entry_points

from .controller import API_VERSION, KINDS, Controller

GROUP_PREFIX = 'cartpole_control.'

logger = logging.getLogger(__name__)


def group_name(kind: str) -> str:
    if kind not in KINDS:
        raise ValueError(f'unknown controller kind {kind!r}; kinds are {list(KINDS)}')
    return GROUP_PREFIX + kind


def load_controllers(kind: str) -> dict[str, type[Controller]]:
    """All loadable plugins of ``kind`` by name, sorted by name."""
    found: dict[str, type[Controller]] = {}
    for ep in entry_points(group=group_name(kind)):
        if ep.name in found:
            continue
        try:
            cls = ep.load()
        except Exception as exc:  # a broken third-party plugin must not stop the manager
            logger.warning('skipping controller plugin %s (%s): %s', ep.name, ep.value, exc)
            continue
        if not (isinstance(cls, type) and issubclass(cls, Controller)):
            logger.warning('skipping %s: %s is not a Controller subclass', ep.name, ep.value)
            continue
        if cls.api_version != API_VERSION:
            logger.warning('skipping %s: written for controller API %s, this is %s',
                           ep.name, cls.api_version, API_VERSION)
            continue
        if cls.kind != kind:
            logger.warning('skipping %s: declared kind %r in group %r', ep.name, cls.kind, kind)
            continue
        found[ep.name] = cls
    return dict(sorted(found.items()))


def create(kind: str, name: str,
           available: dict[str, type[Controller]] | None = None) -> Controller:
    """Instantiate the plugin ``name``; an unknown name is refused with the list of known ones."""
    available = load_controllers(kind) if available is None else available
    try:
        return available[name]()
    except KeyError:
        raise ValueError(f'unknown {kind} controller {name!r}; available: {sorted(available)}') from None
