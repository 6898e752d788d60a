"""Rail guard: never drive the cart into an end stop (thesis section 3.1's requirement; the
guard itself is beyond the thesis).

Zero force alone does not stop the cart: with only Coulomb friction (about
3 N on 5 kg) a cart at 2 m/s rolls almost 3 m. The guard therefore knows the
cart's stopping distance and brakes *before* it is too late.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.rail_guard``).

No ROS import.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from cartpole_core.model import CartPoleParameters, acceleration_function

ARMED = 'armed'
LIMITED = 'limited'
BRAKING = 'braking'
STOPPED = 'stopped'
LIMIT_ITERATIONS = 24
"""Bisection steps of the limited force (resolution ``(F + F_b) / 2**24``, micro-newtons)."""
ACTUATOR_DEAD_TIME = 0.04
"""[s] The actuator's dead time beyond the reported latency (a lag, a filter: the combined
benchmark draws first-order lags up to 30 ms and latency jitter up to 5 ms) that the envelope
assumes until the plant estimate has measured it (``rail.actuator_dead_time``)."""
DISTURBANCE_MAX = 5.0
"""[N] The guard counts the estimated unmodelled force up to this: a cable or a hand
leaning on the cart; the estimate of a push lags it by a window and is left out."""
PASSED_ITERATIONS = 12
"""Bisection steps of an end of :meth:`RailGuard.passed_range` (about 0.02 N on 70 N)."""
HOLD_SPEED = 0.002
"""[m/s] After a trip, creeping towards the nearer stop faster than this is braked."""
RESERVE_TIME = 0.1
"""[s] While balancing, the limiter's reserve is the distance the cart covers in this time
(``rail.reserve_time``): what an unmodelled dead time that long moves its stop."""


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
    creep_speed
        Inside a margin a cart slower than this [m/s] counts as at rest
        (module docstring); at most ``rest_speed`` turns it off.
    limit
        Limit the command of a moving cart to the braking envelope before
        tripping (module docstring); False trips at once.
    limit_reserve
        The limiter keeps the stopping position this much [m] further from
        the stops than the trip test does.
    reserve_time
        While :attr:`balancing`, the reserve is ``|x_dot| reserve_time``, at
        most ``limit_reserve`` [s] (0: the whole reserve at every speed;
        :meth:`reserve`).
    actuator_dead_time
        The actuator's extra dead time [s] assumed until :meth:`set_actuator`
        reports it measured (0: the model's actuator; the manager's default is
        :data:`ACTUATOR_DEAD_TIME`).
    """

    def __init__(self, params: CartPoleParameters, margin: float = 0.02,
                 max_brake_force: float = 30.0, latency: float | None = None,
                 rest_speed: float = 0.02, creep_speed: float = 0.1,
                 limit: bool = True, limit_reserve: float = 0.05,
                 actuator_dead_time: float = 0.0, reserve_time: float = RESERVE_TIME) -> None:
        self.params = params
        self.margin = float(margin)
        self.max_brake_force = float(max_brake_force)
        self.latency = params.sample_time if latency is None else float(latency)
        self.rest_speed = float(rest_speed)
        self.limit = bool(limit)
        self.creep_speed = float(creep_speed)
        self.limit_reserve = float(limit_reserve)
        self.reserve_time = float(reserve_time)
        if not (math.isfinite(self.reserve_time) and self.reserve_time >= 0.0):
            raise ValueError(f'reserve_time must be >= 0, got {reserve_time!r}')
        self.balancing = False
        """The stabiliser balances (the manager says so every cycle): the reserve follows the
        speed (:meth:`reserve`); else, and while the swing-up runs the cart along the rail, it
        is the whole ``limit_reserve``."""
        self.measured_x_dot: float | None = None
        """The estimate's x_dot [m/s] before the prediction (the manager says so every cycle).
        After a trip the brake and the hold judge the faster of it and the predicted x_dot:
        a prediction that takes the amplifier for stronger than it is (a gain not yet
        measured) sees the cart at rest while it still runs towards the stop."""
        self.actuator_dead_time = float(actuator_dead_time)
        if not (math.isfinite(self.actuator_dead_time) and self.actuator_dead_time >= 0.0):
            raise ValueError(f'actuator_dead_time must be >= 0, got {actuator_dead_time!r}')
        self.extra_dead_time = self.actuator_dead_time
        """The actuator's dead time the envelope adds [s]: the prior until measured (:meth:`set_actuator`)."""
        if not (math.isfinite(self.limit_reserve) and
                0.0 <= self.limit_reserve < 0.5 * params.travel - self.margin):
            raise ValueError(f'limit_reserve must be in [0, travel/2 - margin), got {limit_reserve!r}')
        if not 0.0 <= self.margin < 0.5 * params.travel:
            raise ValueError(f'margin must be in [0, travel/2), got {margin!r}')
        if not self.max_brake_force > 0.0:
            raise ValueError(f'max_brake_force must be > 0, got {max_brake_force!r}')
        if not self.latency >= 0.0:
            raise ValueError(f'latency must be >= 0, got {latency!r}')
        if not self.rest_speed > 0.0:
            raise ValueError(f'rest_speed must be > 0, got {rest_speed!r}')
        if not (math.isfinite(self.creep_speed) and self.creep_speed >= 0.0):
            raise ValueError(f'creep_speed must be >= 0, got {creep_speed!r}')
        self.status = ARMED
        # Constants of the per-cycle arithmetic, computed once (the guard's
        # settings are fixed after construction; the manager builds a new guard
        # when they change). Each is the very expression the methods below
        # evaluate, so the numbers are the same to the last bit.
        self._mass = params.m_c + params.m_p
        self._dead_time = self.dead_time
        self._high = params.travel - self.margin
        self._friction = 0.5 * min(params.c_c_right, params.c_c_left)
        self.gain = 1.0
        """The actuator's gain G: the force at the cart per newton commanded (:meth:`set_actuator`)."""
        self.disturbance = 0.0
        """The unmodelled force on the cart [N] the envelope counts where it lengthens a stop."""
        self.predicted_stop = math.nan
        """Where the guard expected the cart to stop when it last tripped [m] (:meth:`braked_stop`)."""
        self._acc = None
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
        """T_d: latency plus the current loop's time constant 1/a of (4.4) plus the
        actuator's dead time the manager's prediction does not cover [s]."""
        return self.latency + 1.0 / self.params.actuator_pole + self.extra_dead_time

    def brake_force(self, direction: float) -> float:
        """Magnitude of the brake at the cart against motion in ``direction`` (sign of x_dot) [N]:
        ``max_brake_force``, at most what the amplifier delivers (G times its limit, Appendix C)."""
        p = self.params
        actuator = -p.force_min if direction > 0.0 else p.force_max
        return min(self.max_brake_force, self.gain * actuator)

    def set_actuator(self, gain: float, disturbance: float = 0.0,
                     dead_time: float | None = 0.0) -> None:
        """The plant estimate's actuator gain G, unmodelled force D on the cart [N] and the
        actuator's dead time its prediction leaves out [s] (None: not measured yet, the
        prior ``actuator_dead_time`` stands).

        The brake is what the amplifier can deliver at the cart (G times its
        limits); a force D that pushes the cart on in its direction of motion
        shortens the deceleration (one that helps is not counted). A brake
        commanded now acts only after the dead time: the cart runs on meanwhile.
        """
        extra = self.actuator_dead_time if dead_time is None else dead_time
        if gain == self.gain and disturbance == self.disturbance \
                and extra == self.extra_dead_time:
            return
        if not (math.isfinite(gain) and gain > 0.0 and math.isfinite(disturbance)
                and math.isfinite(extra) and extra >= 0.0):
            raise ValueError(f'gain must be > 0, disturbance finite and dead time >= 0, got '
                             f'{gain!r}, {disturbance!r}, {dead_time!r}')
        self.extra_dead_time = float(extra)
        self._dead_time = self.dead_time
        self.gain = float(gain)
        self.disturbance = min(max(float(disturbance), -DISTURBANCE_MAX), DISTURBANCE_MAX)
        self._brake_pos = self.brake_force(1.0)
        self._brake_neg = self.brake_force(-1.0)

    def deceleration(self, direction: float, theta_dot, fmax=max):
        """a_b, a conservative braking deceleration [m/s^2] (module docstring).

        ``fmax`` is the maximum of two numbers: ``max`` for floats, ``casadi.fmax``
        for a symbolic ``theta_dot`` (the push bound's envelope,
        :mod:`cartpole_control.push_recovery`)."""
        p = self.params
        pendulum_pull = p.m_p * (p.l * theta_dot * theta_dot + p.g)
        brake = self._brake_pos if direction > 0.0 else self._brake_neg  # brake_force(direction)
        carried = max(self.disturbance * direction, 0.0)  # D pushing on in the motion's direction
        return fmax(brake + self._friction - pendulum_pull - carried,
                    self._min_deceleration) / self._mass

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

    def braked_stop(self, x: float, theta: float, x_dot: float, theta_dot: float) -> float:
        """Where the cart comes to rest under the guard's brake from this state [m]: the model
        (4.18) with the pendulum, the friction, the brake the amplifier delivers (G) and the
        disturbance D, the brake held over each sample as :meth:`command` applies it.

        The envelope (:meth:`stopping_position`) bounds this from the safe side for
        every cycle's decision; this is the expected stop, simulated once at a trip.
        """
        p = self.params
        acc = self._acc
        if acc is None:
            acc = self._acc = acceleration_function(p)
        h = p.sample_time
        direction = math.copysign(1.0, x_dot)
        brake = self._brake_pos if direction > 0.0 else self._brake_neg
        th, w = theta, theta_dot
        for _ in range(int(round(3.0 / h))):
            if x_dot * direction <= self.rest_speed:
                break
            force = -direction * min(brake, self._mass * abs(x_dot) / h) + self.disturbance
            a1, b1 = acc(x, th, x_dot, w, force)
            x_m, th_m = x + 0.5 * h * x_dot, th + 0.5 * h * w
            v_m, w_m = x_dot + 0.5 * h * a1, w + 0.5 * h * b1
            a2, b2 = acc(x_m, th_m, v_m, w_m, force)
            x, th, x_dot, w = x + h * v_m, th + h * w_m, x_dot + h * a2, w + h * b2
        return x

    def passed_range(self, x: float, x_dot: float, theta_dot: float, low: float, high: float,
                     theta: float = 0.0) -> tuple[float, float]:
        """The forces in ``[low, high]`` (at the cart [N]) that :meth:`command` passes
        unchanged from this state, as ``(lowest, highest)``; the guard's status is kept.

        The stopping position grows with the force, so what the margin, the limiter and
        the rule at rest leave is an interval; an end the guard bends is found by
        bisection. A law that plans its forces (``mpc``) bounds its first move by it, so
        that the force its plan predicts is the one the cart gets. Braking or stopped:
        the guard overrides every law, ``[low, high]``.
        """
        status, predicted_stop = self.status, self.predicted_stop
        if status == BRAKING or status == STOPPED:
            return low, high
        try:
            ends = [self._passed_end(x, x_dot, theta_dot, theta, end, other)
                    for end, other in ((low, high), (high, low))]
        finally:
            self.status, self.predicted_stop = status, predicted_stop
        lowest, highest = ends
        if lowest > highest:  # both ends bent past each other: the one force left
            lowest = highest = 0.5 * (lowest + highest)
        return lowest, highest

    def _passed_end(self, x: float, x_dot: float, theta_dot: float, theta: float,
                    end: float, other: float) -> float:
        """The force nearest ``end``, towards ``other``, that :meth:`command` passes."""
        bent = self.command(x, x_dot, theta_dot, end, theta)[0]
        if bent == end:
            return end
        bent = min(max(bent, min(end, other)), max(end, other))
        if self.command(x, x_dot, theta_dot, bent, theta)[0] != bent:
            return bent  # the guard's own force (a brake): nothing between passes
        beyond = bent + 1e-6 * (end - bent)
        if self.command(x, x_dot, theta_dot, beyond, theta)[0] != beyond:
            return bent  # the limiter's force: the end already
        # At rest a push in is withheld whole (no limited force): the end between
        passed, refused = bent, end
        for _ in range(PASSED_ITERATIONS):
            middle = 0.5 * (passed + refused)
            if self.command(x, x_dot, theta_dot, middle, theta)[0] == middle:
                passed = middle
            else:
                refused = middle
        return passed

    # -- one cycle --------------------------------------------------------------------
    def check(self, x: float, x_dot: float, theta_dot: float, force: float) -> GuardAction:
        """Pass, withhold or override ``force`` for the state (x, x_dot, theta_dot)."""
        force, tripped = self.command(x, x_dot, theta_dot, force)
        return GuardAction(force, self.status, tripped)

    def command(self, x: float, x_dot: float, theta_dot: float,
                force: float, theta: float = 0.0) -> tuple[float, bool]:
        """:meth:`check` as ``(force, tripped)``, the status left in :attr:`status`.

        The manager's per-cycle call (no GuardAction to build).
        """
        status = self.status
        if status == STOPPED:
            return self._hold(x, self._faster(x_dot)), False
        if status == BRAKING:
            return self._brake(self._faster(x_dot)), False
        speed = abs(x_dot)
        at_rest = speed <= self.rest_speed or speed <= self.creep_speed and self._in_margin(x)
        limited = False
        stop = self.stopping_position(x, x_dot, theta_dot, force)
        if self.limit:
            reserve = self.reserve(x_dot)
            low, high = self.margin + reserve, self._high - reserve
            right = stop > high and stop > x
            if right or stop < low and stop < x:
                if at_rest:  # no push further in (a full one would start a brake chatter)
                    force = min(force, 0.0) if right else max(force, 0.0)
                else:
                    force = self._limited_force(x, x_dot, theta_dot, force, right,
                                                high if right else low)
                stop = self.stopping_position(x, x_dot, theta_dot, force)
                limited = True
        towards_right = stop > self._high and stop > x
        towards_left = stop < self.margin and stop < x
        if not (towards_right or towards_left):
            force = self._margin_zone(x, force)
            if limited:
                self.status = LIMITED
            return force, False
        if at_rest:
            # At rest near a stop: never push further in, but allow pushing out.
            self.status = LIMITED
            return (min(force, 0.0) if towards_right else max(force, 0.0)), False
        self.status = BRAKING
        brake = self._brake(self._faster(x_dot))
        self.predicted_stop = self.braked_stop(x, theta, x_dot, theta_dot)
        return brake, True

    def reserve(self, x_dot: float) -> float:
        """The limiter's reserve [m] for a cart at ``x_dot``: ``limit_reserve``; while
        :attr:`balancing`, ``|x_dot| reserve_time``, at most ``limit_reserve``. The reserve
        is for what the envelope does not model, a longer dead time above all, which moves
        the stop of a cart at speed v by v times that time: a cart at rest needs none (its
        envelope counts its own dead time), and any reserve at rest held a balancing cart on
        the boundary with its pendulum falling towards the stop (at rest there every push
        towards that stop is withheld)."""
        full = self.limit_reserve
        if not self.balancing or self.reserve_time <= 0.0:
            return full
        return min(full, abs(x_dot) * self.reserve_time)

    def _in_margin(self, x: float) -> bool:
        """x inside ``[0, margin)`` or ``(travel - margin, travel]`` (the estimate may be past them)."""
        return x < self.margin or x > self._high

    def _margin_zone(self, x: float, force: float) -> float:
        """Inside a margin, never push towards that stop (whatever the velocity estimate says).

        A cart resting at the left stop after reset, with a noisy velocity
        estimate, may look as moving away from the stop; a push towards it is
        then no braking and would press the cart into it. Inside
        ``[0, margin)`` (or ``(travel - margin, travel]``) such a push is
        withheld, status ``limited``; pushing out is always allowed.
        """
        if force < 0.0 and x < self.margin or force > 0.0 and x > self._high:
            self.status = LIMITED
            return 0.0
        self.status = ARMED
        return force

    def _limited_force(self, x: float, x_dot: float, theta_dot: float, force: float,
                       towards_right: bool, boundary: float) -> float:
        """The force nearest ``force`` whose stopping position stays inside ``boundary``.

        Towards the right stop the admissible forces are those with
        ``stop(F) <= boundary``: the largest is sought in ``[-F_b, F]``;
        towards the left the smallest with ``stop(F) >= boundary`` in
        ``[F, F_b]``. If even the full brake F_b does not keep the stop inside,
        the full brake (or a stronger command against the motion).
        """
        if towards_right:
            safe = -self._brake_pos
            if safe >= force or self.stopping_position(x, x_dot, theta_dot, safe) > boundary:
                return min(force, safe)
            inside = lambda f: self.stopping_position(x, x_dot, theta_dot, f) <= boundary  # noqa: E731
        else:
            safe = self._brake_neg
            if safe <= force or self.stopping_position(x, x_dot, theta_dot, safe) < boundary:
                return max(force, safe)
            inside = lambda f: self.stopping_position(x, x_dot, theta_dot, f) >= boundary  # noqa: E731
        unsafe = force
        for _ in range(LIMIT_ITERATIONS):
            middle = 0.5 * (safe + unsafe)
            if inside(middle):
                safe = middle
            else:
                unsafe = middle
        return safe

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

    def _faster(self, x_dot: float) -> float:
        """``x_dot`` or :attr:`measured_x_dot`, whichever is faster."""
        measured = self.measured_x_dot
        return x_dot if measured is None or abs(x_dot) >= abs(measured) else measured

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


class GuardView:
    """The manager's rail guard as a law sees it (:attr:`.ControlContext.rail_guard`): the
    force it passes at a state. The manager puts its current guard behind it (a change of
    the ``rail.*`` parameters builds a new one); without one every force passes."""

    def __init__(self, guard: RailGuard | None = None) -> None:
        self.guard = guard

    def passed_range(self, x: float, x_dot: float, theta_dot: float, low: float, high: float,
                     theta: float = 0.0) -> tuple[float, float]:
        """:meth:`RailGuard.passed_range` of the current guard."""
        guard = self.guard
        if guard is None:
            return low, high
        return guard.passed_range(x, x_dot, theta_dot, low, high, theta)
