"""Rail guard: never drive the cart into an end stop (SPEC section 3.1 requirement, beyond the thesis).

Zero force alone does not stop the cart: with only Coulomb friction (about
3 N on 5 kg) a cart at 2 m/s rolls almost 3 m. The guard therefore knows the
cart's stopping distance and brakes *before* it is too late.

Each cycle, for the force ``F`` the controllers want, the guard predicts the
cart after the command has acted for the dead time ``T_d`` (the loop latency
plus the current loop's time constant 1/a of (4.4)), with the conservative
acceleration ``F / (m_c + m_p)`` (friction ignored)::

    v_1 = v + F T_d / (m_c + m_p),   x_1 = x + v T_d + F T_d^2 / (2 (m_c + m_p))

and from there the distance a full brake needs::

    d = v_1^2 / (2 a_b),   a_b = (F_b + c_c/2 - m_p (l theta_dot^2 + g)) / (m_c + m_p)

where ``F_b`` is the braking force (``max_brake_force``, limited by what the
amplifier gives in that direction: ``force_max`` to push right, ``-force_min``
to push left), ``c_c/2`` credits only half the smaller Coulomb friction of the
model (friction helps braking but is uncertain), and ``m_p (l theta_dot^2 + g)``
bounds the pull of a swinging pendulum on the cart (rod tension: centripetal
plus gravity). If ``x_1 +- d`` would leave ``[margin, travel - margin]`` while
the cart moves towards that side:

- a cart at rest (``|x_dot| <= rest_speed``, e.g. sitting at the left stop
  after reset), or moving away from that stop (only the commanded force would
  carry it there), is not braked; only the force pushing it towards that stop
  is withheld (set to zero). Inside a margin, a push further in is withheld
  whatever the velocity estimate says. Pushing away from a stop is always
  allowed.
- a moving cart trips the guard: it brakes with the full opposing force
  (the last step proportional, ``(m_c + m_p) |v| / Ts``, so it does not
  reverse the cart) until ``|x_dot| <= rest_speed``, then holds zero force.
  The guard stays tripped until :meth:`reset`; the manager reports the fault
  ``rail guard``.

No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_sim.model import CartPoleParameters

ARMED = 'armed'
LIMITED = 'limited'
BRAKING = 'braking'
STOPPED = 'stopped'
HOLD_SPEED = 0.002
"""[m/s] After a trip, creeping towards the nearer stop faster than this is braked."""


@dataclass(frozen=True)
class GuardAction:
    """What the guard did with one command."""

    force: float
    """The force to apply [N] (the command, a withheld zero, or the brake)."""
    status: str
    """``armed`` (command passed), ``limited`` (push towards a stop withheld),
    ``braking`` or ``stopped``."""
    tripped: bool
    """True on the one cycle the guard trips."""


class RailGuard:
    """Stopping-distance guard of the rail ends; see the module docstring.

    Parameters
    ----------
    params
        The controller's model of the plant (masses, friction, travel, force limits).
    margin
        Distance kept from each end stop [m].
    max_brake_force
        F_b [N], further limited by the amplifier in the braking direction.
    latency
        Loop latency before a command acts [s] (one sample period by default).
    rest_speed
        |x_dot| [m/s] below which the cart counts as at rest.
    """

    def __init__(self, params: CartPoleParameters, margin: float = 0.02,
                 max_brake_force: float = 30.0, latency: float | None = None,
                 rest_speed: float = 0.02) -> None:
        self.params = params
        self.margin = float(margin)
        self.max_brake_force = float(max_brake_force)
        self.latency = params.sample_time if latency is None else float(latency)
        self.rest_speed = float(rest_speed)
        if not 0.0 <= self.margin < 0.5 * params.travel:
            raise ValueError(f'margin must be in [0, travel/2), got {margin!r}')
        if not self.max_brake_force > 0.0:
            raise ValueError(f'max_brake_force must be > 0, got {max_brake_force!r}')
        if not self.latency >= 0.0:
            raise ValueError(f'latency must be >= 0, got {latency!r}')
        if not self.rest_speed > 0.0:
            raise ValueError(f'rest_speed must be > 0, got {rest_speed!r}')
        self.status = ARMED
        # Constants of the per-cycle arithmetic, computed once (the guard's
        # settings are fixed after construction; the manager builds a new guard
        # when they change). Each is the very expression the methods below
        # evaluate, so the numbers are the same to the last bit.
        self._mass = params.m_c + params.m_p
        self._dead_time = self.dead_time
        self._high = params.travel - self.margin
        self._friction = 0.5 * min(params.c_c_right, params.c_c_left)
        self._brake_pos = self.brake_force(1.0)
        self._brake_neg = self.brake_force(-1.0)
        self._min_deceleration = 0.05 * self._mass

    @property
    def tripped(self) -> bool:
        return self.status in (BRAKING, STOPPED)

    def reset(self) -> None:
        """Re-arm (after the manager's restart)."""
        self.status = ARMED

    # -- the estimate ---------------------------------------------------------------
    @property
    def dead_time(self) -> float:
        """T_d: latency plus the current loop's time constant 1/a of (4.4) [s]."""
        return self.latency + 1.0 / self.params.actuator_pole

    def brake_force(self, direction: float) -> float:
        """Magnitude of the brake available against motion in ``direction`` (sign of x_dot) [N]."""
        p = self.params
        actuator = -p.force_min if direction > 0.0 else p.force_max
        return min(self.max_brake_force, actuator)

    def deceleration(self, direction: float, theta_dot: float) -> float:
        """a_b, a conservative braking deceleration [m/s^2] (module docstring)."""
        p = self.params
        pendulum_pull = p.m_p * (p.l * theta_dot * theta_dot + p.g)
        brake = self._brake_pos if direction > 0.0 else self._brake_neg  # brake_force(direction)
        return max(brake + self._friction - pendulum_pull, self._min_deceleration) / self._mass

    def stopping_position(self, x: float, x_dot: float, theta_dot: float,
                          force: float) -> float:
        """Where a full brake starting after the dead time would stop the cart [m]."""
        mass = self._mass
        t_d = self._dead_time
        a_d = force / mass
        v_1 = x_dot + a_d * t_d
        x_1 = x + x_dot * t_d + 0.5 * a_d * t_d * t_d
        if v_1 == 0.0:
            return x_1
        direction = math.copysign(1.0, v_1)
        return x_1 + direction * v_1 * v_1 / (2.0 * self.deceleration(direction, theta_dot))

    # -- one cycle --------------------------------------------------------------------
    def check(self, x: float, x_dot: float, theta_dot: float, force: float) -> GuardAction:
        """Pass, withhold or override ``force`` for the state (x, x_dot, theta_dot)."""
        force, tripped = self.command(x, x_dot, theta_dot, force)
        return GuardAction(force, self.status, tripped)

    def command(self, x: float, x_dot: float, theta_dot: float,
                force: float) -> tuple[float, bool]:
        """:meth:`check` as ``(force, tripped)``, the status left in :attr:`status`.

        The manager's per-cycle call (no GuardAction to build).
        """
        status = self.status
        if status == STOPPED:
            return self._hold(x, x_dot), False
        if status == BRAKING:
            return self._brake(x_dot), False
        stop = self.stopping_position(x, x_dot, theta_dot, force)
        # Inside a margin a push further in is never passed, whatever x_dot reads.
        towards_right = (stop > self._high and stop > x) or (x > self._high and force > 0.0)
        towards_left = (stop < self.margin and stop < x) or (x < self.margin and force < 0.0)
        if not (towards_right or towards_left):
            self.status = ARMED
            return force, False
        if abs(x_dot) <= self.rest_speed or (x_dot < 0.0 if towards_right else x_dot > 0.0):
            # At rest, or moving away from that stop (only the command would carry
            # the cart there): never push further in, but allow pushing out. Braking
            # against x_dot here would push towards the very stop (a cart at the left
            # stop whose noisy velocity estimate reads +3 cm/s).
            self.status = LIMITED
            return (min(force, 0.0) if towards_right else max(force, 0.0)), False
        self.status = BRAKING
        return self._brake(x_dot), True

    def _hold(self, x: float, x_dot: float) -> float:
        """After a trip, at rest: zero force, unless the cart creeps towards the nearer stop.

        A pendulum falling or swinging after the trip can drag the stopped cart
        slowly (below ``rest_speed``) for seconds; any motion towards the nearer
        stop faster than :data:`HOLD_SPEED` is braked with the force that stops
        it within one sample (at most the full brake).
        """
        towards_stop = x_dot < -HOLD_SPEED if x < 0.5 * self.params.travel else x_dot > HOLD_SPEED
        if not towards_stop:
            return 0.0
        if abs(x_dot) > self.rest_speed:
            return self._brake(x_dot)
        direction = math.copysign(1.0, x_dot)
        brake = self._brake_pos if direction > 0.0 else self._brake_neg
        return -direction * min(brake, self._mass * abs(x_dot) / self.params.sample_time)

    def _brake(self, x_dot: float) -> float:
        if abs(x_dot) <= self.rest_speed:
            self.status = STOPPED
            return 0.0
        self.status = BRAKING
        direction = math.copysign(1.0, x_dot)
        # Full brake; the last step only what stops the cart within one sample.
        brake = self._brake_pos if direction > 0.0 else self._brake_neg
        magnitude = min(brake, self._mass * abs(x_dot) / self.params.sample_time)
        return -direction * magnitude
