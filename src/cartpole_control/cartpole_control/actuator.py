"""The actuator the loop really has: its force gain and its extra dead time, estimated on line.

The controllers' model says the cart feels the commanded force F* from the
moment the plant reports it applied (:mod:`cartpole_control.latency`): F =
F* through the current loop (4.4), whose time constant (0.1 ms) is nothing at
5 ms. A real amplifier may give less (a gain error, a supply that sags: the
robustness grid's "actuator gain") or act later (a slower current loop, a
filter: "actuator lag"), and neither is something the plant can report: the
device only knows when it wrote the setpoint. Both show in how the cart moves.

The cart row of (4.17) is a momentum balance, dp/dt = F - B_c(x_dot) with
p = (m_c + m_p) x_dot - m_p l cos(theta) theta_dot; weighed over windows of
the encoders' samples it gives the gain by recursive least squares for each
candidate dead time.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.actuator``).

No ROS import.
"""
from __future__ import annotations

import math
from collections import deque

from cartpole_core.model import CartPoleParameters

from .position_window import PositionWindow

HALF_WINDOW = 20
"""T of the window, in samples (0.1 s at 5 ms)."""
EVERY = 5
"""A window every this many samples."""
DELAY_STEP = 0.005
"""[s] Spacing of the dead-time candidates."""
DELAY_MAX = 0.1
"""[s] The largest dead time considered."""
DELAY_DEADBAND_STEPS = 0.5
"""Candidate steps taken off the dead-time estimate before it is compensated
(:attr:`ActuatorEstimator.delay_compensation`)."""
FORGETTING = 0.998
"""Weight kept by the past per window (memory about 50 s of windows every 25 ms)."""
MIN_EXCITATION = 0.1
"""sum(Phi^2) [N^2 s^4] before the estimate is used: about thirty windows of a
10 N force (Phi of a 10 N force over T = 0.1 s is 0.1 N s^2)."""
PHI_MIN = 0.05
"""[N s^2] Windows whose commanded force averages less than about 5 N are left out:
there the cart's friction, known only roughly, is as large as the force."""
GAIN_MIN, GAIN_MAX = 0.4, 2.5
"""The gain estimate is held inside these bounds."""
GAIN_DEADBAND = 0.03
"""What the estimate cannot tell from the model's actuator: the friction, known only
roughly, biases it by a few per cent (x1.5 friction: 0.93-0.96). :meth:`ActuatorEstimator.
compensation` acts only on the part of the estimate beyond this band around 1."""


def _triangle_integral(a: float, b: float, half: float) -> float:
    """int_a^b (T - |s|) ds for ``-T <= a <= b <= T``."""
    return half * (b - a) - 0.5 * (b * abs(b) - a * abs(a))


