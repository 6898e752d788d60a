"""Real-time hygiene of the control loop's processes (no ROS import).

A 5 ms loop on two shared cores must not wait behind a BLAS thread pool, a full garbage
collection or normal-priority work. :func:`enter_loop` does once after start-up what the
ROS 2 real-time guides ask (:meth:`LoopHygiene.leave` undoes it): the collector frozen,
pushed out to :data:`SAFETY_THRESHOLD` and run where the loop has time to spare
(:func:`collect_when_idle`); ``SCHED_FIFO`` at :data:`DEFAULT_PRIORITY` for every thread
of a loop process (:data:`cartpole_core.roles.LOOP_ROLES`) in real time only, dropped
back to normal after :data:`RUNAWAY_LIMIT` s without blocking. :func:`pin_numerical_threads`
pins the BLAS threads to one (every cartpole package's ``__init__`` runs it, before numpy
loads); :class:`CycleGapMeter` keeps the longest gap between two cycles.

``CARTPOLE_REALTIME`` chooses the priority (unset or ``on``, 1..49, ``off`` or ``0``).
Design notes, log lines and measurements: (docs/realtime.md, "Real-time priority and stalls").
"""
from __future__ import annotations

import ctypes
import gc
import os
import resource
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, MutableMapping

from .roles import LOOP_ROLES

NUMERICAL_THREAD_VARIABLES = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS',
                              'BLIS_NUM_THREADS', 'VECLIB_MAXIMUM_THREADS',
                              'NUMEXPR_NUM_THREADS')
"""Thread-pool sizes of OpenMP, OpenBLAS, MKL, BLIS, Accelerate and numexpr."""

ENVIRONMENT_SWITCH = 'CARTPOLE_REALTIME'
DEFAULT_PRIORITY = 20
"""SCHED_FIFO priority of the loop's threads: above every normal process, well below
the kernel's threaded interrupts (50) and its migration and watchdog threads (99)."""
MAX_PRIORITY = 49
RECORDER_ROLE = 'recorder'
RECORDER_BELOW_LOOP = 5
"""The recorder in real time runs SCHED_FIFO this far below the loop (15 by default): not
in the loop, but a recorder starved for longer than the publishers' queues (0.5 s) loses
samples; a loop priority of 5 or less leaves it at normal priority."""
IDLE_THRESHOLDS = (700, 10)
"""CPython's default thresholds of the young generations, applied by :func:`collect_when_idle`."""
SAFETY_THRESHOLD = 200_000
"""Generation-0 threshold of the automatic collection while the policy is active: it
only runs if the loop has not called :func:`collect_when_idle` for that long."""
RUNAWAY_LIMIT = 0.5
"""CPU seconds a real-time thread may run without blocking before the process drops
back to normal priority (RLIMIT_RTTIME soft limit; a loop cycle takes well under 1 ms)."""


