"""The rig's calibration: encoder ticks <-> SI units (2.3), (2.4), force <-> DAC setpoint (A.3).

One frozen record the bridge converts with and the emulator converts back
with, so both sides of the Joint protocol use the same numbers
(docs/rig.md, "Conversions, device-time stamps and the safety rules"). No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters, EncoderResolution


@dataclass(frozen=True)
class Calibration(EncoderResolution):
    """Ticks <-> SI and force <-> setpoint of the rig.

    The encoder figures default to those of :class:`CartPoleParameters` (the
    one place the thesis's 8737 ticks over 0.769 m, 2000 ticks/rev and 16-bit
    counters are written), as floats (the bridge's parameters
    are doubles); the resolutions are :class:`EncoderResolution`'s. Signs are +1 when a positive count means the cart moved right (x grows)
    and the pendulum turned towards positive theta, and when a positive
    setpoint pushes the cart right; flip them if the wiring is reversed.
    """

    cart_sign: int = 1
    pendulum_sign: int = 1
    force_sign: int = 1
    cart_ticks_over_travel: float = float(CartPoleParameters.cart_ticks_over_travel)
    """Cart ticks over the whole travel (2.4)."""
    travel: float = CartPoleParameters.travel
    """Cart travel between the end stops [m] (section 2.3)."""
    pendulum_ticks_per_rev: float = float(CartPoleParameters.pendulum_ticks_per_rev)
    """Pendulum ticks per revolution (2.3)."""
    setpoint_per_newton: float = 56.744
    """1 / 0.017623 N, setpoint per newton (A.3)."""
    dac_zero: int = 1953
    """DAC value of zero current (Appendix A: offset 2000 corrected to 1953)."""
    dac_max: int = 4095
    """Largest value of the 12-bit DAC."""
    counter_bits: int = CartPoleParameters.counter_bits
    """Width of the HCTL-2021 counters; they wrap (section 2.3)."""

    def __post_init__(self) -> None:
        for name in ('cart_sign', 'pendulum_sign', 'force_sign'):
            if getattr(self, name) not in (1, -1):
                raise ValueError(f'{name} must be +1 or -1, got {getattr(self, name)!r}')
        for name in ('cart_ticks_over_travel', 'travel', 'pendulum_ticks_per_rev',
                     'setpoint_per_newton'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        if not (isinstance(self.dac_max, int) and self.dac_max > 0):
            raise ValueError(f'dac_max must be a positive integer, got {self.dac_max!r}')
        if not (isinstance(self.dac_zero, int) and 0 <= self.dac_zero <= self.dac_max):
            raise ValueError(f'dac_zero must be an integer in [0, {self.dac_max}], got {self.dac_zero!r}')

    @classmethod
    def from_parameters(cls, params: CartPoleParameters, **changes) -> 'Calibration':
        """The calibration matching the plant parameters' encoder figures."""
        base = dict(cart_ticks_over_travel=float(params.cart_ticks_over_travel),
                    travel=params.travel,
                    pendulum_ticks_per_rev=float(params.pendulum_ticks_per_rev),
                    counter_bits=params.counter_bits)
        base.update(changes)
        return cls(**base)

    @property
    def setpoint_min(self) -> int:
        """Lowest setpoint the DAC can output: -dac_zero (-1953)."""
        return -self.dac_zero

    @property
    def setpoint_max(self) -> int:
        """Highest setpoint the DAC can output: dac_max - dac_zero (2142)."""
        return self.dac_max - self.dac_zero

    def cart_position(self, ticks: int) -> float:
        """x [m] from an unwrapped cart count (2.4); 0 at the left stop after reset."""
        return self.cart_sign * ticks * self.cart_resolution

    def pendulum_angle(self, ticks: int) -> float:
        """theta [rad] from an unwrapped pendulum count (2.3); pi hanging after reset."""
        return math.pi + self.pendulum_sign * ticks * self.pendulum_resolution

    def force_to_setpoint(self, force: float) -> int:
        """setpoint = 56.744 x F (A.3), rounded half up, clamped to the DAC range
        [-1953, 2142]; a non-finite force gives 0. The amplifier saturates at
        +11 A / -12 A (about +34 N / -37 N, Appendix C) anyway, well inside
        that range (+-37 N is about +-2100)."""
        if not math.isfinite(force):
            return 0
        setpoint = math.floor(self.force_sign * force * self.setpoint_per_newton + 0.5)
        return self.clamp_setpoint(setpoint)

    def setpoint_to_force(self, setpoint: int) -> float:
        """F = setpoint / 56.744 = 0.017623 N x setpoint (A.3)."""
        return self.force_sign * setpoint / self.setpoint_per_newton

    def clamp_setpoint(self, setpoint: int) -> int:
        """The setpoint the DAC can output: dac_value(s) - dac_zero."""
        return min(max(int(setpoint), self.setpoint_min), self.setpoint_max)

    def dac_value(self, setpoint: int) -> int:
        """12-bit DAC value for a setpoint: dac_zero + setpoint clamped to 0..dac_max."""
        return min(max(self.dac_zero + int(setpoint), 0), self.dac_max)
