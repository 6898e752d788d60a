"""The plant's disturbance machinery: seeded random streams, the command delay line,
the exact factors of the amplifier's extra lag, and the disturbed hold
(:class:`DisturbedHold`, a base of :class:`~cartpole_sim.plant.Plant`).

Times are whole nanoseconds (int), like ROS stamps and the plant's clock, so
a delay of exactly two samples lands exactly on a sample instant.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from cartpole_core.model import torque_accelerations

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
        self._queue: deque[tuple[int, float, float | None]] = deque()
        self._last_arrival = -1
        self.applied = 0.0
        """The command in force (0 N until the first one arrives)."""
        self.arrived: list[tuple[float, int]] = []
        """``(source, arrival_ns)`` of each tagged command that has taken effect (the
        plant's report of when each command was applied; its reader clears it)."""
        self._jitter = RandomStream(self._seed, STREAM_JITTER, 'uniform') \
            if self.jitter_ns else None

    def send(self, t_ns: int, command: float, source: float | None = None) -> int:
        """Queue ``command`` sent at ``t_ns``; returns its arrival time [ns].

        ``source`` (the stamp of the sample the command was computed from)
        tags it: its arrival is then listed in :attr:`arrived`.
        """
        arrival = t_ns + self.delay_ns
        if self._jitter is not None:
            arrival += int(round(self._jitter.next() * self.jitter_ns))
        if arrival < self._last_arrival:
            arrival = self._last_arrival
        self._last_arrival = arrival
        self._queue.append((arrival, command, source))
        return arrival

    def arrivals_between(self, t0_ns: int, t1_ns: int) -> list[int]:
        """Arrival times strictly inside (t0, t1): where a hold must be split."""
        return [a for a, _, _ in self._queue if t0_ns < a < t1_ns]

    def command_at(self, t_ns: int) -> float:
        """The command in force from ``t_ns`` on (every arrival up to ``t_ns`` applied)."""
        queue = self._queue
        while queue and queue[0][0] <= t_ns:
            arrival, self.applied, source = queue.popleft()
            if source is not None:
                self.arrived.append((source, arrival))
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


class DisturbedHold:
    """The plant's hold under delay, jitter, force noise, extra lag or pushes.

    A part of :class:`~cartpole_sim.plant.Plant` (its base class): it uses the
    plant's state, current loop and RK4 (``_rk4_steps``, ``_substeps``,
    ``_current_target``) and the delay line, streams and push windows the
    plant sets up from its scenario. :meth:`Plant.step` calls
    :meth:`_step_disturbed` when any of these disturbances is on.
    """

    def _step_disturbed(self, force_command: float, duration: float | None,
                        source: float | None = None) -> None:
        """:meth:`step` with delay, jitter, force noise, extra lag or pushes.

        The command enters the delay line at the start of the hold; the hold
        is split where a queued command arrives or a push starts or ends, and
        each piece is integrated like a hold of its own length (the
        unsplit hold exactly like the fast path, to the bit).
        """
        t0 = int(round(self.t * 1e9))
        t1 = t0 + (self._period_ns if duration is None else max(1, int(round(duration * 1e9))))
        self.force_command = force_command
        line = self._delay_line
        line.send(t0, force_command, source)
        noise = (self._force_noise_draws.next() * self.scenario.force_noise
                 if self._force_noise_draws is not None else 0.0)
        cuts = line.arrivals_between(t0, t1)
        for start, end, _, _ in self._pushes:
            if t0 < start < t1:
                cuts.append(start)
            if t0 < end < t1:
                cuts.append(end)
        bounds = [t0, *sorted(set(cuts)), t1] if cuts else [t0, t1]
        x, th, v, w = self.state
        deepest = 0.0
        for a, b in zip(bounds, bounds[1:]):
            cart, torque = noise, 0.0
            for start, end, target, amplitude in self._pushes:
                if start <= a < end:
                    if target == 'cart':
                        cart += amplitude
                    else:
                        torque += amplitude
            h, forces = self._hold(line.command_at(a), b - a, cart)
            x, th, v, w, d = self._rk4_steps(x, th, v, w, h, forces,
                                             self._acc_with_torque(torque) if torque else None,
                                             a / 1e9, cart)
            if d and abs(d) > abs(deepest):
                deepest = d
        self.state = [x, th, v, w]
        self.t = t1 / 1e9
        self.contact_penetration = deepest

    def _hold(self, command: float, duration_ns: int, extra: float) -> tuple[float, list[float]]:
        """The RK4 step length and the force of each step of a hold of ``command``.

        The current loop (4.4), after the extra lag if ``actuator_tau`` > 0
        (:func:`~cartpole_sim.disturbance.lag_factors`), integrated exactly
        over each step; ``extra`` [N] (force noise, a push) is added to the
        actuator's force. Advances :attr:`current` and :attr:`lag_current`.
        """
        factors = self._hold_factors.get(duration_ns)
        if factors is None:
            duration = duration_ns / 1e9
            n, h, decay, mean_factor = (self._default_substeps if duration_ns == self._period_ns
                                        else self._substeps(duration))
            tau = self.scenario.actuator_tau
            lag = lag_factors(self.true_params.actuator_pole, tau, h) if tau else None
            factors = self._hold_factors[duration_ns] = (n, h, decay, mean_factor, lag)
        n, h, decay, mean_factor, lag = factors
        i_target = self._current_target(command)
        fpa = self.true_params.force_per_ampere
        current = self.current
        forces = []
        if lag is None:
            for _ in range(n):
                forces.append((i_target + (current - i_target) * mean_factor) * fpa)
                current = i_target + (current - i_target) * decay
        else:
            dz, di, cz, mi, mc = lag
            z = self.lag_current
            for _ in range(n):
                e_z, e_i = z - i_target, current - i_target
                forces.append((i_target + e_i * mi + e_z * mc) * fpa)
                current = i_target + e_i * di + e_z * cz
                z = i_target + e_z * dz
            self.lag_current = z
        self.current = current
        if extra:
            forces = [f + extra for f in forces]
        return h, forces

    def _acc_with_torque(self, torque: float):
        """The acceleration function with a torque on the pendulum (:func:`torque_accelerations`)."""
        fn = self._torque_acc.get(torque)
        if fn is None:
            acc, p = self._acc, self.true_params

            def fn(x, th, v, w, force):
                a, b = acc(x, th, v, w, force)
                da, db = torque_accelerations(th, torque, p)
                return a + da, b + db
            self._torque_acc[torque] = fn
        return fn
