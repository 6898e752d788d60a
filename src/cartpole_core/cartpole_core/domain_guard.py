"""One graph per namespace of a ROS domain: a node refuses to start where its role is taken.

Two graphs in one namespace of one ``ROS_DOMAIN_ID`` share their topics, so one's
controller would drive the other's plant. Every node executable
(:func:`cartpole_core.node_runner.run_node` calls :func:`refuse_duplicate_node`) and
``cartpole run`` (:func:`claim_graph`) check before they create a node, by the node's
role (:mod:`cartpole_core.roles`, not its name), in two ways: on this machine, certain
and at once, an exclusive ``flock`` on ``<tmp>/cartpole-ros-domain-<N>/<namespace>.<role>.lock``
held for the life of the process (:class:`NodeClaim`); on the DDS graph, a hidden probe
node looks for a publisher of the role's own topic (:data:`cartpole_core.roles.ROLE_TOPICS`)
within :func:`discovery_wait` seconds.

A refusal raises :class:`DuplicateNodeError` naming the namespace, the domain, the node
found and the fixes. ``cartpole run --allow-duplicates`` or the parameter
``allow_duplicates:=true`` skips the check.
Design notes: (docs/running.md, "Namespaces, one graph per namespace").
"""
from __future__ import annotations

import fcntl
import functools
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

from .middleware import discovery_range
from .roles import ROLE_TOPICS, topic_in_namespace

ALLOW_PARAMETER = 'allow_duplicates'
LOCAL_WAIT = 0.5
"""Discovery wait [s] with localhost-only discovery (the locks cover this machine)."""
NETWORK_WAIT = 3.5
"""Discovery wait [s] when other machines can be on the domain."""
POLL = 0.05


class DuplicateNodeError(ValueError):
    """A node of the same role runs in the namespace already (the message says where and what to do)."""


def domain_id() -> int:
    """The ROS domain of this process (``ROS_DOMAIN_ID``, default 0)."""
    try:
        return int(os.environ.get('ROS_DOMAIN_ID') or 0)
    except ValueError:
        return 0


def discovery_wait() -> float:
    """How long the DDS look waits for discovery [s] (see the module docstring)."""
    scope = discovery_range()
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


def _lock_path(domain: int, namespace: str, role: str) -> Path:
    # '.' is in no ROS name: the namespace's tokens and the role never run together.
    stem = '.'.join([token for token in namespace.split('/') if token] + [role])
    return lock_directory(domain) / f'{stem}.lock'


def full_name(namespace: str, name: str) -> str:
    """``/rig1/sim`` of node ``sim`` in namespace ``/rig1`` (``/sim`` in the root)."""
    return topic_in_namespace(name, namespace)


@dataclass
class NodeClaim:
    """Roles held in a namespace of a domain by this process; :meth:`release` gives them back."""

    domain: int
    namespace: str = '/'
    roles: list[str] = field(default_factory=list)
    _fds: list[int] = field(default_factory=list, repr=False)

    def release(self) -> None:
        for fd in self._fds:
            try:
                os.close(fd)  # closing the descriptor releases its flock
            except OSError:
                pass
        self._fds.clear()
        self.roles.clear()


def _holder(fd: int) -> str:
    try:
        text = os.pread(fd, 4096, 0).decode('utf-8', 'replace').strip()
    except OSError:
        return ''
    return text


def _in_use(domain: int) -> bool:
    """Whether a cartpole node on this machine holds a lock of ``domain``."""
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


def refusal(domain: int, namespace: str, what: str, allow: str) -> DuplicateNodeError:
    """The error that refuses a start: ``what`` was found in ``namespace`` of ``domain``."""
    free = free_domain(domain)
    return DuplicateNodeError(
        f'{what}: another graph runs in namespace {namespace} on ROS_DOMAIN_ID={domain}, and '
        f'two graphs in one namespace drive each other\'s nodes. Stop the other graph, or run '
        f'this one in another namespace (cartpole run --namespace NAME; a node: --ros-args -r '
        f'__ns:=/NAME) or on another domain (ROS_DOMAIN_ID={free} is free on this machine: '
        f'export ROS_DOMAIN_ID={free}), or start anyway with {allow}.')


def claim_roles(roles: Iterable[str], *, namespace: str = '/', domain: int | None = None,
                hold: bool = True, allow: str = '--allow-duplicates',
                names: Mapping[str, str] | None = None) -> NodeClaim:
    """Take the machine-local locks of ``roles`` in ``namespace`` (1. of the module docstring).

    ``names`` gives the node name of a role (default: the role) for the
    holder's line in the lock file. With ``hold=False`` the locks are only
    tried and given back at once (a process that starts the nodes as
    children, which take them themselves). Raises :class:`DuplicateNodeError`
    naming the holder of a taken role.
    """
    domain = domain_id() if domain is None else domain
    claim = NodeClaim(domain, namespace)
    for role in roles:
        path = _lock_path(domain, namespace, role)
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
            raise refusal(domain, namespace, f'{role} node {holder or "of another process"} '
                                             f'is running', allow) from None
        if not hold:
            os.close(fd)
            continue
        if writable:
            name = full_name(namespace, (names or {}).get(role, role))
            os.ftruncate(fd, 0)
            os.pwrite(fd, f'{name} (PID {os.getpid()}: {_command_line()})'.encode(), 0)
        claim._fds.append(fd)
        claim.roles.append(role)
    return claim


