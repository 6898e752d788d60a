"""The simulated rig around the model: actuator, end stops, encoders, sampling.

Signal path (Figure 2.2, section 4.5): a force command F* [N] is held over each sample
period (zero-order hold), turned into a current reference i* = F* / (k_t / r), passed
through the current loop H(s) = b / (s + a) (4.4) with the amplifier's saturation
(+11 A / -12 A, Appendix C), and applied to the cart as F = (k_t / r) i (2.1). Two stiff
spring-damper end stops hold the cart in its travel (section 4.5): resting against one is
no crash, an :class:`Impact` is. The encoders count quadrature ticks (2.3)/(2.4) in 16-bit
counters that wrap (section 2.3). The mechanics (4.18) are integrated with fixed-step RK4
at ``integration_step`` (1 ms); the current loop, too fast for RK4 at that step, exactly.

The scenario's disturbances (:mod:`cartpole_sim.scenario`) act here too: :meth:`Plant.step`
splits a hold where a delayed command arrives or a push starts or ends, and
:meth:`Plant.sample_lost` loses samples; with none on, a step costs nothing more.
Deterministic: the same parameters, scenario (seed included) and inputs give the same
trajectory bit for bit. Each part with its numbers: (docs/simulator.md, "The model").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .disturbance import STREAM_DROP, STREAM_FORCE_NOISE, CommandDelayLine, DisturbedHold, \
    RandomStream
from cartpole_core.model import CartPoleParameters, acceleration_function, accelerations, wrap_counter
from .scenario import Push, Scenario, parse_push  # noqa: F401 (re-exported: the plant's scenario)

END_STOP_TOLERANCE = 1.0e-6
"""[m] Penetration past an end stop that counts as contact: 1 um, 1 N of stop
force at the stiffness 1e6 N/m, far below one cart encoder tick (88 um). A
cart resting at the left stop after reset sits at x = 0 up to round-off
(e.g. -1.7e-22 m); a sign test on that float is not a contact."""
IMPACT_SPEED = 0.02
"""[m/s] A cart arriving at a stop faster than this hits it (an :class:`Impact`).

