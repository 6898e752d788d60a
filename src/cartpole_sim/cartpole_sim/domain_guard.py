"""One graph per ROS domain: a node refuses to start when its name is taken on the domain.

Two graphs on one ``ROS_DOMAIN_ID`` see each other's topics: one graph's
controller would drive the other's plant, one's shutdown would switch off
the other's controller. So every node executable
(:func:`cartpole_sim.node_runner.run_node` calls :func:`refuse_duplicate_node`)
and ``cartpole run`` (:func:`claim_node_names` for the whole graph) check
before they create a node, in two ways:

1. **On this machine, certain and at once:** an exclusive ``flock`` on
   ``<tmp>/cartpole-ros-domain-<N>/<namespace>_<name>.lock``, held for the
   life of the process (the kernel releases it when the process ends, also
   on SIGKILL). The file names the holder (PID and command line).
2. **On the DDS graph:** a hidden probe node (``_cartpole_probe_<pid>``)
   looks for the names among the nodes it discovers within
   :func:`discovery_wait` seconds (0.5 s with
   ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, where 1. already covers every
   cartpole node; 3.5 s otherwise, about one participant announcement
   period of Fast DDS, for graphs on other machines).

A refusal raises :class:`DuplicateNodeError` with a message naming the
domain, the holder and the fix (another ``ROS_DOMAIN_ID``). It is skipped
with ``cartpole run --allow-duplicates`` or, for an executable, the ROS
argument ``-p allow_duplicates:=true`` (or ``allow_duplicates: true`` under
``/**`` in a parameters file).
"""
from __future__ import annotations

import fcntl
import functools
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

NODE_OF_CLASS: dict[str, str] = {
    'cartpole_sim.sim_node.SimNode': 'sim',
    'cartpole_estimation.ekf_node.EkfNode': 'ekf',
    'cartpole_control.manager_node.ControllerManagerNode': 'controller_manager',
    'cartpole_hw.hw_node.HwBridgeNode': 'hw_bridge',
    'cartpole_bringup.graph.recorder.RecorderNode': 'recorder',
}
"""Node class (module.Class) -> the node name it creates (docs/architecture.md)."""
ALLOW_PARAMETER = 'allow_duplicates'
LOCAL_WAIT = 0.5
"""Discovery wait [s] with localhost-only discovery (the locks cover this machine)."""
NETWORK_WAIT = 3.5
"""Discovery wait [s] when other machines can be on the domain."""
POLL = 0.05


class DuplicateNodeError(ValueError):
    """A node of the same name is already on the domain (the message says where and what to do)."""


def domain_id() -> int:
    """The ROS domain of this process (``ROS_DOMAIN_ID``, default 0)."""
    try:
        return int(os.environ.get('ROS_DOMAIN_ID') or 0)
    except ValueError:
        return 0


def discovery_wait() -> float:
    """How long the DDS look waits for discovery [s] (see the module docstring)."""
    scope = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper()
    return LOCAL_WAIT if scope in ('LOCALHOST', 'OFF') else NETWORK_WAIT


def lock_directory(domain: int) -> Path:
    """The directory of the name locks of one domain (shared by all users of the machine)."""
    path = Path(tempfile.gettempdir()) / f'cartpole-ros-domain-{domain}'
    if not path.is_dir():
        path.mkdir(mode=0o1777, exist_ok=True)
        try:
            path.chmod(0o1777)
        except OSError:
            pass
    return path


def _lock_path(domain: int, namespace: str, name: str) -> Path:
    stem = (namespace.strip('/').replace('/', '_') + '_' if namespace.strip('/') else '') + name
    return lock_directory(domain) / f'{stem}.lock'


def _full_name(namespace: str, name: str) -> str:
    return namespace.rstrip('/') + '/' + name


@dataclass
class NodeClaim:
    """Names held on a domain by this process; :meth:`release` gives them back."""

    domain: int
    names: list[str] = field(default_factory=list)
    _fds: list[int] = field(default_factory=list, repr=False)

    def release(self) -> None:
        for fd in self._fds:
            try:
                os.close(fd)  # closing the descriptor releases its flock
            except OSError:
                pass
        self._fds.clear()
        self.names.clear()


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 4096, 0).decode('utf-8', 'replace').strip()
    except OSError:
        return ''
    return text


def _in_use(domain: int) -> bool:
    """Whether a cartpole node on this machine holds a name lock of ``domain``."""
    directory = Path(tempfile.gettempdir()) / f'cartpole-ros-domain-{domain}'
    for path in directory.glob('*.lock') if directory.is_dir() else ():
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        finally:
            os.close(fd)
    return False


def free_domain(after: int) -> int:
    """The next domain after ``after`` that no cartpole node on this machine uses."""
    for step in range(1, 233):
        candidate = (after + step) % 233
        if not _in_use(candidate):
            return candidate
    return (after + 1) % 233


def refusal(domain: int, what: str, allow: str) -> DuplicateNodeError:
    """The error that refuses a start: ``what`` was found on ``domain``; ``allow`` overrides."""
    free = free_domain(domain)
    return DuplicateNodeError(
        f'{what} on ROS_DOMAIN_ID={domain}: another graph is using this domain, and two graphs '
        f'on one domain drive each other\'s nodes. Stop the other graph, or run this one on '
        f'another domain (ROS_DOMAIN_ID={free} is free on this machine: export '
        f'ROS_DOMAIN_ID={free}), or start anyway with {allow}.')


