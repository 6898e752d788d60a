"""Cart friction feedforward (6.12).

The controllers are designed without the cart's Coulomb friction (6.11); the
manager adds it back to the active controller's output ``u``:

    B_ff(x_dot, u) = c_c(x_dot) tanh(k u),   c_c = c_c,R if x_dot >= 0 else c_c,L   (6.12)

The tanh follows the sign of the *command* ``u``, not of the velocity, so the
compensation never works against the controller (section 6.3). The thesis
tuned c_c,R = 3.3 N and c_c,L = 2.8 N (section 9.2.1); k is a tuning
parameter (per newton), about 10-100 (SPEC section 7). Without it the
swing-up's first centring push (about 1.9 N) stays below the 3.4 N static
friction and the cart never leaves the left stop.

No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class FrictionFeedforward:
    """B_ff of (6.12).

    Parameters
    ----------
    c_right
        c_c,R, Coulomb level used while x_dot >= 0 [N] (thesis 3.3 N).
    c_left
        c_c,L, Coulomb level used while x_dot < 0 [N] (thesis 2.8 N).
    steepness
        k of tanh(k u) [1/N].
    """

    c_right: float = 3.3
    c_left: float = 2.8
    steepness: float = 20.0

    def __call__(self, x_dot: float, u: float) -> float:
        """B_ff(x_dot, u) [N], (6.12)."""
        c_c = self.c_right if x_dot >= 0.0 else self.c_left
        return c_c * math.tanh(self.steepness * u)