Above one cart encoder tick per sample (88 um / 5 ms = 17.6 mm/s: a speed
the loop can see) and above what noise alone gives a resting cart: one 4-sigma
sample of 3 N force noise moves the lightest cart of the combined table
(3.8 kg) at 16 mm/s. Resting contacts arrive at a few mm/s. At 20 mm/s the
stop (1e6 N/m, 1e3 N s/m) already peaks near 60 N on the cart."""
IMPACT_PRESS_FORCE = 5.0
"""[N] Our force (the amplifier's) pressing the cart into a stop beyond this is
an :class:`Impact`. Resting needs none; a controller at rest may command its
friction feedforward (6.12), up to c_c,R = 3.4 N, into the stop from the sign
of a noisy velocity, and 1.3 x that (the combined table's largest gain error)
is 4.4 N. More than 5 N is our code driving the cart into the stop."""


@dataclass(frozen=True)
class Impact:
    """The cart hit an end stop: it arrived faster than :data:`IMPACT_SPEED`
    (``kind`` ``arrival``) or our force pressed it in beyond
    :data:`IMPACT_PRESS_FORCE` (``press``). One per contact with the stop."""

    t: float
    """When [s]: the integration step where it happened."""
    side: str
    """``left`` or ``right``."""
    kind: str
    """``arrival`` or ``press``."""
    speed: float
    """Speed into the stop when the cart reached it [m/s] (>= 0)."""
    force: float
    """Our force into the stop at the step [N] (positive into the stop)."""


@dataclass(frozen=True)
class Measurement:
    """One encoder sample, as the decoders see it."""

    t: float
    """Sample time [s] since the plant's reset."""
    cart_ticks: int
    """Raw 16-bit signed cart counter."""
    pendulum_ticks: int
    """Raw 16-bit signed pendulum counter."""
    x: float
    """Cart position [m] from the unwrapped count."""
    theta: float
    """Pendulum angle [rad] from the unwrapped count, pi hanging after reset."""


def _rk4_stage(acc, stop, travel: float, force: float, x: float, th: float, v: float,
               w: float, k: float, dx: float, dth: float, dv: float,
               dw: float) -> tuple[float, float, float, float]:
    """One later RK4 stage of (4.18) with end stops: the state ``s + k d`` from the step's
    start ``s = (x, th, v, w)`` along the previous stage's derivative ``d``, and the
    accelerations there (the end-stop force only outside the travel).

    Returns that stage's velocities and accelerations (its positions are not needed again).
    """
    xs = x + k * dx
    vs = v + k * dv
    ws = w + k * dw
    a, b = acc(xs, th + k * dth, vs, ws, force if 0.0 <= xs <= travel else force + stop(xs, vs))
    return vs, ws, a, b


@dataclass
class Plant(DisturbedHold):
    """The simulated rig: call :meth:`step` with a force command, read :meth:`measure`.

    ``params`` are the nominal parameters; the scenario's tip mass and
    friction scale make the true ones (:attr:`true_params`).

    Why one class of about 250 lines: the integration (RK4, the end-stop contact),
    the held and delayed command and the encoder read-out share one true state; the
    scenario's random streams are :mod:`cartpole_sim.disturbance`.
    """

    params: CartPoleParameters = field(default_factory=CartPoleParameters)
    scenario: Scenario = field(default_factory=Scenario)
    integration_step: float = 0.001

    def __post_init__(self) -> None:
        if not (0.0 < self.integration_step <= self.params.sample_time):
            raise ValueError('integration_step must be in (0, sample_time]')
        self.true_params = self.scenario.plant_parameters(self.params)
        self._acc = acceleration_function(self.true_params)
        self._travel = self.true_params.travel
        p, tp = self.params, self.true_params
        # Per-step constants, computed once with the very expressions step()
        # and measure() used to evaluate each time (same numbers to the bit).
        self._cart_resolution = p.cart_resolution
        self._pendulum_resolution = p.pendulum_resolution
        self._current_gain = tp.actuator_gain / tp.actuator_pole
        sc = self.scenario
        if sc.actuator_gain != 1.0:  # amplifier gain error: G times the commanded current
            self._current_gain *= sc.actuator_gain
        self._default_substeps = self._substeps(p.sample_time)
        self._disturbed = sc.disturbs_the_hold
        self._period_ns = int(round(p.sample_time * 1e9))
        self._hold_factors: dict[int, tuple] = {}
        self._pushes = [(int(round(q.t * 1e9)), int(round((q.t + q.width) * 1e9)),
                         q.target, float(q.amplitude)) for q in sc.pushes]
        self._torque_acc: dict[float, object] = {}
        self.reset()

    # -- state -------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the scenario's initial state; encoders reset, noise re-seeded."""
        self.t = 0.0
        self.state = list(self.scenario.initial_state())
        self.current = 0.0
        self.force_command = 0.0
        self.end_stop_contact = False
        """Latched: the cart hit a stop (an :class:`Impact`); resting against one is not."""
        self.impacts: list[Impact] = []
        """Every impact on a stop since the reset, in time order."""
        self._in_stop = False  # past END_STOP_TOLERANCE at the end of the last RK4 step
        self._v_in = self.state[2]  # cart velocity at the last step start inside the travel
        self._contact_counted = False  # this contact with a stop is an impact already
        self.contact_penetration = 0.0
        """Deepest penetration past a stop during the last step [m]: positive at
        the left stop, negative at the right one, 0.0 within the tolerance."""
        sc = self.scenario
        self._rng = np.random.default_rng(sc.seed)
        self.lag_current = 0.0
        """State of the amplifier's extra lag (``actuator_tau``) [A]."""
        self.lost_samples = 0
        """Samples lost on the way to the host since the reset (:meth:`sample_lost`)."""
        self._delay_line = CommandDelayLine(sc.delay, sc.jitter, sc.seed)
        self._applied: list[tuple[float, float]] = []
        self._drop_draws = RandomStream(sc.seed, STREAM_DROP, 'uniform') if sc.drop else None
        self._force_noise_draws = (RandomStream(sc.seed, STREAM_FORCE_NOISE, 'normal')
                                   if sc.force_noise else None)
        # Encoders are zeroed at the left stop and with the pendulum at
        # pi + encoder_offset (Appendix H).
        self._theta_at_reset = math.pi + self.scenario.encoder_offset

    @property
    def force(self) -> float:
        """The force the actuator currently applies to the cart [N]."""
        return self.current * self.true_params.force_per_ampere

    def in_end_stop(self) -> bool:
        """The cart is pressed into a stop by more than :data:`END_STOP_TOLERANCE`."""
        x = self.state[0]
        return x < -END_STOP_TOLERANCE or x > self.true_params.travel + END_STOP_TOLERANCE

    @property
    def end_stop_force(self) -> float:
        """The stops' spring force on the cart at the deepest point of the last step [N].

        Positive from the left stop (pushing right), negative from the right
        one; exactly 0.0 unless the penetration exceeded :data:`END_STOP_TOLERANCE`.
        """
        return self.true_params.end_stop_stiffness * self.contact_penetration

    # -- actuator (4.4) and saturation (Appendix C) -------------------------------
    def _current_target(self, force_command: float) -> float:
        p = self.true_params
        i_ref = force_command / p.force_per_ampere
        i_ss = self._current_gain * i_ref  # p.actuator_gain / p.actuator_pole * i_ref
        return min(max(i_ss, p.current_min), p.current_max)

    def _substeps(self, duration: float) -> tuple[int, float, float, float]:
        """(n, h, decay, mean_factor) of a hold of ``duration``: n RK4 steps of h,
        and the current loop's exact factors over one step (see :meth:`step`)."""
        n = max(1, int(round(duration / self.integration_step)))
        h = duration / n
        pole = self.true_params.actuator_pole
        decay = math.exp(-pole * h)
        # Mean of i(t) = i_target + (i0 - i_target) e^{-a t} over one step.
        mean_factor = (1.0 - decay) / (pole * h)
        return n, h, decay, mean_factor

    # -- integration ----------------------------------------------------------------
    def _end_stop_force(self, x: float, x_dot: float) -> float:
        p = self.true_params
        if x < 0.0:
            return max(0.0, -p.end_stop_stiffness * x - p.end_stop_damping * x_dot)
        if x > p.travel:
            return min(0.0, -p.end_stop_stiffness * (x - p.travel) - p.end_stop_damping * x_dot)
        return 0.0

    def _derivative(self, s: list[float], force: float) -> tuple[float, float, float, float]:
        x, theta, x_dot, theta_dot = s
        total = force + self._end_stop_force(x, x_dot)
        x_ddot, theta_ddot = accelerations(x, theta, x_dot, theta_dot, total, self.true_params)
        return x_dot, theta_dot, x_ddot, theta_ddot

    def _rk4(self, h: float, force: float) -> None:
        """One RK4 step of (4.18) with end stops on :attr:`state` (see :meth:`_rk4_steps`)."""
        x, th, v, w, _ = self._rk4_steps(*self.state, h, (force,))
        self.state = [x, th, v, w]

    def _rk4_steps(self, x: float, th: float, v: float, w: float, h: float,
                   forces, acc=None, t0: float | None = None,
                   extra: float = 0.0) -> tuple[float, float, float, float, bool]:
        """RK4 steps of length h of (4.18) with end stops, one per force in ``forces``.

        ``acc`` replaces the plant's acceleration function (a push on the
        pendulum adds its torque, :meth:`_acc_with_torque`). ``t0`` (default
        :attr:`t`) is the time of the first step's start and ``extra`` the part
        of each force that is not ours (force noise, a push): a step past a
        stop is judged by :meth:`_at_stop` (an impact or resting).

        Returns the final state and the deepest penetration past a stop after
        any of the steps (positive at the left stop, negative at the right one,
        0.0 if none went past :data:`END_STOP_TOLERANCE`; see :meth:`in_end_stop`). The same sums as
        :meth:`_derivative`, with local names instead of state lists: this is the
        inner loop of every offline run (faster in CPython than calling
        :meth:`_derivative`); :meth:`_derivative` is the readable
        reference and a test checks the two agree to the last bit. The three
        later stages are one :func:`_rk4_stage` each.
        """
        if acc is None:
            acc = self._acc
        travel = self._travel
        stop = self._end_stop_force
        hh = 0.5 * h
        h6 = h / 6.0
        deepest = 0.0
        in_stop, v_in = self._in_stop, self._v_in
        for i, force in enumerate(forces):
            # The end-stop force is zero inside the travel; skip the call there.
            if 0.0 <= x <= travel:
                v_in = v  # the speed at which a cart reaching a stop arrives
                a1, b1 = acc(x, th, v, w, force)
            else:
                a1, b1 = acc(x, th, v, w, force + stop(x, v))
            v2, w2, a2, b2 = _rk4_stage(acc, stop, travel, force, x, th, v, w, hh, v, w, a1, b1)
            v3, w3, a3, b3 = _rk4_stage(acc, stop, travel, force, x, th, v, w, hh, v2, w2, a2, b2)
            v4, w4, a4, b4 = _rk4_stage(acc, stop, travel, force, x, th, v, w, h, v3, w3, a3, b3)
            x, th, v, w = (x + h6 * (v + 2.0 * v2 + 2.0 * v3 + v4),
                           th + h6 * (w + 2.0 * w2 + 2.0 * w3 + w4),
                           v + h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
                           w + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4))
            if x < -END_STOP_TOLERANCE:
                if -x > abs(deepest):
                    deepest = -x
                self._at_stop(self.t if t0 is None else t0, i, h, 'left', in_stop, -v_in,
                              extra - force)
                in_stop = True
            elif x > travel + END_STOP_TOLERANCE:
                if x - travel > abs(deepest):
                    deepest = travel - x
                self._at_stop(self.t if t0 is None else t0, i, h, 'right', in_stop, v_in,
                              force - extra)
                in_stop = True
            else:
                in_stop = False
        self._in_stop, self._v_in = in_stop, v_in
        return x, th, v, w, deepest

    def _at_stop(self, t0: float, i: int, h: float, side: str, was_in: bool, speed: float,
                 press: float) -> None:
        """Step ``i`` (of length ``h`` from ``t0``) ended past the ``side`` stop: an impact?

        ``speed`` is the velocity into the stop at the start of the last step
        that began inside the travel (the arrival speed if ``was_in`` is False,
        a new contact), ``press`` our force into the stop. A contact is one
        impact at most; a bounce back into the stop is a new contact.
        """
        if not was_in:
            self._contact_counted = False
            if speed > IMPACT_SPEED:
                self._impact(t0 + (i + 1) * h, side, 'arrival', speed, press)
                return
        if press > IMPACT_PRESS_FORCE and not self._contact_counted:
            self._impact(t0 + (i + 1) * h, side, 'press', max(speed, 0.0) if not was_in else 0.0,
                         press)

    def _impact(self, t: float, side: str, kind: str, speed: float, press: float) -> None:
        self._contact_counted = True
        self.end_stop_contact = True
        self.impacts.append(Impact(round(t * 1e9) / 1e9, side, kind, speed, press))

    def step(self, force_command: float, duration: float | None = None,
             source: float | None = None) -> None:
        """Advance by ``duration`` (one sample period by default) holding ``force_command``.

        The command is held (ZOH); the current follows it through (4.4)
        exactly; the mechanics advance with RK4 at :attr:`integration_step`.
        With a scenario delay the command takes effect that much later (the
        previous one is held until then, :meth:`_step_disturbed`).

        ``source``, the stamp of the sample a new command was computed from,
        asks for the report of when it took effect (:meth:`applied_commands`);
        leave it None for a command held again (a lost sample).
        """
        if not math.isfinite(force_command):
            force_command = 0.0
        if self._disturbed:
            self._step_disturbed(force_command, duration, source)
            return
        if source is not None:
            self._applied.append((source, self.t))
        if duration is None:
            n, h, decay, mean_factor = self._default_substeps
        else:
            n, h, decay, mean_factor = self._substeps(duration)
        i_target = self._current_target(force_command)
        force_per_ampere = self.true_params.force_per_ampere
        self.force_command = force_command
        # The current loop over the n steps first (it does not depend on the
        # mechanics): the force of each step, the mean current times k_t / r.
        forces = []
        current = self.current
        for _ in range(n):
            forces.append((i_target + (current - i_target) * mean_factor) * force_per_ampere)
            current = i_target + (current - i_target) * decay
        x, th, v, w, deepest = self._rk4_steps(*self.state, h, forces)
        self.state = [x, th, v, w]
        self.current = current
        # Time in whole nanoseconds, like a ROS stamp: no drift from adding
        # h = 0.001 thousands of times (5.55 s stays 5.55, not 5.550000000000188).
        self.t = round((self.t + n * h) * 1e9) / 1e9
        self.contact_penetration = deepest

    def applied_commands(self) -> list[tuple[float, float]]:
        """``[(source, applied), ...]``: when each tagged command took effect [s], since the last call.

        The plant's report of the loop's latency (``applied - source``): with
        no delay a command acts from the start of its hold, with a scenario
        delay (and jitter) that much later.
        """
        out = self._applied
        arrived = self._delay_line.arrived
        if arrived:
            out.extend((source, arrival * 1e-9) for source, arrival in arrived)
            arrived.clear()
        self._applied = []
        return out

    def sample_lost(self) -> bool:
        """Whether the sample taken now is lost on its way to the host (scenario ``drop``).

        Call it once per sample (the closed loop, the simulator and the
        emulator do); it draws from its own seeded generator and counts
        :attr:`lost_samples`. Always False without ``drop``.
        """
        if self._drop_draws is None or self._drop_draws.next() >= self.scenario.drop:
            return False
        self.lost_samples += 1
        return True

    # -- encoders (2.3), (2.4) ----------------------------------------------------------
    def encoder_counts(self) -> tuple[int, int]:
        """The raw 16-bit counters (cart, pendulum) now, noise included if enabled."""
        cart, pend = self._continuous_counts()
        bits = self.params.counter_bits
        return wrap_counter(cart, bits), wrap_counter(pend, bits)

    def _continuous_counts(self) -> tuple[int, int]:
        """The quadrature counts (cart, pendulum) since the reset, before the counters wrap."""
        x = self.state[0]
        theta = self.state[1] - self._theta_at_reset
        if self.scenario.noise:
            x += self._rng.normal(0.0, self.scenario.noise_std_cart)
            theta += self._rng.normal(0.0, self.scenario.noise_std_pendulum)
        return (math.floor(x / self._cart_resolution + 0.5),
                math.floor(theta / self._pendulum_resolution + 0.5))

    def measure(self) -> Measurement:
        """Sample the encoders: raw counters and the positions they stand for.

        The positions are those of the continuous counts, which is what the
        host rebuilds from the wrapping counters (``cartpole_hw.protocol.
        CounterUnwrapper``, exact while a counter moves less than half its
        range between two samples; a test checks both agree).
        """
        cart, pend = self._continuous_counts()
        bits = self.params.counter_bits
        return Measurement(self.t, wrap_counter(cart, bits), wrap_counter(pend, bits),
                            cart * self._cart_resolution,
                            math.pi + pend * self._pendulum_resolution)

    def true_state(self) -> np.ndarray:
        return np.array(self.state)
