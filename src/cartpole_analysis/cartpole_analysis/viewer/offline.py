"""``cartpole offline --view``: the offline loop, played in real time to the live viewer (no ROS).

The very closed loop of :func:`cartpole_bringup.offline.closed_loop.run_closed_loop`
(plant, 5 ms sampling, EKF, controller manager) with an observer that, for
every sample, feeds :class:`cartpole_analysis.viewer.server.LiveView` what the ROS
graph would have published -- the measurement, the ground truth, the
estimate, the controller status (with the force command) -- stamped with the
simulated time, and paces the loop to the wall clock: simulated time t is
shown at wall time ``start + t / speed``. The Foxglove WebSocket server,
channels and layout are the ``viewer`` node's, so the same Foxglove layout
shows a simulated run without any ROS graph.
"""
from __future__ import annotations

import time
from typing import Callable

from .server import ControlSample, LiveView


def control_sample(out) -> ControlSample:
    """A :class:`ControlSample` from the manager's :class:`~cartpole_control.manager.ManagerOutput`."""
    return ControlSample(mode=out.mode, swingup=out.swingup, stabilizer=out.stabilizer,
                         enabled=out.enabled, energy=out.energy, energy_error=out.energy_error,
                         raw_force=out.raw_force, feedforward=out.feedforward, force=out.force,
                         catch_count=float(out.catch_count), fall_count=float(out.fall_count),
                         event=out.event)


class RealTimePlayer:
    """The observer of the offline loop that shows it at ``speed`` x real time.

    Parameters
    ----------
    view
        Where the samples go.
    speed
        Simulated seconds per wall second (> 0).
    clock, sleep
        The wall clock and how to wait on it (injectable for tests).
    """

    def __init__(self, view: LiveView, speed: float = 1.0,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if not speed > 0:
            raise ValueError(f'speed must be > 0, got {speed!r}')
        self.view = view
        self.speed = float(speed)
        self.clock = clock
        self.sleep = sleep
        self._start: float | None = None
        self.late = 0
        """Samples shown more than a sample time after their wall time (the loop fell behind)."""

    def __call__(self, meas, est, out, truth) -> None:
        view = self.view
        stamp = int(round(meas.t * 1e9))
        if self._start is None:
            self._start = self.clock() - meas.t / self.speed
        wait = self._start + meas.t / self.speed - self.clock()
        if wait > 0:
            self.sleep(wait)
        elif wait < -0.005:
            self.late += 1
        view.measurement(stamp, meas.x, meas.theta)
        view.truth(stamp, truth[0], truth[1], truth[2], truth[3])
        view.estimate(stamp, est.x, est.theta, est.x_dot, est.theta_dot)
        view.status(stamp, control_sample(out))
