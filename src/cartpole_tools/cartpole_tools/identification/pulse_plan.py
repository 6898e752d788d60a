"""A pulse test's plan (section 4.3.1): :class:`Pulse` and its parser (no ROS)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters

from .recording import IdentificationError


@dataclass(frozen=True)
class Pulse:
    """One force pulse of a test (section 4.3.1): ``force`` [N] held for ``length`` [s]."""

    force: float
    length: float


MAX_PULSE_LENGTH = 1.0
"""Longest pulse [s]; at 15 N the cart gains about 2.5 m/s in a second, far beyond the rail."""


def parse_pulse_plan(text: str, params: CartPoleParameters | None = None) -> tuple[Pulse, ...]:
    """``'15:0.25,-12:0.25'`` -> pulses (force [N] : length [s], comma-separated).

    Forces must be non-zero and within what the amplifier gives
    (``params.force_min`` .. ``params.force_max``); lengths in (0, 1] s.
    """
    params = params or CartPoleParameters()
    pulses = []
    for item in (s.strip() for s in str(text).split(',')):
        if not item:
            continue
        force, sep, length = item.partition(':')
        try:
            if not sep:
                raise ValueError
            pulse = Pulse(float(force), float(length))
        except ValueError:
            raise IdentificationError(
                f'pulse {item!r} is not FORCE:LENGTH (e.g. 15:0.25 for 15 N over 0.25 s)') from None
        if not (math.isfinite(pulse.force) and pulse.force != 0.0
                and params.force_min <= pulse.force <= params.force_max):
            raise IdentificationError(
                f'pulse force {pulse.force} N must be non-zero and within '
                f'[{params.force_min:.4g}, {params.force_max:.4g}] N')
        if not (math.isfinite(pulse.length) and 0.0 < pulse.length <= MAX_PULSE_LENGTH):
            raise IdentificationError(
                f'pulse length {pulse.length} s must be in (0, {MAX_PULSE_LENGTH}] s')
        pulses.append(pulse)
    if not pulses:
        raise IdentificationError('the pulse plan is empty')
    return tuple(pulses)