def pin_numerical_threads(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set every :data:`NUMERICAL_THREAD_VARIABLES` entry to ``'1'`` unless it is set.

    Call before numpy (or scipy) is imported: the pools are sized when the
    libraries load. Returns the variables this call set.
    """
    env = os.environ if environ is None else environ
    changed = {}
    for name in NUMERICAL_THREAD_VARIABLES:
        if not env.get(name):
            env[name] = '1'
            changed[name] = '1'
    return changed


def unpinned_numerical_threads(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The thread-pool variables whose value is not 1 (set so by the user), for a warning."""
    env = os.environ if environ is None else environ
    return {name: env[name] for name in NUMERICAL_THREAD_VARIABLES
            if env.get(name, '1').strip() != '1'}


def priority_from_environment(environ: Mapping[str, str] | None = None) -> int:
    """The priority ``CARTPOLE_REALTIME`` asks for (0: none); ValueError if it is garbage."""
    env = os.environ if environ is None else environ
    text = env.get(ENVIRONMENT_SWITCH, '').strip().lower()
    if text in ('', 'on'):
        return DEFAULT_PRIORITY
    if text == 'off':
        return 0
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_PRIORITY:
        raise ValueError(f'{ENVIRONMENT_SWITCH}={env.get(ENVIRONMENT_SWITCH)!r}: expected on, '
                         f'off (or 0) or a SCHED_FIFO priority 1..{MAX_PRIORITY}')
    return value


# -- garbage collector ---------------------------------------------------------------------
def collect_when_idle() -> int:
    """Run the collection that is due, if the loop policy is active; returns its generation.

    The choice is CPython's own (the oldest generation whose count exceeds
    its threshold, :data:`IDLE_THRESHOLDS`), made here, at a moment the loop
    has to spare, instead of at whatever allocation crosses the threshold.
    Returns -1 when nothing is due or the policy is not active. Cheap: a
    young collection with the start-up heap frozen takes tens of us. The
    oldest generation is never collected here: its pause grows with
    everything the run keeps (the monitor's series), which CPython itself
    only scans when it has grown by a quarter; it is left to the safety net.
    """
    if gc.get_threshold()[0] < SAFETY_THRESHOLD:
        return -1
    counts = gc.get_count()
    if counts[0] <= IDLE_THRESHOLDS[0]:
        return -1
    generation = 1 if counts[1] >= IDLE_THRESHOLDS[1] else 0
    gc.collect(generation)
    return generation


# -- scheduling ------------------------------------------------------------------------------
def _thread_ids() -> list[int]:
    try:
        return [int(tid) for tid in os.listdir('/proc/self/task')]
    except OSError:
        return [0]


def _set_policy(policy: int, priority: int) -> int:
    """``sched_setscheduler`` on every thread of this process; returns how many took it."""
    done = 0
    first_error: OSError | None = None
    for tid in _thread_ids():
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
            done += 1
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except OSError as error:
            first_error = first_error or error
    if done == 0 and first_error is not None:
        raise first_error
    return done


def _normal_policy() -> int:
    return os.SCHED_OTHER


@dataclass
class LoopHygiene:
    """What :func:`enter_loop` did to this process; :meth:`leave` undoes it."""

    priority: int = 0
    """The SCHED_FIFO priority the threads run at (0: normal scheduling)."""
    frozen: int = 0
    """Objects frozen after start-up."""
    message: str = ''
    """The log line :func:`enter_loop` wrote."""
    demoted: str = ''
    """Why the priority was dropped while running ('' if it was not)."""
    log: Callable[[str], None] = field(default=lambda text: None, repr=False)
    _previous_thresholds: tuple[int, int, int] | None = field(default=None, repr=False)
    _previous_rttime: tuple[int, int] | None = field(default=None, repr=False)
    _previous_xcpu: object = field(default=None, repr=False)
    _left: bool = field(default=False, repr=False)
    memory_locked: bool = False
    """The pages mapped at start-up are locked in memory (:func:`lock_memory`)."""

    def demote(self, why: str) -> None:
        """Back to normal scheduling for every thread (idempotent); logs ``why``."""
        if self.priority == 0:
            return
        try:
            _set_policy(_normal_policy(), 0)
        except OSError:
            pass
        self.priority = 0
        self.demoted = why
        self.log(f'real-time priority dropped: {why}')

    def _on_runaway(self, signum, frame) -> None:  # noqa: ARG002 - signal handler
        self.demote(f'a thread ran {RUNAWAY_LIMIT:g} s without blocking (SIGXCPU); the '
                    'process continues at normal priority')

    def leave(self) -> None:
        """Normal scheduling and the normal collector again (end of the loop's run)."""
        if self._left:
            return
        self._left = True
        if self.priority:
            try:
                _set_policy(_normal_policy(), 0)
            except OSError:
                pass
            self.priority = 0
        if self.memory_locked:
            unlock_memory()
            self.memory_locked = False
        if self._previous_rttime is not None:
            try:
                resource.setrlimit(resource.RLIMIT_RTTIME, self._previous_rttime)
            except (OSError, ValueError):
                pass
        if self._previous_xcpu is not None:
            try:
                signal.signal(signal.SIGXCPU, self._previous_xcpu)
            except (OSError, ValueError):
                pass
        if self._previous_thresholds is not None:
            gc.set_threshold(*self._previous_thresholds)
            gc.unfreeze()


MCL_CURRENT, MCL_ONFAULT = 1, 4
"""mlockall(2) flags: what is mapped now, locked as it is touched (nothing pre-faulted)."""


def lock_memory() -> str | None:
    """Lock the pages mapped now (the interpreter, the libraries, DDS) in memory, each as it is
    touched: None on success, else why not.

    A real-time thread that touches a code page the kernel evicted waits for the disk, and a
    neighbour that reads many files (a test suite, a build) evicts them. Later mappings
    (heap growth) are not locked, so no allocation can fail on ``RLIMIT_MEMLOCK``.
    """
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(MCL_CURRENT | MCL_ONFAULT) == 0:
            return None
        return os.strerror(ctypes.get_errno())
    except (OSError, AttributeError) as error:
        return str(error)


def unlock_memory() -> None:
    """Undo :func:`lock_memory`."""
    try:
        ctypes.CDLL(None, use_errno=True).munlockall()
    except (OSError, AttributeError):
        pass


def _guard_runaway(hygiene: LoopHygiene) -> bool:
    """RLIMIT_RTTIME soft limit + SIGXCPU handler (main thread only); True if installed."""
    if threading.current_thread() is not threading.main_thread():
        return False  # signal handlers can only be installed from the main thread
    try:
        previous = resource.getrlimit(resource.RLIMIT_RTTIME)
        soft = int(RUNAWAY_LIMIT * 1e6)
        hard = previous[1]
        if hard != resource.RLIM_INFINITY and hard < soft:
            soft = hard
        hygiene._previous_xcpu = signal.signal(signal.SIGXCPU, hygiene._on_runaway)
        resource.setrlimit(resource.RLIMIT_RTTIME, (soft, hard))
        hygiene._previous_rttime = previous
    except (OSError, ValueError, AttributeError):
        return False
    return True


def enter_loop(priority: int | None = None, *, log: Callable[[str], None] = print,
               warn: Callable[[str], None] | None = None, what: str = 'loop') -> LoopHygiene:
    """Freeze the collector, take the real-time priority; call once, after start-up.

    Parameters
    ----------
    priority
        SCHED_FIFO priority, 0 for none; None reads ``CARTPOLE_REALTIME``
        (:func:`priority_from_environment`, ValueError if it is garbage).
    log, warn
        Where the one-line report goes: ``log`` when all went as asked,
        ``warn`` (default ``log``) when the priority was not permitted or the
        numerical threads are not pinned.
    what
        The process's name in the log line.
    """
    warn = warn or log
    if priority is None:
        priority = priority_from_environment()
    if not 0 <= priority <= MAX_PRIORITY:
        raise ValueError(f'priority must be in 0..{MAX_PRIORITY}, got {priority}')
    hygiene = LoopHygiene(log=warn)
    gc.freeze()
    hygiene.frozen = gc.get_freeze_count()
    hygiene._previous_thresholds = gc.get_threshold()
    gc.set_threshold(SAFETY_THRESHOLD, *hygiene._previous_thresholds[1:])
    parts = [f'gc frozen ({hygiene.frozen} objects), collected when idle']
    problems = []
    unpinned = unpinned_numerical_threads()
    if unpinned:
        problems.append('numerical threads not pinned to one: ' + ', '.join(
            f'{k}={v}' for k, v in unpinned.items()))
    if priority == 0:
        parts.insert(0, 'normal priority')
    elif not sys.platform.startswith('linux'):
        problems.append('real-time priority is only taken on Linux; normal priority')
    else:
        try:
            threads = _set_policy(os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, priority)
        except OSError as error:
            problems.append(
                f'real-time priority (SCHED_FIFO {priority}) not permitted ({error.strerror}): '
                'the loop runs at normal priority and can stall under load; allow it with '
                'CAP_SYS_NICE or an rtprio limit (ulimit -r, /etc/security/limits.conf), '
                f'or set {ENVIRONMENT_SWITCH}=off')
        else:
            hygiene.priority = priority
            guarded = _guard_runaway(hygiene)
            parts.insert(0, f'SCHED_FIFO priority {priority} on {threads} threads'
                         + (f' (back to normal after {RUNAWAY_LIMIT:g} s without blocking)'
                            if guarded else ''))
            refused = lock_memory()
            if refused is None:
                hygiene.memory_locked = True
                parts.insert(1, 'memory locked')
            else:
                problems.append(f'memory not locked ({refused}): a page evicted under load '
                                'stalls the loop; allow it with CAP_IPC_LOCK or a memlock '
                                'limit (ulimit -l unlimited, /etc/security/limits.conf)')
    hygiene.message = f'{what}: real-time: ' + '; '.join(parts + problems)
    (warn if problems else log)(hygiene.message)
    return hygiene


def node_hygiene(role: str | None, logger, simulated_time: bool = False,
                 name: str | None = None) -> LoopHygiene:
    """:func:`enter_loop` for a node process: priority only for a ``role`` of
    :data:`cartpole_core.roles.LOOP_ROLES` in real time (not on ``simulated_time``,
    i.e. ``use_sim_time`` in lockstep), and :data:`RECORDER_BELOW_LOOP` below it for
    the recorder.

    ``logger`` has ``info`` and ``warning`` (an rclpy logger or a
    :class:`logging.Logger`); ``name`` (default: the role) is the node's name
    in the log line. Every node gets the collector policy.
    """
    base = priority_from_environment() if not simulated_time else 0
    if role in LOOP_ROLES:
        priority = base
    elif role == RECORDER_ROLE:
        priority = max(0, base - RECORDER_BELOW_LOOP)
    else:
        priority = 0
    return enter_loop(priority, log=logger.info, warn=logger.warning,
                      what=name or role or 'node')


# -- stall figure ---------------------------------------------------------------------------------
class CycleGapMeter:
    """The longest gap between two consecutive cycles [s] (a stall figure).

    ``tick()`` once a cycle (with the cycle's time, or the clock's now); the
    first tick only starts the measurement.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self.last: float | None = None
        self.longest = 0.0
        self.cycles = 0

    def tick(self, now: float | None = None) -> float:
        """Count a cycle at ``now``; returns the gap since the previous one (0 for the first)."""
        now = self._clock() if now is None else now
        gap = 0.0 if self.last is None else now - self.last
        if gap > self.longest:
            self.longest = gap
        self.last = now
        self.cycles += 1
        return gap
