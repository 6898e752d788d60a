"""The plant's disturbance machinery: seeded random streams, the command delay line,
the exact factors of the amplifier's extra lag. Used by :class:`~cartpole_sim.plant.Plant`.

Times are whole nanoseconds (int), like ROS stamps and the plant's clock, so
a delay of exactly two samples lands exactly on a sample instant.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

STREAM_JITTER = 1
STREAM_DROP = 2
STREAM_FORCE_NOISE = 3
"""Sub-stream numbers: each random disturbance has its own generator,
``default_rng([seed, stream])``, independent of the others and of the
measurement noise (``default_rng(seed)``)."""


class RandomStream:
    """Draws of one distribution from its own seeded generator, fetched in blocks.

    ``next()`` costs a list index instead of a numpy call per draw (this is
    in the plant's inner loop); the sequence depends only on the seed.
    """

    BLOCK = 256

    def __init__(self, seed: int, stream: int, kind: str) -> None:
        if kind not in ('uniform', 'normal'):
            raise ValueError(f'kind must be uniform or normal, got {kind!r}')
        self._rng = np.random.default_rng([int(seed), int(stream)])
        self._draw = self._rng.random if kind == 'uniform' else self._rng.standard_normal
        self._block: list[float] = []
        self._i = 0

    def next(self) -> float:
        if self._i >= len(self._block):
            self._block = self._draw(self.BLOCK).tolist()
            self._i = 0
        value = self._block[self._i]
        self._i += 1
        return value


class CommandDelayLine:
    """Force commands on their way to the amplifier: a FIFO with latency.

    A command sent at ``t_ns`` arrives at ``t_ns + delay + U[0, jitter]``
    (whole nanoseconds), never before the previous one (a serial link keeps
    the order). :meth:`command_at` gives the command in force at a time.
    """

    def __init__(self, delay: float, jitter: float, seed: int) -> None:
        self.delay_ns = int(round(delay * 1e9))
        self.jitter_ns = float(jitter) * 1e9
        self._seed = seed
        self.reset()

    def reset(self) -> None:
        self._queue: deque[tuple[int, float]] = deque()
        self._last_arrival = -1
        self.applied = 0.0
        """The command in force (0 N until the first one arrives)."""
        self._jitter = RandomStream(self._seed, STREAM_JITTER, 'uniform') \
            if self.jitter_ns else None

    def send(self, t_ns: int, command: float) -> int:
        """Queue ``command`` sent at ``t_ns``; returns its arrival time [ns]."""
        arrival = t_ns + self.delay_ns
        if self._jitter is not None:
            arrival += int(round(self._jitter.next() * self.jitter_ns))
        if arrival < self._last_arrival:
            arrival = self._last_arrival
        self._last_arrival = arrival
        self._queue.append((arrival, command))
        return arrival

    def arrivals_between(self, t0_ns: int, t1_ns: int) -> list[int]:
        """Arrival times strictly inside (t0, t1): where a hold must be split."""
        return [a for a, _ in self._queue if t0_ns < a < t1_ns]

    def command_at(self, t_ns: int) -> float:
        """The command in force from ``t_ns`` on (every arrival up to ``t_ns`` applied)."""
        queue = self._queue
        while queue and queue[0][0] <= t_ns:
            self.applied = queue.popleft()[1]
        return self.applied


def lag_factors(pole: float, tau: float, h: float) -> tuple[float, float, float, float, float]:
    """Exact factors of the amplifier with an extra lag over a step of length ``h``.

    The commanded steady-state current c (constant over the step) passes the
    extra lag dz/dt = (c - z) / tau and then the current loop (4.4),
    di/dt = a (z - i) (its DC gain is in c). With e_z = z - c, e_i = i - c:

        e_z(t) = e_z0 exp(-t / tau)
        e_i(t) = e_i0 exp(-a t) + e_z0 a / (a - 1/tau) (exp(-t / tau) - exp(-a t))

    Returns ``(dz, di, cz, mi, mc)``: e_z(h) = dz e_z0,
    e_i(h) = di e_i0 + cz e_z0, and the mean of e_i over the step
    mi e_i0 + mc e_z0 (the force of the step is the mean current times
    k_t / r, as without the lag). At a = 1/tau the limit a t exp(-a t) is
    used.
    """
    a = float(pole)
    lam = 1.0 / float(tau)
    dz = math.exp(-lam * h)
    di = math.exp(-a * h)
    mz = -math.expm1(-lam * h) / (lam * h)
    mi = -math.expm1(-a * h) / (a * h)
    if abs(a - lam) > 1e-9 * a:
        k = a / (a - lam)
        cz = k * (dz - di)
        mc = k * (mz - mi)
    else:
        cz = a * h * di
        mc = (1.0 - di * (1.0 + a * h)) / (a * h)
    return dz, di, cz, mi, mc
