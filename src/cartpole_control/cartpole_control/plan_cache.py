"""The plan cache: minimum-time plans on disk, one solver a plan, no stale locks (no ROS).

Plans (:class:`~cartpole_control.trajectory_optimization.Trajectory`) are
stored as ``<key>.npz`` in :func:`default_cache_dir`, ``key`` being the
SHA-256 of the problem and the control grid
(:meth:`~cartpole_control.trajectory_optimization.MinimumTimeProblem.key`), so
a repeated start costs one file read.

Design notes: docs/controllers.md ("Design notes by module", ``cartpole_control.plan_cache``).
"""
from __future__ import annotations

import argparse
import fcntl
import hashlib
import json
import logging
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from .tracking import tracking_gains
from .trajectory_optimization import MinimumTimeProblem, Trajectory, solve_minimum_time

logger = logging.getLogger(__name__)

LOCK_POLL_S = 0.2
"""How often a waiting solver looks at a lock held by a live process [s]."""

Progress = Callable[[str], None]


class PlanError(RuntimeError):
    """A solve that raised (not an infeasible problem: that is a plan with success false)."""


class PlanBusy(RuntimeError):
    """A live process holds the plan's lock (``pid``) and the caller would not wait."""

    def __init__(self, pid: int | None) -> None:
        super().__init__(f'process {pid or "?"} is solving this plan')
        self.pid = pid


def default_cache_dir() -> Path:
    """``$CARTPOLE_CACHE_DIR``, else ``$XDG_CACHE_HOME/cartpole/trajectories`` (~/.cache/...)."""
    env = os.environ.get('CARTPOLE_CACHE_DIR')
    if env:
        return Path(env)
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return Path(base) / 'cartpole' / 'trajectories'


class PlanLock:
    """``<key>.lock``: one solver a plan; stale by holder (module docstring), never by age."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fd: int | None = None

    def acquire(self) -> bool:
        """Take the lock without waiting; False when a live process holds it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                os.close(fd)
                return False
            try:
                # The previous holder unlinks the file before it lets go: if ours is
                # no longer the file at the path, someone may hold the new one.
                current = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                current = False
            if current:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({'pid': os.getpid(), 'host': socket.gethostname(),
                                 'since': time.time()}).encode())
        self._fd = fd
        return True

    def release(self) -> None:
        if self._fd is None:
            return
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = None

    def holder(self) -> int | None:
        """PID of the live process that holds the lock (0 if it has not written it yet), or None.

        None also for a lock file nobody holds: a stale one (its writer died).
        """
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                try:
                    return int(json.loads(os.read(fd, 4096) or b'{}').get('pid', 0))
                except (ValueError, AttributeError):
                    return 0
            fcntl.flock(fd, fcntl.LOCK_UN)
            return None
        finally:
            os.close(fd)

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


