"""The DDS settings a cartpole process starts with: nothing another process does holds the loop.

Two waits of Fast DDS would stop a loop process for a newcomer on the domain: a service
reply waits for the caller's discovery (100 ms by default, holding the GIL; the
``service`` profile bounds it to :data:`REPLY_WAIT_S`), and the shared-memory transport
opens a newcomer's port in the sending thread after a health check that can sleep 333 ms
(the participant profiles use UDP only).

:func:`use_profiles` points Fast DDS at ``share/cartpole_core/config/`` (the localhost
file when discovery stays on this host, else the network file) before ``rclpy.init`` in
every node executable and the ``cartpole`` command; child processes inherit it. For
``LOCALHOST`` rmw_fastrtps would add its own shared-memory transport, so the range is
handed to the profile (``ROS_AUTOMATIC_DISCOVERY_RANGE`` becomes ``SYSTEM_DEFAULT``,
:data:`REQUESTED_RANGE_VARIABLE` keeps ``LOCALHOST``). A profiles file of your own,
``ROS_STATIC_PEERS`` with localhost discovery and another RMW are left alone.
Causes, measurements and fixes for your own file: "The rig disarms when someone runs
``ros2 param``" and "A 333 ms stall when a process joins the domain" in
(docs/troubleshooting.md, "Troubleshooting").
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Mapping, MutableMapping

PROFILES_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
"""The variable Fast DDS 2 (ROS 2 Jazzy) reads its profiles file from."""
FASTDDS_PROFILES_VARIABLE = 'FASTDDS_DEFAULT_PROFILES_FILE'
"""The variable's name from Fast DDS 3 on (2.14 reads only the other); we never set it."""
USER_VARIABLES = (PROFILES_VARIABLE, FASTDDS_PROFILES_VARIABLE)
"""Either set by the user: their file is used, not ours."""
PROFILES_NAME = 'fastdds_profiles.xml'
"""Network discovery (``SUBNET``, the default): UDPv4 with Fast DDS's multicast discovery."""
LOCALHOST_PROFILES_NAME = 'fastdds_profiles_localhost.xml'
"""Discovery on this host: UDPv4 on 127.0.0.1, peers on 127.0.0.1, no multicast (what
rmw_fastrtps's ``LOCALHOST`` range sets, without its shared-memory transport)."""
RANGE_VARIABLE = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
REQUESTED_RANGE_VARIABLE = 'CARTPOLE_DISCOVERY_RANGE'
"""The range asked for when :func:`use_profiles` handed ``LOCALHOST`` to the profile."""
REPLY_WAIT_S = 0.005
"""Longest wait [s] of a reply for its caller's discovery (the ``service`` profile's
``max_blocking_time``): one sample period."""


def profiles_file(name: str = PROFILES_NAME) -> Path | None:
    """The installed profiles file ``name`` (the source tree's in a symlink install), None
    if missing."""
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory('cartpole_core')) / 'config')
    except Exception:  # not an ament install (PackageNotFoundError, no ament_index)
        pass
    candidates.append(Path(__file__).resolve().parent.parent / 'config')
    for directory in candidates:
        if (directory / name).is_file():
            return directory / name
    return None


def discovery_range(environ: Mapping[str, str] | None = None) -> str:
    """The discovery range asked for (upper case; '' if unset): ``ROS_AUTOMATIC_DISCOVERY_RANGE``,
    ``LOCALHOST`` by the deprecated ``ROS_LOCALHOST_ONLY=1`` or handed to our profile."""
    environ = os.environ if environ is None else environ
    scope = environ.get(RANGE_VARIABLE, '').strip().upper()
    if scope == 'SYSTEM_DEFAULT' and environ.get(REQUESTED_RANGE_VARIABLE) == 'LOCALHOST':
        return 'LOCALHOST'
    if environ.get('ROS_LOCALHOST_ONLY', '').strip() == '1':
        return 'LOCALHOST'  # rcl lets it win over the range
    return scope


def _ours(path: str) -> bool:
    return any(str(profiles_file(name)) == path for name in (PROFILES_NAME,
                                                              LOCALHOST_PROFILES_NAME))


def use_profiles(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """Set ``FASTRTPS_DEFAULT_PROFILES_FILE`` to ours for the discovery range in ``environ``
    (default ``os.environ``) unless the user chose a file or another RMW; returns the file
    it set, else None. Call it again after changing the range."""
    environ = os.environ if environ is None else environ
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    chosen = environ.get(PROFILES_VARIABLE)
    if ((rmw and not rmw.startswith('rmw_fastrtps')) or environ.get(FASTDDS_PROFILES_VARIABLE)
            or (chosen and not _ours(chosen))):
        return None
    scope = discovery_range(environ)
    localhost = scope == 'LOCALHOST' and not environ.get('ROS_STATIC_PEERS', '').strip()
    path = profiles_file(LOCALHOST_PROFILES_NAME if localhost else PROFILES_NAME)
    if path is None:
        return None
    environ[PROFILES_VARIABLE] = str(path)
    if localhost:  # else rmw_fastrtps adds its shared-memory transport to the profile's
        environ[RANGE_VARIABLE] = 'SYSTEM_DEFAULT'
        environ[REQUESTED_RANGE_VARIABLE] = 'LOCALHOST'
        environ.pop('ROS_LOCALHOST_ONLY', None)
    else:
        environ.pop(REQUESTED_RANGE_VARIABLE, None)
    return path


def set_discovery_range(scope: str, environ: MutableMapping[str, str] | None = None) -> str:
    """Ask for the discovery range ``scope`` (``LOCALHOST``, ``SUBNET``, ...) and take the
    profiles that go with it; returns the range now asked for."""
    environ = os.environ if environ is None else environ
    environ[RANGE_VARIABLE] = scope.strip().upper()
    environ.pop(REQUESTED_RANGE_VARIABLE, None)
    environ.pop('ROS_LOCALHOST_ONLY', None)
    use_profiles(environ)
    return discovery_range(environ)


def keep_on_this_host(environ: MutableMapping[str, str] | None = None) -> str:
    """Discovery on this host unless a range was asked for (:func:`set_discovery_range`);
    returns the range asked for."""
    environ = os.environ if environ is None else environ
    scope = discovery_range(environ)
    return scope if scope else set_discovery_range('LOCALHOST', environ)