def claim_node_names(names: Iterable[str], *, namespace: str = '/', domain: int | None = None,
                     hold: bool = True, allow: str = '--allow-duplicates') -> NodeClaim:
    """Take the machine-local locks of ``names`` on the domain (1. of the module docstring).

    With ``hold=False`` the locks are only tried and given back at once (a
    process that starts the nodes as children, which take them themselves).
    Raises :class:`DuplicateNodeError` naming the holder of a taken name.
    """
    domain = domain_id() if domain is None else domain
    claim = NodeClaim(domain)
    me = f'{os.getpid()} {_command_line()}'
    for name in names:
        path = _lock_path(domain, namespace, name)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
            writable = True
        except PermissionError:  # another user's lock file: a read-only descriptor locks too
            fd = os.open(path, os.O_RDONLY)
            writable = False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            claim.release()
            held = f' (held by PID {holder})' if holder else ''
            raise refusal(domain, f'node {_full_name(namespace, name)} is running already'
                                   f'{held}', allow) from None
        if not hold:
            os.close(fd)
            continue
        if writable:
            os.ftruncate(fd, 0)
            os.pwrite(fd, me.encode(), 0)
        claim._fds.append(fd)
        claim.names.append(name)
    return claim


def _command_line() -> str:
    try:
        return Path('/proc/self/cmdline').read_bytes().replace(b'\0', b' ').decode().strip()[:300]
    except OSError:
        return ''


def graph_duplicates(node, names: Iterable[str], *, namespace: str = '/',
                     wait: float | None = None, own: str | None = None) -> list[str]:
    """Names among ``names`` that the DDS graph shows in ``namespace`` (2. of the docstring).

    Polls ``node``'s graph for up to ``wait`` seconds (default
    :func:`discovery_wait`) and returns as soon as one is seen. ``own`` is a
    name the looking node itself carries (seen once without being a duplicate).
    """
    wanted = set(names)
    deadline = time.monotonic() + (discovery_wait() if wait is None else wait)
    while True:
        counts: dict[str, int] = {}
        for name, ns in node.get_node_names_and_namespaces():
            if name in wanted and (ns or '/') == namespace:
                counts[name] = counts.get(name, 0) + 1
        found = sorted(n for n, c in counts.items() if c > (1 if n == own else 0))
        if found or time.monotonic() >= deadline:
            return found
        time.sleep(POLL)


def probe_node(context=None):
    """A hidden node for looking at the graph (no rosout, no parameter services)."""
    from rclpy.node import Node
    return Node(f'_cartpole_probe_{os.getpid()}', context=context, enable_rosout=False,
                start_parameter_services=False,
                automatically_declare_parameters_from_overrides=True)


def claim_unique_names(probe, names: list[str], *, held: Iterable[str] | None = None,
                       namespace: str = '/', own: str | None = None,
                       allow: str = '--allow-duplicates') -> NodeClaim:
    """Both checks of the module docstring for ``names``, looking through ``probe``.

    The locks of ``held`` (default: all of ``names``) are kept in the returned
    claim; the others are only tried (their processes take them). Raises
    :class:`DuplicateNodeError`, holding nothing then.
    """
    held = list(names) if held is None else list(held)
    claim = claim_node_names(held, namespace=namespace, allow=allow)
    try:
        others = [n for n in names if n not in held]
        if others:
            claim_node_names(others, namespace=namespace, hold=False, allow=allow)
        found = graph_duplicates(probe, names, namespace=namespace, own=own)
        if found:
            what = ', '.join(_full_name(namespace, n) for n in found)
            raise refusal(claim.domain, f'node{"s" if len(found) > 1 else ""} {what} on the '
                                        f'graph already', allow)
    except BaseException:
        claim.release()
        raise
    return claim


def refuse_duplicate_node(make_node, context=None) -> NodeClaim | None:
    """The check of a node executable, before its node exists (see the module docstring).

    ``make_node`` is the node class; classes not in :data:`NODE_OF_CLASS`
    are not checked. Returns the claim (held until the context shuts down),
    None when not checked or allowed. Raises :class:`DuplicateNodeError`.
    """
    name = NODE_OF_CLASS.get(f'{getattr(make_node, "__module__", "")}.'
                             f'{getattr(make_node, "__qualname__", "")}')
    if name is None:
        return None
    probe = probe_node(context)
    try:
        allow = probe.get_parameter_or(ALLOW_PARAMETER, None).value
        if allow is True or str(allow).lower() == 'true':
            return None
        own = None
        if not probe.get_name().startswith('_cartpole_probe_'):
            name = own = probe.get_name()  # a global __node remapping renames every node
        claim = claim_unique_names(probe, [name], namespace=probe.get_namespace(), own=own,
                                   allow=f'-p {ALLOW_PARAMETER}:=true')
    finally:
        probe.destroy_node()
    (context or _default_context()).on_shutdown(functools.partial(NodeClaim.release, claim))
    return claim


def _default_context():
    from rclpy.utilities import get_default_context
    return get_default_context()
