"""Playing a pulse test sample by sample with a rail guard, and rehearsing it (no ROS)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

from .pulse_plan import Pulse
from .recording import Recording


@dataclass
class PulsePlayer:
    """Plays a pulse test sample by sample, with a rail guard (no ROS).

    Call :meth:`update` with every sample's time and measured cart position;
    it returns the force command for that sample (held until the next):

    1. zero for ``lead_in`` s (the quiet start :func:`fit_initial_state` uses);
    2. each pulse's force for its length, then zero until the cart has stood
       still (within two cart ticks) for ``settle`` s, or ``max_wait`` s
       passed; then the next pulse;
    3. zero once every pulse has settled (:attr:`done`).

    Rail guard: a pulse pushing towards a stop while the cart is within
    ``margin`` of that stop is cut to zero, and the rest of the plan is
    dropped (:attr:`reason` says why). Zero force lets the cart coast on its
    friction; it does not brake, so size the pulses with :func:`rehearse`.
    """

    pulses: tuple[Pulse, ...]
    params: CartPoleParameters = field(default_factory=CartPoleParameters)
    lead_in: float = 0.5
    settle: float = 1.0
    margin: float = 0.1
    max_wait: float = 10.0
    done: bool = field(default=False, init=False)
    reason: str = field(default='', init=False)
    """Empty while all is well; the guard's reason when it cut the plan short."""
    index: int = field(default=0, init=False)
    """The pulse being played or settled after."""
    _t0: float | None = field(default=None, init=False, repr=False)
    _phase: str = field(default='lead_in', init=False, repr=False)
    _t_phase: float = field(default=0.0, init=False, repr=False)
    _samples: int = field(default=0, init=False, repr=False)
    _anchor: tuple[float, float] = field(default=(0.0, 0.0), init=False, repr=False)

    def update(self, t: float, x: float) -> float:
        """The force command [N] for the sample at ``t`` [s] with cart position ``x`` [m]."""
        if self._t0 is None:
            self._t0 = t
            self._t_phase = t
            self._anchor = (t, x)
        if abs(x - self._anchor[1]) > 2.0 * self.params.cart_resolution:
            self._anchor = (t, x)  # the cart moved: stillness counts from here
        if self.done:
            return 0.0
        if self._phase == 'lead_in':
            if t - self._t0 < self.lead_in - 1e-9:
                return 0.0
            self._begin('pulse', t)
        if self._phase == 'settle':
            still = t - self._anchor[0] >= self.settle - 1e-9
            if not (still or t - self._t_phase >= self.max_wait - 1e-9):
                return 0.0
            if self.index + 1 >= len(self.pulses):
                self.done = True
                return 0.0
            self.index += 1
            self._begin('pulse', t)
        pulse = self.pulses[self.index]
        if self._samples >= max(1, int(round(pulse.length / self.params.sample_time))):
            self._begin('settle', t)
            return 0.0
        if (pulse.force > 0 and x > self.params.travel - self.margin) or \
                (pulse.force < 0 and x < self.margin):
            self.reason = (f'rail guard: pulse {self.index + 1} ({pulse.force:g} N) cut at '
                           f'x = {x:.3f} m, within {self.margin:g} m of the stop it pushes to')
            self.index = len(self.pulses) - 1
            self._begin('settle', t)
            return 0.0
        self._samples += 1
        return pulse.force

    def _begin(self, phase: str, t: float) -> None:
        self._phase, self._t_phase, self._samples = phase, t, 0


def rehearse(pulses: Sequence[Pulse], params: CartPoleParameters | None = None, *,
             x0: float = 0.0, theta0: float = math.pi, lead_in: float = 0.5,
             settle: float = 1.0, margin: float = 0.1, max_duration: float = 60.0,
             integration_step: float = 0.001) -> tuple[Recording, PulsePlayer]:
    """Play a pulse plan on the simulated plant: the predicted test and the player.

    The same :class:`PulsePlayer` the rig will see, driven by
    :class:`~cartpole_sim.plant.Plant` measurements; use it to size the
    pulses before trying them (where does the cart stop? does the guard
    trip?).
    """
    params = params or CartPoleParameters()
    player = PulsePlayer(tuple(pulses), params, lead_in=lead_in, settle=settle, margin=margin)
    plant = Plant(params, Scenario(x0=x0, theta0=theta0), integration_step=integration_step)
    t, x, theta, force = [], [], [], []
    n_max = int(round(max_duration / params.sample_time))
    for _ in range(n_max):
        m = plant.measure()
        f = player.update(m.t, m.x)
        t.append(m.t)
        x.append(m.x)
        theta.append(m.theta)
        force.append(f)
        if player.done:
            break
        plant.step(f)
    return Recording(np.array(t), np.array(x), np.array(theta), np.array(force),
                     'rehearsal'), player


def rehearsal_warnings(rec: Recording, player: PulsePlayer) -> list[str]:
    """Why a rehearsed pulse plan is unsafe to play on the rig ([] if it is not).

    Unsafe: the rail guard cut a pulse; the cart reached the travel's ends;
    or, once it has left the stop zones (``player.margin`` from each end),
    it came back within them (a coasting cart is not braked by anything but
    its friction).
    """
    p = player.params
    out = []
    if player.reason:
        out.append(player.reason)
    if not player.done:
        out.append(f'the plan did not finish within {rec.duration:.1f} s')
    if np.any(rec.x < 0.0) or np.any(rec.x > p.travel):
        out.append(f'the cart reaches an end stop (x from {rec.x.min():.3f} to '
                   f'{rec.x.max():.3f} m, travel {p.travel} m)')
    inside = (rec.x >= player.margin) & (rec.x <= p.travel - player.margin)
    if np.any(inside):
        first = int(np.argmax(inside))
        if not np.all(inside[first:]):
            k = first + int(np.argmin(inside[first:]))
            out.append(f'the cart coasts to x = {rec.x[k]:.3f} m at t = {rec.t[k]:.2f} s, within '
                       f'{player.margin:g} m of a stop')
    return out
