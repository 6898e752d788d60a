"""The DDS settings a cartpole process starts with: a service reply never holds the loop.

rmw_fastrtps waits inside ``send_response``, holding the GIL, until the caller's reply
reader is discovered, up to the reply writer's ``max_blocking_time`` (100 ms by default):
every ``ros2 param set`` discovered late would stop every thread of the process that
long, and the bridge's 50 ms watchdogs would disarm the rig.

:func:`use_profiles` points Fast DDS at ``share/cartpole_core/config/fastdds_profiles.xml``,
whose ``service`` profile bounds that wait to :data:`REPLY_WAIT_S`, one sample period. It
runs before ``rclpy.init`` in every node executable and the ``cartpole`` command; child
processes inherit it. A profiles file of your own (``FASTRTPS_DEFAULT_PROFILES_FILE`` or
``FASTDDS_DEFAULT_PROFILES_FILE``) and another RMW are left alone.
Cause, measurements and the fix for your own profiles file: "The rig disarms when someone
runs ``ros2 param``" in (docs/troubleshooting.md, "Troubleshooting").
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import MutableMapping

PROFILES_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
"""The variable Fast DDS 2 (ROS 2 Jazzy) reads its profiles file from."""
USER_VARIABLES = (PROFILES_VARIABLE, 'FASTDDS_DEFAULT_PROFILES_FILE')
"""Either set by the user: their file is used, not ours."""
PROFILES_NAME = 'fastdds_profiles.xml'
REPLY_WAIT_S = 0.005
"""Longest wait [s] of a reply for its caller's discovery (the ``service`` profile's
``max_blocking_time``): one sample period."""


def profiles_file() -> Path | None:
    """The installed profiles file (the source tree's in a symlink install), None if missing."""
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory('cartpole_core')) / 'config')
    except Exception:  # not an ament install (PackageNotFoundError, no ament_index)
        pass
    candidates.append(Path(__file__).resolve().parent.parent / 'config')
    for directory in candidates:
        if (directory / PROFILES_NAME).is_file():
            return directory / PROFILES_NAME
    return None


def use_profiles(environ: MutableMapping[str, str] | None = None) -> Path | None:
    """Set ``FASTRTPS_DEFAULT_PROFILES_FILE`` to ours in ``environ`` (default ``os.environ``)
    unless the user chose a file or another RMW; returns the file it set, else None."""
    environ = os.environ if environ is None else environ
    rmw = environ.get('RMW_IMPLEMENTATION', '')
    if (rmw and not rmw.startswith('rmw_fastrtps')) or any(environ.get(v) for v in USER_VARIABLES):
        return None
    path = profiles_file()
    if path is not None:
        environ[PROFILES_VARIABLE] = str(path)
    return path
