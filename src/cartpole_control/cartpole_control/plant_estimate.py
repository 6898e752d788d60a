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

import math
from collections import deque
from typing import Callable

from cartpole_core.model import CartPoleParameters

from .actuator import ActuatorEstimator
from .latency import CommandsInFlight, LatencyEstimator, SampleAge
from .natural_frequency import NaturalFrequencyEstimator

SAMPLE_LAG = 0.5
"""The encoders' samples are taken by the first cycle at least this many sample periods
after their stamp: the previous sample's, published before this cycle's state could be
(:meth:`PlantEstimate.take_reports`)."""
REPORT_LAG = 1.5
"""The applied-command reports are taken this many sample periods after the time they
report: a plant reports a command with the sample after it took effect."""


DISTURBANCE_BAND = 1.0
"""[N] What the disturbance estimate cannot tell from the friction model's error at speed;
the swing-up cancels only the part beyond it."""
DISTURBANCE_CANCEL_MAX = 10.0
"""[N] The most of the disturbance a swing-up cancels."""


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
        self.sample_age = SampleAge(self.sample_time)
        """The mean age of the newest sample from the lost ones (:meth:`measured`)."""
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
        self.used_gain = 1.0
        """The actuator gain G the manager divided the last command by (``actuator.gain``)."""
        self.used_delay = 0.0
        """The extra dead time the manager's last prediction covered [s] (``actuator.delay``)."""
        self.used_friction = 1.0
        """The scale of the friction feedforward (6.12) the manager adds this cycle
        (``actuator.friction``)."""
        self.delay_known = False
        """The actuator's dead time is measured (or ``actuator.delay`` fixes it)."""

    @property
    def disturbance(self) -> float:
        """The estimated unmodelled force on the cart [N], positive to the right
        (:attr:`ActuatorEstimator.disturbance`)."""
        return self.actuator.disturbance

    @property
    def swingup_disturbance(self) -> float:
        """The part of :attr:`disturbance` a swing-up cancels [N]: beyond :data:`DISTURBANCE_BAND`,
        at most :data:`DISTURBANCE_CANCEL_MAX`.

        A cart held by friction stronger than the model's (or pushed back by a
        weak amplifier, or a cable) reads as a force against the push; the
        swing-up's small first pushes then never move it.
        """
        d = self.actuator.disturbance
        if abs(d) <= DISTURBANCE_BAND:
            return 0.0
        d -= math.copysign(DISTURBANCE_BAND, d)
        return min(max(d, -DISTURBANCE_CANCEL_MAX), DISTURBANCE_CANCEL_MAX)

    def force_limits(self) -> tuple[float, float]:
        """``(low, high)`` [N]: the force the amplifier delivers at the cart, G times its
        limits (Appendix C), with G the gain the manager divides the command by."""
        gain = self.used_gain
        return gain * self.plant.force_min, gain * self.plant.force_max

    @property
    def dead_time(self) -> float:
        """The loop's latency plus the actuator's extra dead time the manager compensates [s]."""
        return self.latency.latency + self.used_delay

    def acting_force(self, t: float) -> float | None:
        """The force [N] the cart feels over ``[t, t + Ts]`` by this estimate, once the command of
        the sample stamped ``t`` is sent: the commands in flight, each acting :attr:`dead_time`
        after its sample, times :attr:`used_gain`. What the EKF predicts with (its
        ``force_input`` ``acting``): the command as sent acts later and, on a weak amplifier,
        weaker. None when no command was sent for ``t`` (an idle or faulted cycle sends zero).
        """
        flight = self.in_flight
        if flight.last_stamp != t:
            return None
        mean = flight.mean_force(t, t + self.sample_time, self.dead_time)
        return None if mean is None else self.used_gain * mean

    def force_for_filter(self, t: float, command: float) -> float:
        """What the EKF predicts the interval after the sample ``t`` with (``force_input``
        ``acting``, ``cartpole/force_acting``): :meth:`acting_force` within the amplifier's
        range, or ``command`` [N] when there is none."""
        acting = self.acting_force(t)
        if acting is None:
            return command
        return min(max(acting, self.plant.force_min), self.plant.force_max)

    def filter_force(self, force_input: str) -> Callable[[float, float], float]:
        """``(t, command) -> force`` the EKF predicts the interval after the sample ``t`` with,
        for its ``force_input``: :meth:`force_for_filter` for 'acting', else the command."""
        return self.force_for_filter if force_input == 'acting' else _the_command

    @property
    def uncovered_dead_time(self) -> float | None:
        """The actuator's dead time the manager's prediction leaves out [s]: the estimate
        beyond :attr:`used_delay` (its dead band), None while not :attr:`delay_known` (the
        rail guard then assumes its prior, ``rail.actuator_dead_time``)."""
        if not self.delay_known:
            return None
        return max(self.actuator.delay - self.used_delay, 0.0)

    @property
    def omega_sq(self) -> float:
        """The pendulum's omega_0^2 = m_p g l / J [1/s^2]."""
        return self.natural_frequency.omega_sq

    def estimated_plant(self) -> CartPoleParameters:
        """The nominal plant with the pendulum length that gives :attr:`omega_sq` (l = g / omega_0^2)."""
        p = self.plant
        omega_sq = self.natural_frequency.omega_sq
        if omega_sq == self.natural_frequency.nominal:
            return p
        return p.replace(l=p.g / omega_sq)

    def command_applied(self, source: float, applied: float) -> None:
        """The command computed from the sample stamped ``source`` took effect at ``applied`` [s]."""
        self.reports.append((applied, source))

    def measured(self, t: float, x: float, theta: float) -> None:
        """The encoders' sample at ``t``: cart position [m], pendulum angle [rad] (unwrapped)."""
        self.samples.append((t, x, theta))
        self.sample_age.sample(t)

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

    def finish(self) -> None:
        """The work of the samples taken that need not precede the command: the actuator's
        window (:meth:`ActuatorEstimator.finish`)."""
        self.actuator.finish()

    def new_run(self) -> None:
        """A new run (a plant reset, a homing): the reports and windows of before end here.

        What was learnt of the loop, the actuator and the pendulum stays.
        """
        self.in_flight.reset()
        self.reports.clear()
        self.samples.clear()
        self.natural_frequency.forget_samples()
        self.actuator.forget_samples()


def _the_command(t: float, command: float) -> float:
    """The command as sent (``force_input`` 'command')."""
    return command
