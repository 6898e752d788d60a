"""Cart friction feedforward (6.12), with the kinetic friction of a moving cart compensated by its velocity.

The controllers are designed without the cart's Coulomb friction (6.11); the
manager adds it back to the active controller's output ``u`` by the thesis's
law (6.12), ``B_ff(x_dot, u) = c_c(x_dot) tanh(k u)``; while stabilising, a
moving cart's kinetic friction is compensated along its velocity instead.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.feedforward``).

No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class FrictionFeedforward:
    """B_ff of (6.12), with the velocity band described in the module docstring.

    Parameters
    ----------
    c_right
        c_c,R, Coulomb level used while x_dot >= 0 [N] (thesis 3.3 N).
    c_left
        c_c,L, Coulomb level used while x_dot < 0 [N] (thesis 2.8 N).
    steepness
        k of tanh(k u) [1/N].
    velocity_band
        v_b [m/s]: above it the kinetic friction is compensated along the
        velocity; 0 gives the thesis's (6.12) at every speed.
    """

    c_right: float = 3.3
    c_left: float = 2.8
    steepness: float = 20.0
    velocity_band: float = 0.0005

    def __call__(self, x_dot: float, u: float) -> float:
        """B_ff(x_dot, u) [N] of (6.12), what swing-up laws get."""
        c_c = self.c_right if x_dot >= 0.0 else self.c_left
        return c_c * math.tanh(self.steepness * u)

    def stabilizing(self, x_dot: float, u: float) -> float:
        """B_ff(x_dot, u) [N] with the velocity band, what stabilisers get."""
        c_c = self.c_right if x_dot >= 0.0 else self.c_left
        command = math.tanh(self.steepness * u)
        band = self.velocity_band
        if band <= 0.0:
            return c_c * command  # (6.12)
        s = x_dot / band
        if s >= 1.0:
            return c_c
        if s <= -1.0:
            return -c_c
        return c_c * (s + (1.0 - abs(s)) * command)