class TrajectoryCache:
    """Plans on disk, one ``<key>.npz`` a problem (key: :meth:`MinimumTimeProblem.key`)."""

    def __init__(self, directory: str | Path | None = None) -> None:
        self.directory = Path(directory) if directory else default_cache_dir()

    def path(self, key: str) -> Path:
        return self.directory / f'{key}.npz'

    def lock(self, key: str) -> PlanLock:
        return PlanLock(self.directory / f'{key}.lock')

    def log_path(self, key: str) -> Path:
        """The background worker's log for ``key``."""
        return self.directory / f'{key}.log'

    def has(self, key: str) -> bool:
        """Whether a plan file for ``key`` exists (one ``stat``, no read)."""
        return self.path(key).is_file()

    def get(self, key: str) -> Trajectory | None:
        """The cached plan for ``key``, or None (a damaged file counts as missing)."""
        path = self.path(key)
        if not path.is_file():
            return None
        try:
            return Trajectory.load(path)
        except Exception:
            return None

    def put(self, key: str, trajectory: Trajectory) -> None:
        """Store a plan (atomically); the failure record and the gains of an older one go."""
        trajectory.save(self.path(key))
        self.directory.joinpath(f'{key}.failed').unlink(missing_ok=True)
        for old in self.directory.glob(f'{key}.tvlqr-*.npy'):
            old.unlink(missing_ok=True)

    def gains_path(self, key: str, q: Sequence[float], r: float) -> Path:
        """The TV-LQR gains of plan ``key`` for the weights (q, r)."""
        tag = hashlib.sha256(json.dumps([[float(v) for v in q], float(r)]).encode()).hexdigest()
        return self.directory / f'{key}.tvlqr-{tag[:16]}.npy'

    def get_gains(self, key: str, q: Sequence[float], r: float) -> np.ndarray | None:
        """Cached gains (N, 4) of plan ``key`` for (q, r), or None."""
        try:
            return np.load(self.gains_path(key, q, r), allow_pickle=False)
        except (OSError, ValueError):
            return None

    def put_gains(self, key: str, q: Sequence[float], r: float, gains: np.ndarray) -> None:
        path = self.gains_path(key, q, r)
        tmp = path.with_name(f'{path.name}.{os.getpid()}.tmp')
        try:
            with open(tmp, 'wb') as f:
                np.save(f, np.asarray(gains, dtype=float), allow_pickle=False)
            os.replace(tmp, path)
        except OSError as error:  # no writable cache: they are built again next time
            logger.warning('could not store the gains %s: %s', path, error)

    def failure(self, key: str) -> str | None:
        """Why the last solve of ``key`` raised, if it did (and no plan was stored since)."""
        try:
            return json.loads(self.directory.joinpath(f'{key}.failed').read_text())['reason']
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def record_failure(self, key: str, reason: str) -> None:
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self.directory.joinpath(f'{key}.failed').write_text(
                json.dumps({'reason': reason, 'pid': os.getpid(), 'time': time.time()}) + '\n')
        except OSError:
            pass

    def solve(self, problem: MinimumTimeProblem, grid: float | None, **options) -> Trajectory:
        """The plan for ``problem`` on ``grid``: from the cache, or solved and stored (blocks)."""
        return solve_cached(problem, grid, self, **options).plan


@dataclass(frozen=True)
class CachedPlan:
    """What :func:`solve_cached` returns."""

    plan: Trajectory
    solved: bool
    """Solved by this call (False: read from the cache)."""
    path: Path


def solve_cached(problem: MinimumTimeProblem, grid: float | None,
                 cache: TrajectoryCache | None = None, *, progress: Progress | None = None,
                 wait: bool = True, timeout: float | None = None, **options) -> CachedPlan:
    """The plan for ``problem`` on ``grid`` from ``cache``, or solved now and stored.

    Blocks for the solve. If a live process is solving the same plan, waits
    for it (``wait``) or raises :class:`PlanBusy`; a stale lock is taken over.
    ``options`` go to :func:`~cartpole_control.trajectory_optimization.solve_minimum_time`.
    ``progress`` gets one-line messages for the user.

    Raises
    ------
    PlanError
        The solve raised (the reason is logged and kept in ``<key>.failed``), or the
        cache directory cannot be written.
    TimeoutError
        ``timeout`` seconds passed waiting for another solver.
    """
    cache = cache or TrajectoryCache()
    key = problem.key(grid)
    lock = cache.lock(key)
    deadline = None if timeout is None else time.monotonic() + timeout
    announced: int | None = None
    while True:
        plan = cache.get(key)
        if plan is not None:
            return CachedPlan(plan, False, cache.path(key))
        try:
            acquired = lock.acquire()
        except OSError as error:
            raise PlanError(f'cannot use the plan cache {cache.directory}: {error}') from error
        if acquired:
            try:
                plan = cache.get(key)  # stored by the holder we waited for
                if plan is not None:
                    return CachedPlan(plan, False, cache.path(key))
                return CachedPlan(_solve_and_store(problem, grid, cache, key, options), True,
                                  cache.path(key))
            finally:
                lock.release()
        holder = lock.holder()
        if not wait:
            raise PlanBusy(holder)
        if holder != announced and progress is not None:
            progress(f'waiting for process {holder or "?"}, which is solving this plan '
                     f'(lock {lock.path})')
        announced = holder
        if deadline is not None and time.monotonic() > deadline:
            raise TimeoutError(f'process {holder} still holds {lock.path} after {timeout:g} s')
        time.sleep(LOCK_POLL_S)


