"""Cart friction feedforward (6.12), with the kinetic friction of a moving cart compensated by its velocity.

The controllers are designed without the cart's Coulomb friction (6.11); the
manager adds it back to the active controller's output ``u``. The thesis's
law (6.12),

    B_ff(x_dot, u) = c_c(x_dot) tanh(k u),   c_c = c_c,R if x_dot >= 0 else c_c,L   (6.12)

follows the sign of the *command* ``u``, not of the velocity, so the
compensation never works against the controller (section 6.3). The thesis
tuned c_c,R = 3.3 N and c_c,L = 2.8 N (section 9.2.1); k is a tuning
parameter (per newton), about 10-100 (docs/controller_manager.md, "Modes and
transitions"). Without it the
swing-up's first centring push (about 1.9 N) stays below the 3.4 N static
friction and the cart never leaves the left stop.

Why the command's sign chatters while balancing. There ``u`` is small and
crosses zero all the time; the slope of (6.12) at ``u = 0`` is ``c_c k``
(66 N/N with k = 20), so every crossing flips the force by about 6 N, and the
loop's fastest mode (the LQR's pole near -130 1/s) sees its gain multiplied
by 67 near zero: the force flips sign from one sample to the next
(a period-2 oscillation at 100 Hz), which is most of the ``lqg`` command's
chatter. Yet the friction of a *moving* cart has a known sign, the
velocity's, which the EKF estimates well once the cart moves faster than a
few mm/s. With a velocity band ``v_b > 0``:

    B_ff(x_dot, u) = c_c(x_dot) [ s + (1 - |s|) tanh(k u) ],   s = sat(x_dot / v_b)

A cart moving faster than ``v_b`` gets exactly its kinetic friction
compensated, in the direction of its motion (so the controller sees the
frictionless cart it was designed for, braking included); a cart at rest gets
(6.12), the breakaway push in the command's direction; in between the two
blend linearly. It is memoryless and continuous in x_dot, so the noise of
the velocity estimate does not flip it. ``v_b = 0`` is the thesis's (6.12).

The default band is 0.5 mm/s, about the resolution of the EKF's velocity at
rest: the compensation follows the sign of the velocity as soon as the filter
sees the cart move, and the breakaway push of (6.12) goes only to a cart at
rest. Measured (``lqg`` on the EKF, nominal plant with noise, 10 seeds, last
10 s): force rms at most 2.80 N with 0.5 mm/s, 2.89 N with 1 mm/s, 3.0 N
with 1.5 mm/s; with (6.12) alone 4.5 N. A cart that moves all the time needs
its friction, 3.4 N right and 2.45 N left (2.96 N rms): below that the cart
must rest at times, which only a compensation that leaves a cart at rest
alone lets it do.

The band applies while stabilising only (:meth:`FrictionFeedforward.stabilizing`):
the swing-up laws keep (6.12), which they were designed and tuned with (with
the band, pendulum_energy's reversals lose the extra push of the command's
sign and the swing-up no longer reaches the catch window).

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
