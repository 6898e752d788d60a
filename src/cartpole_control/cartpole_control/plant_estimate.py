"""What the controller manager learns of the plant on line: one estimate every consumer reads.

The plant reports when each command took effect (:meth:`PlantEstimate.command_applied`)
and the encoders' samples (:meth:`PlantEstimate.measured`); the control cycle
feeds them, in stamp order, to the loop's latency (:mod:`cartpole_control.latency`),
the actuator's gain and dead time (:mod:`cartpole_control.actuator`) and the
pendulum's natural frequency (:mod:`cartpole_control.natural_frequency`), and
remembers the commands in flight. Design and equations: docs/controller_manager.md
("The plant estimate").

No ROS import.
"""
from __future__ import annotations

from collections import deque

from cartpole_core.model import CartPoleParameters

from .actuator import ActuatorEstimator
from .latency import CommandsInFlight, LatencyEstimator
from .natural_frequency import NaturalFrequencyEstimator

SAMPLE_LAG = 0.5
"""The encoders' samples are taken by the first cycle at least this many sample periods
after their stamp: the previous sample's, published before this cycle's state could be
(:meth:`PlantEstimate.take_reports`)."""
REPORT_LAG = 1.5
"""The applied-command reports are taken this many sample periods after the time they
report: a plant reports a command with the sample after it took effect."""


class PlantEstimate:
    """The loop's latency, the actuator and the pendulum as the manager has measured them.

    Parameters
    ----------
    plant
        The controllers' model of the plant (nominal parameters).
    sample_time
        Control period Ts [s].
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float) -> None:
        self.plant = plant
        self.sample_time = float(sample_time)
        self.latency = LatencyEstimator()
        """The loop's latency from the plant's reports (:meth:`command_applied`)."""
        self.natural_frequency = NaturalFrequencyEstimator(plant, self.sample_time)
        """omega_0^2 of the pendulum on the rig, from the encoders (:meth:`measured`)."""
        self.actuator = ActuatorEstimator(plant, self.sample_time)
        """The actuator's gain and extra dead time, from the cart's motion (:meth:`measured`)."""
        self.in_flight = CommandsInFlight()
        """The commands sent, by the stamp of the sample each was computed from."""
        self.reports: deque[tuple[float, float]] = deque()
        """(applied, source) of the plant's reports not yet taken (:meth:`take_reports`)."""
        self.samples: deque[tuple[float, float, float]] = deque()
        """(t, x, theta) of the encoders' samples not yet taken."""

    def command_applied(self, source: float, applied: float) -> None:
        """The command computed from the sample stamped ``source`` took effect at ``applied`` [s]."""
        self.reports.append((applied, source))

    def measured(self, t: float, x: float, theta: float) -> None:
        """The encoders' sample at ``t``: cart position [m], pendulum angle [rad] (unwrapped)."""
        self.samples.append((t, x, theta))

    def take_reports(self, t: float, stabilizing: bool) -> None:
        """Feed the estimators what the plant reported before the cycle at ``t``.

        The reports come on their own topics, and a cycle may run before the
        newest of them has arrived; taking only those published before the
        previous command was sent (:data:`SAMPLE_LAG`, :data:`REPORT_LAG`), in
        stamp order, makes every cycle's estimates depend on the samples alone,
        not on the order of arrival (a lockstep run stays the same run however
        its processes are scheduled). While ``stabilizing`` the natural
        frequency is not fed: a balanced pendulum says little about how it swings.
        """
        cutoff = t - REPORT_LAG * self.sample_time
        reports, samples = self.reports, self.samples
        while reports and reports[0][0] <= cutoff:
            applied, source = reports.popleft()
            self.latency.report(source, applied)
            force = self.in_flight.force_at(source)
            if force is not None:
                self.actuator.applied(applied, force)
        cutoff = t - SAMPLE_LAG * self.sample_time
        while samples and samples[0][0] <= cutoff:
            ts, x, theta = samples.popleft()
            if not stabilizing:
                self.natural_frequency.update(ts, x, theta)
            self.actuator.update(ts, x, theta)

    def new_run(self) -> None:
        """A new run (a plant reset, a homing): the reports and windows of before end here.

        What was learnt of the loop, the actuator and the pendulum stays.
        """
        self.in_flight.reset()
        self.reports.clear()
        self.samples.clear()
        self.natural_frequency.forget_samples()
        self.actuator.forget_samples()