def _solve_and_store(problem: MinimumTimeProblem, grid: float | None, cache: TrajectoryCache,
                     key: str, options: dict) -> Trajectory:
    try:
        plan = solve_minimum_time(problem, grid=grid, **options)
    except Exception as error:
        reason = f'{type(error).__name__}: {error}'
        logger.error('minimum-time solve %s failed: %s', key[:12], reason)
        cache.record_failure(key, reason)
        raise PlanError(reason) from error
    if not plan.success:
        logger.warning('minimum-time solve %s: IPOPT found no feasible plan from %s; stored as '
                       'unsuccessful', key[:12], problem.start)
    try:
        cache.put(key, plan)
    except OSError as error:
        raise PlanError(f'cannot store the plan in {cache.directory}: {error}') from error
    return plan


def cached_tracking_gains(problem: MinimumTimeProblem, plan: Trajectory, key: str,
                          q: Sequence[float], r: float, cache: TrajectoryCache) -> np.ndarray:
    """The TV-LQR gains of ``plan`` (cached as ``key``) for (q, r): a file read, else built
    (:func:`~cartpole_control.tracking.tracking_gains`: CasADi's import
    and about 10 ms) and stored next to the plan, so that the next load needs no CasADi."""
    gains = cache.get_gains(key, q, r)
    if gains is None or gains.shape != (len(plan.forces), 4):
        gains = tracking_gains(problem, plan, q, r)
        cache.put_gains(key, q, r, gains)
    return gains


# -- the background worker ----------------------------------------------------------------------
def start_background_solve(problem: MinimumTimeProblem, grid: float | None,
                           cache: TrajectoryCache | None = None,
                           tvlqr: tuple[Sequence[float], float] | None = None,
                           **options) -> subprocess.Popen | None:
    """Start a detached worker process solving ``problem`` into ``cache``; never blocks.

    With ``tvlqr`` = (q, r) the worker stores the plan's tracking gains too.
    Returns the worker (its output goes to ``<key>.log``), or None when the plan
    is cached already or a live process holds its lock.
    """
    cache = cache or TrajectoryCache()
    key = problem.key(grid)
    if cache.has(key) or cache.lock(key).holder() is not None:
        return None
    cache.directory.mkdir(parents=True, exist_ok=True)
    request = {'problem': problem.to_dict(), 'grid': grid, 'options': options,
               'tvlqr': None if tvlqr is None else [[float(v) for v in tvlqr[0]], float(tvlqr[1])]}
    with open(cache.log_path(key), 'ab') as log:
        return subprocess.Popen(
            [sys.executable, '-m', 'cartpole_control.plan_cache', '--cache', str(cache.directory),
             json.dumps(request)],
            stdin=subprocess.DEVNULL, stdout=log, stderr=log, start_new_session=True)


def main(argv: list[str] | None = None) -> int:
    """The worker: solve one request (JSON: problem, grid, options) into the cache."""
    parser = argparse.ArgumentParser(description='solve one minimum-time plan into the cache')
    parser.add_argument('--cache', required=True, help='cache directory')
    parser.add_argument('request', help='JSON {"problem": ..., "grid": ..., "options": ...}')
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format=f'%(asctime)s pid {os.getpid()} %(levelname)s %(message)s')
    try:
        os.nice(10)  # the control loop comes first
    except OSError:
        pass
    request = json.loads(args.request)
    problem = MinimumTimeProblem.from_dict(request['problem'])
    cache = TrajectoryCache(args.cache)
    logger.info('solving %s from %s', problem.key(request['grid'])[:12], problem.start)
    try:
        result = solve_cached(problem, request['grid'], cache, wait=False,
                              **request.get('options', {}))
    except PlanBusy as busy:
        logger.info('%s; leaving it to that one', busy)
        return 0
    except PlanError:
        return 1  # logged with its reason
    plan = result.plan
    if plan.success and request.get('tvlqr'):
        q, r = request['tvlqr']
        cached_tracking_gains(problem, plan, problem.key(request['grid']), q, r, cache)
    logger.info('%s: %s, T = %.3f s, %.1f s', result.path.name,
                'plan stored' if plan.success else 'no feasible plan (stored as unsuccessful)',
                plan.final_time, plan.solve_time)
    return 0


if __name__ == '__main__':
    sys.exit(main())
