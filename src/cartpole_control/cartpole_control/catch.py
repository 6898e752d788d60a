"""Catch trigger (6.4) and fall detector: when the stabiliser takes over, and when it gives up.

Catch trigger (section 6.4). The stabiliser is switched in when both

    |E* - E_p| <= tol E*          (pendulum energy within tol of the upright energy)
    |theta_w|  <= angle           (the pendulum within angle of upright)

hold, with E_p the pendulum energy (7.3), E* = 2 m_p g l (6.8), tol = 0.05 and
angle = 30 deg in the thesis, and theta_w the angle wrapped to (-pi, pi]
(section 9.1: an unwrapped angle after a full revolution would make the
stabiliser correct a 2 pi error).

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.catch``).

No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters, pendulum_energy, wrap_angle


@dataclass(frozen=True)
class CatchTrigger:
    """The catch conditions (6.4) and the fall condition, as thresholds.

    Parameters
    ----------
    energy_tolerance
        tol of ``|E* - E_p| <= tol E*`` (thesis 0.05).
    angle
        Catch window on ``|theta_w|`` [rad] (thesis 30 deg = 0.5236 rad).
    fall_angle
        ``|theta_w|`` beyond which a stabilised pendulum counts as fallen [rad];
        must be larger than ``angle``.
    """

    energy_tolerance: float = 0.05
    angle: float = math.radians(30.0)
    fall_angle: float = math.radians(45.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.energy_tolerance) and self.energy_tolerance > 0.0):
            raise ValueError(f'energy_tolerance must be > 0, got {self.energy_tolerance!r}')
        if not (0.0 < self.angle <= math.pi):
            raise ValueError(f'catch angle must be in (0, pi], got {self.angle!r}')
        if not (self.angle < self.fall_angle <= math.pi):
            raise ValueError(f'fall angle ({math.degrees(self.fall_angle):g} deg) must be larger '
                             f'than the catch angle ({math.degrees(self.angle):g} deg) and at '
                             'most 180 deg')

    def energy_condition(self, energy: float, upright_energy: float) -> bool:
        """``|E* - E_p| <= tol E*`` (6.4)."""
        return abs(upright_energy - energy) <= self.energy_tolerance * upright_energy

    def angle_condition(self, theta: float) -> bool:
        """``|theta_w| <= angle`` (6.4); ``theta`` may be unwrapped."""
        return abs(wrap_angle(theta)) <= self.angle

    def should_catch(self, theta: float, theta_dot: float, params: CartPoleParameters) -> bool:
        """Both catch conditions of (6.4), with E_p from (7.3) and E* from (6.8)."""
        energy = pendulum_energy(theta, theta_dot, params)
        return self.energy_condition(energy, params.upright_energy) and self.angle_condition(theta)

    def has_fallen(self, theta: float) -> bool:
        """``|theta_w| > fall_angle``: the stabiliser has lost the pendulum."""
        return abs(wrap_angle(theta)) > self.fall_angle
