"""What /proc says of a process: CPU time, resident memory, open files, children, its node.

Read by the benchmarks and ``cartpole soak``, which account each process of a
graph (one process a node with ``--processes``) separately. Linux only.
"""
from __future__ import annotations

import os
from pathlib import Path


def stat_fields(pid: int) -> list[str] | None:
    """/proc/<pid>/stat from field 3 (state) on, or None if the process is gone."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None


def cpu_seconds(pid: int) -> float | None:
    """CPU time of this process alone: utime + stime (fields 14, 15) [s]."""
    fields = stat_fields(pid)
    if fields is None:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def process_name(pid: int, default: str) -> str:
    """The graph node a process runs (its executable's name, as in graph.NODES), else ``default``."""
    from cartpole_bringup.graph.graph import NODES
    try:
        argv = Path(f'/proc/{pid}/cmdline').read_bytes().split(b'\0')
    except OSError:
        return default
    names = {exe: name for name, (_, exe, _, _) in NODES.items()}
    names.setdefault('cartpole_viewer', 'viewer')  # cartpole run --view's viewer process
    for arg in argv[:2]:
        base = os.path.basename(arg.decode(errors='replace'))
        if base in names:
            return names[base]
    return default


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (scanning /proc for their parent PID)."""
    out = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            fields = stat_fields(int(entry.name))
            if fields is not None and int(fields[1]) == pid:
                out.append(int(entry.name))
    return sorted(out)


def rss_bytes(pid: int) -> int | None:
    """Resident memory of the process (VmRSS of /proc/<pid>/status) [bytes], None if gone."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def open_files(pid: int) -> int | None:
    """Open file descriptors of the process (entries of /proc/<pid>/fd), None if gone."""
    try:
        return len(os.listdir(f'/proc/{pid}/fd'))
    except OSError:
        return None