class ActuatorEstimator:
    """Gain ``G`` and extra dead time ``d`` of the actuator, from the cart's motion; see the module docstring.

    Parameters
    ----------
    plant
        The nominal model: masses, length, cart friction (4.20)/(4.27).
    sample_time
        Ts [s] of the encoders' samples.
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float | None = None,
                 half_window: int = HALF_WINDOW, forgetting: float = FORGETTING,
                 min_excitation: float = MIN_EXCITATION) -> None:
        self.plant = plant
        self.sample_time = float(sample_time or plant.sample_time)
        self.window = PositionWindow(self.sample_time, half_window, EVERY)
        """The encoders' samples of the next window."""
        self.forgetting = float(forgetting)
        self.min_excitation = float(min_excitation)
        self._mass = plant.m_c + plant.m_p
        self._m_p_l = plant.m_p * plant.l
        self.delays = tuple(round(i * DELAY_STEP, 9)
                            for i in range(int(round(DELAY_MAX / DELAY_STEP)) + 1))
        self.reset()

    def reset(self) -> None:
        """Back to the nominal actuator, no data."""
        n = len(self.delays)
        self._s_py = [0.0] * n
        self._s_pp = [0.0] * n
        self._s_yy = 0.0
        self.gain = 1.0
        """The estimated gain G (1 until enough excitation)."""
        self.delay = 0.0
        """The estimated extra dead time d [s] (0 until enough excitation)."""
        self.windows = 0
        self.window.clear()
        horizon = 2 * self.window.half_window + 2 + int(math.ceil(DELAY_MAX / self.sample_time)) + 8
        self._applied: deque[tuple[float, float]] = deque(maxlen=4 * horizon)

    @property
    def compensation(self) -> float:
        """The gain the command is divided by: the estimate, less :data:`GAIN_DEADBAND` towards 1.

        Continuous in the estimate; exactly 1 (the model's actuator, the thesis's
        loop) while the estimate is within the band: a nominal rig's commands are
        not rescaled by an estimate's noise.
        """
        excess = self.gain - 1.0
        if abs(excess) <= GAIN_DEADBAND:
            return 1.0
        return self.gain - GAIN_DEADBAND if excess > 0.0 else self.gain + GAIN_DEADBAND

    @property
    def delay_compensation(self) -> float:
        """The dead time added to the prediction horizon [s]: the estimate less half a candidate step.

        The commands are held over a sample, and a zero-order hold acts, on
        average, half a sample late; with candidates a sample apart a nominal
        actuator comes out at 0 or 5 ms by the noise of the windows. Half a
        step off keeps the half sample the hold really costs: offline, default
        pair, 8 seeds: nominal theta amplitude mean 0.254 deg (0.296 with the
        whole estimate, 0.282 with a whole step off), and the pendulum 20-25 %
        shorter than the model, which needs it, balanced in 2 of 3 seeds (0 of
        3 with a whole step off). A 60 ms lag (estimate 50 ms) is compensated
        over 47.5 ms.
        """
        return max(self.delay - DELAY_DEADBAND_STEPS * DELAY_STEP, 0.0)

    @property
    def ready(self) -> bool:
        """Enough excitation for the estimate to be used."""
        best = self.delays.index(self.delay) if self.delay in self.delays else 0
        return self._s_pp[best] >= self.min_excitation

    def applied(self, t: float, force: float) -> None:
        """The force command ``force`` [N] took effect at ``t`` [s] (in order)."""
        applied = self._applied
        if applied and t < applied[-1][0]:
            applied.clear()  # time went back: a new run
        applied.append((t, force))

    def _force_integral(self, start: float, centre: float, half: float) -> float:
        """int_{-T}^{T} k(s) F*(centre + s - d) ds with ``start = centre - d - T``."""
        total = 0.0
        applied = self._applied
        end = start + 2.0 * half
        shift = start + half  # s = time - shift
        n = len(applied)
        # the last application at or before start
        i = n - 1
        while i > 0 and applied[i][0] > start:
            i -= 1
        if applied[i][0] > start:
            return math.nan  # the window reaches back before the first command known
        a = start
        force = applied[i][1]
        for j in range(i + 1, n):
            t_j = applied[j][0]
            if t_j >= end:
                break
            if t_j > a:
                total += force * _triangle_integral(a - shift, t_j - shift, half)
                a = t_j
            force = applied[j][1]
        total += force * _triangle_integral(a - shift, end - shift, half)
        return total

    def forget_samples(self) -> None:
        """Start the next window afresh (a plant reset moved the positions); the estimate stays."""
        self.window.clear()
        self._applied.clear()

    def update(self, t: float, x: float, theta: float) -> None:
        """Take the encoders' sample at ``t``: cart position [m], pendulum angle [rad]."""
        if self.window.push(t, x, theta) and self._applied:
            self._take_window()

    def _take_window(self) -> None:
        window = self.window
        m = window.half_window
        times, xs, ths = window.t, window.x, window.theta
        h = window.step
        half = m * h
        travel = self.plant.travel
        if min(xs) < 0.005 or max(xs) > travel - 0.005:
            return  # the end stops may push: not the actuator's force
        # The commanded force first: most windows of a balanced pendulum stop here, before
        # the positions' sums (the cost of an estimate in the 200 Hz loop).
        centre = times[m]
        phi_0 = self._force_integral(centre - half, centre, half)
        if not abs(phi_0) >= PHI_MIN:  # also NaN: not enough commands known
            return
        p = self.plant
        mass, m_p_l = self._mass, self._m_p_l
        cos, tanh = math.cos, math.tanh
        y = 0.0
        for i in range(2 * m):
            slope = 1.0 if i < m else -1.0
            dx = xs[i + 1] - xs[i]
            dth = ths[i + 1] - ths[i]
            y -= slope * (mass * dx - m_p_l * cos(0.5 * (ths[i] + ths[i + 1])) * dth)
            v = dx / h
            friction = ((p.c_c_right if v >= 0.0 else p.c_c_left)
                        * tanh(p.friction_steepness_cart * v) + p.v_c * v)
            y += (m - abs(i + 0.5 - m)) * h * friction * h
        phis = []
        for d in self.delays:
            phi = self._force_integral(centre - d - half, centre - d, half)
            if math.isnan(phi):
                return
            phis.append(phi)
        lam = self.forgetting
        self._s_yy = lam * self._s_yy + y * y
        s_py, s_pp = self._s_py, self._s_pp
        best, best_residual = 0, math.inf
        for k, phi in enumerate(phis):
            s_py[k] = lam * s_py[k] + phi * y
            s_pp[k] = lam * s_pp[k] + phi * phi
            if s_pp[k] > 0.0:
                residual = self._s_yy - s_py[k] * s_py[k] / s_pp[k]
                if residual < best_residual:
                    best, best_residual = k, residual
        self.windows += 1
        if s_pp[best] >= self.min_excitation:
            self.delay = self.delays[best]
            self.gain = min(max(s_py[best] / s_pp[best], GAIN_MIN), GAIN_MAX)