def _command_line() -> str:
    try:
        return Path('/proc/self/cmdline').read_bytes().replace(b'\0', b' ').decode().strip()[:300]
    except OSError:
        return ''


def role_publishers(node, roles: Iterable[str], namespace: str = '/') -> dict[str, list[str]]:
    """The nodes (full names) the graph shows publishing each role's topic in ``namespace``.

    Keyed by the topic's absolute name; roles without a topic of their own
    (:data:`cartpole_core.roles.ROLE_TOPICS`) are not looked for.
    """
    out: dict[str, list[str]] = {}
    for topic in sorted({ROLE_TOPICS[r] for r in roles if r in ROLE_TOPICS}):
        name = topic_in_namespace(topic, namespace)
        out[name] = sorted(full_name(info.node_namespace or '/', info.node_name)
                           for info in node.get_publishers_info_by_topic(name))
    return out


def graph_duplicates(node, roles: Iterable[str], *, namespace: str = '/',
                     wait: float | None = None) -> list[str]:
    """What the DDS graph shows of ``roles`` in ``namespace`` (2. of the module docstring).

    Polls ``node``'s graph for up to ``wait`` seconds (default
    :func:`discovery_wait`) and returns as soon as one is seen: one
    ``node /rig1/sim publishes /rig1/joint_states`` a node found.
    """
    roles = list(roles)
    deadline = time.monotonic() + (discovery_wait() if wait is None else wait)
    while True:
        found = [f'node {publisher} publishes {topic}'
                 for topic, publishers in role_publishers(node, roles, namespace).items()
                 for publisher in publishers]
        if found or time.monotonic() >= deadline:
            return found
        time.sleep(POLL)


def probe_node(context=None, cli_args: list[str] | None = None):
    """A hidden node for looking at the graph (no rosout, no parameter services).

    ``cli_args`` (``['--ros-args', '-r', '__ns:=/rig1']``) puts it where the graph will be.
    """
    from rclpy.node import Node
    return Node(f'_cartpole_probe_{os.getpid()}', context=context, enable_rosout=False,
                start_parameter_services=False, cli_args=cli_args,
                automatically_declare_parameters_from_overrides=True)


def claim_graph(probe, roles: list[str], *, held: Iterable[str] | None = None,
                namespace: str = '/', names: Mapping[str, str] | None = None,
                allow: str = '--allow-duplicates') -> NodeClaim:
    """Both checks of the module docstring for ``roles`` in ``namespace``, looking through ``probe``.

    The locks of ``held`` (default: all of ``roles``) are kept in the returned
    claim; the others are only tried (their processes take them). Raises
    :class:`DuplicateNodeError`, holding nothing then.
    """
    held = list(roles) if held is None else list(held)
    claim = claim_roles(held, namespace=namespace, allow=allow, names=names)
    try:
        others = [r for r in roles if r not in held]
        if others:
            claim_roles(others, namespace=namespace, hold=False, allow=allow)
        found = graph_duplicates(probe, roles, namespace=namespace)
        if found:
            raise refusal(claim.domain, namespace, '; '.join(found), allow)
    except BaseException:
        claim.release()
        raise
    return claim


def refuse_duplicate_node(role: str | None, context=None) -> NodeClaim | None:
    """The check of a node executable of ``role``, before its node exists (module docstring).

    A node without a role (None) is not checked. The node's namespace and
    name come from the process's ROS arguments (``-r __ns:=``, ``-r __node:=``).
    Returns the claim (held until the context shuts down), None when not
    checked or allowed. Raises :class:`DuplicateNodeError`.
    """
    if role is None:
        return None
    probe = probe_node(context)
    try:
        allow = probe.get_parameter_or(ALLOW_PARAMETER, None).value
        if allow is True or str(allow).lower() == 'true':
            return None
        name = probe.get_name()
        if name.startswith('_cartpole_probe_'):
            name = role  # no global __node remapping: the node keeps its role's name
        claim = claim_graph(probe, [role], namespace=probe.get_namespace(),
                            names={role: name}, allow=f'-p {ALLOW_PARAMETER}:=true')
    finally:
        probe.destroy_node()
    (context or _default_context()).on_shutdown(functools.partial(NodeClaim.release, claim))
    return claim


def _default_context():
    from rclpy.utilities import get_default_context
    return get_default_context()
