"""Controller plugins found through Python entry points (no pluginlib).

Groups: ``cartpole_control.swingup`` and ``cartpole_control.stabilizer``. A
third party adds a controller by installing a package that declares, in its
setup.py, e.g.::

    entry_points={'cartpole_control.stabilizer': ['mine = my_pkg.mine:MyStabilizer']}

As in ros2cli's ``entry_points.py``, a plugin that cannot be used is logged
(a warning naming the entry point and its distribution) and skipped, never
fatal: one that fails to import (a class that overrides the template methods
``activate``/``deactivate`` fails here too), is not a :class:`Controller`
subclass, was written for another API version, declares another kind than its
group, or whose entry-point name is not its class's ``name`` (the type string
the manager loads must be the name it reports). Two distributions that declare
the same name: the first found on ``sys.path`` is used, and the warning names
both.
"""
from __future__ import annotations

import logging
from importlib.metadata import EntryPoint, entry_points

from .controller import API_VERSION, KINDS, Controller

GROUP_PREFIX = 'cartpole_control.'

logger = logging.getLogger(__name__)


def group_name(kind: str) -> str:
    if kind not in KINDS:
        raise ValueError(f'unknown controller kind {kind!r}; kinds are {list(KINDS)}')
    return GROUP_PREFIX + kind


def distribution_of(ep: EntryPoint) -> str:
    """``<name> <version>`` of the distribution that declares ``ep`` (``unknown distribution`` if none)."""
    dist = getattr(ep, 'dist', None)
    if dist is None:
        return 'unknown distribution'
    return f'{dist.metadata["Name"] or dist.name} {dist.version}'


def _refusal(ep: EntryPoint, cls: object, kind: str) -> str:
    """Why the loaded object ``cls`` of ``ep`` cannot be a plugin of ``kind``; '' if it can."""
    if not (isinstance(cls, type) and issubclass(cls, Controller)):
        return f'{ep.value} is not a Controller subclass'
    if cls.api_version != API_VERSION:
        return f'written for controller API {cls.api_version}, this is {API_VERSION}'
    if cls.kind != kind:
        return f'declared kind {cls.kind!r} in group {group_name(kind)!r}'
    if cls.name != ep.name:
        return (f'entry point name {ep.name!r} is not the class\'s name {cls.name!r} '
                '(the type string must be the name the plugin reports)')
    return ''


def load_controllers(kind: str) -> dict[str, type[Controller]]:
    """All loadable plugins of ``kind`` by name, sorted by name."""
    found: dict[str, type[Controller]] = {}
    origin: dict[str, str] = {}
    for ep in entry_points(group=group_name(kind)):
        where = distribution_of(ep)
        if ep.name in found:
            logger.warning('skipping controller plugin %s (%s) from %s: the name is taken by '
                           '%s from %s, which is used', ep.name, ep.value, where,
                           found[ep.name].__qualname__, origin[ep.name])
            continue
        try:
            cls = ep.load()
        except Exception as exc:  # a broken third-party plugin must not stop the manager
            logger.warning('skipping controller plugin %s (%s) from %s: %s: %s', ep.name,
                           ep.value, where, type(exc).__name__, exc)
            continue
        reason = _refusal(ep, cls, kind)
        if reason:
            logger.warning('skipping controller plugin %s (%s) from %s: %s', ep.name, ep.value,
                           where, reason)
            continue
        found[ep.name] = cls
        origin[ep.name] = where
    return dict(sorted(found.items()))


def create(kind: str, name: str,
           available: dict[str, type[Controller]] | None = None) -> Controller:
    """Instantiate the plugin ``name``; an unknown name is refused with the list of known ones."""
    available = load_controllers(kind) if available is None else available
    try:
        return available[name]()
    except KeyError:
        raise ValueError(f'unknown {kind} controller {name!r}; available: {sorted(available)}') from None
