"""The catch the stabiliser can hold: its region of attraction on the estimated plant (beyond (6.4)).

The thesis's catch trigger (6.4) (:mod:`cartpole_control.catch`), a fixed window, stays the
outer gate; inside it the catch waits until the state is in the region of attraction of the
stabiliser on the plant the loop has measured (:mod:`cartpole_control.plant_estimate`). The
closed loop of that plant's LQR (Riccati equation (8.18)), under the force the amplifier can
deliver (G times its limits, less the friction feedforward's share), held over each sample
and started one sample late, is simulated with the nonlinear model (4.18); the catch is taken
if it settles upright with the cart on the rail. A level set of ``V = x' P x`` certifies a
region hundreds of times smaller than what the loop holds, so the simulation decides.
Hysteresis: the fall detector hands back only beyond ``fall.angle_deg``, and every fall makes
the next catch wait for a region held with a tighter force budget.
Design and figures: docs/controller_manager.md ("The catch the stabiliser can hold"). No ROS.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.linalg

from cartpole_core.model import CartPoleParameters, acceleration_function, linearise_upright

DEFAULT_Q = (10.0, 10000.0, 10.0, 1.0, 400.0)
"""The state weights of the LQR whose region decides, the fifth on the cart error's integral
(LQI): the ``lqg`` plugin's robust gain, the one that acts at a catch
(:data:`cartpole_control.controllers.lqg.ROBUST_GAIN`)."""
DEFAULT_R = 0.01
HORIZON = 1.2
"""[s] How long the simulated catch runs."""
STEP = 0.005
"""[s] Its step: the control period, the force held over it (zero-order hold)."""
SETTLED_ANGLE = 0.1
"""[rad] At the end of the simulation the pendulum is within this of upright ..."""
SETTLED_RATE = 1.0
"""[rad/s] ... and turns slower than this."""
SETTLED_STEPS = 40
"""So many steps (0.2 s) settled with the force inside its limits end the simulation early."""
FEEDFORWARD_SHARE = 3.3
"""[N] Of the amplifier's force, what the friction feedforward (6.12) may take."""
FALL_TIGHTENING = 0.8
"""Each fall since the last reset multiplies the force budget the region is computed
with by this (at least :data:`MIN_BUDGET` of it)."""
MIN_BUDGET = 0.5
DEAD_TIME_MAX = 0.02
"""[s] The most of the guard's unmeasured dead time a simulated catch allows for: the
guard's prior bounds the lag (40 ms), and with that much the model's LQR holds nothing;
half of it is the lag expected of the combined benchmark's table (0-30 ms) and jitter."""


class CatchRegion:
    """Whether a catch from a state will be held, on an estimated plant; see the module docstring.

    Parameters
    ----------
    plant
        The nominal model (masses, length, friction, force limits, travel).
    sample_time
        The control period Ts [s].
    q, r
        LQR weights of (8.15) on ``[x - x*, theta_w, x_dot, theta_dot]`` and the force.
    rail_margin
        The cart must stay this far [m] from both end stops in the simulation.
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float,
                 q: Sequence[float] = DEFAULT_Q, r: float = DEFAULT_R,
                 rail_margin: float = 0.02) -> None:
        self.plant = plant
        self.sample_time = float(sample_time)
        self.q = tuple(float(v) for v in q)
        self.r = float(r)
        self.rail_margin = float(rail_margin)
        self.falls = 0
        """Falls since :meth:`reset`; each tightens the force budget."""
        self.checks = 0
        """Simulated catches since construction."""
        self._key: tuple[float, float] | None = None
        self.set_plant(plant.g / plant.l, 1.0)

    def reset(self) -> None:
        """A new run: the falls are forgotten."""
        self.falls = 0

    def fell(self) -> None:
        """The stabiliser lost the pendulum: the next catch must hold with less force."""
        self.falls += 1

    def set_plant(self, omega_sq: float, gain: float) -> None:
        """The plant estimate: the pendulum's omega_0^2 [1/s^2], the actuator gain G.

        The pendulum is the nominal one with the length that gives omega_0^2
        (``l = g / omega_0^2``); the LQR gain is solved again (8.17)/(8.18) when
        either changed by more than 1 %.
        """
        key = (omega_sq, gain)
        if self._key is not None and abs(omega_sq / self._key[0] - 1.0) <= 0.01 \
                and abs(gain / self._key[1] - 1.0) <= 0.01:
            return
        self._key = key
        p = self.plant
        length = p.g / omega_sq if omega_sq > 0.0 else p.l
        self.estimated = p.replace(l=length, c_c_right=0.0, c_c_left=0.0)
        """The plant the region is computed for (Coulomb friction left to the feedforward)."""
        a, b = linearise_upright(self.estimated)
        pm = scipy.linalg.solve_continuous_are(a, b, np.diag(self.q[:4]), np.array([[self.r]]))
        self.lyapunov = pm
        """P of (8.18) of the plain LQR: V = x' P x."""
        if len(self.q) > 4 and self.q[4] > 0.0:  # LQI: the Riccati equation of the augmented model
            n = a.shape[0]
            a_aug = np.zeros((n + 1, n + 1))
            a_aug[:n, :n] = a
            a_aug[n, 0] = 1.0
            b_aug = np.vstack([b, [[0.0]]])
            p_aug = scipy.linalg.solve_continuous_are(a_aug, b_aug, np.diag(self.q),
                                                      np.array([[self.r]]))
            k = (b_aug.T @ p_aug / self.r)[0]
        else:
            k = np.append((b.T @ pm / self.r)[0], 0.0)
        self.gain = tuple(float(v) for v in k)
        """[K, K_i] of (8.17) for the estimated plant (K_i on the integral of x - x*)."""
        self._acc = acceleration_function(self.estimated)
        self._low = gain * p.force_min + FEEDFORWARD_SHARE
        self._high = gain * p.force_max - FEEDFORWARD_SHARE

    def holds(self, x_err: float, x: float, theta_w: float, x_dot: float,
              theta_dot: float, dead_time: float = 0.0, rail_margin: float | None = None
              ) -> bool:
        """True if the LQR of the estimated plant, caught now, settles the pendulum on the rail.

        ``x_err = x - x*`` [m], ``x`` the cart position [m] (for the rail), the
        rest the (predicted) state. ``dead_time`` [s]: the actuator's dead time the
        prediction leaves out (each command acts that much later, rounded to samples);
        ``rail_margin`` [m]: keep the cart this far from the stops (default: the
        region's ``rail_margin``).
        """
        self.checks += 1
        budget = max(FALL_TIGHTENING ** self.falls, MIN_BUDGET)
        low, high = budget * self._low, budget * self._high
        k0, k1, k2, k3, k_i = self.gain
        integral = 0.0
        acc = self._acc
        h = STEP
        margin = self.rail_margin if rail_margin is None else rail_margin
        lo_x = margin - x + x_err  # rail bounds in x_err coordinates
        hi_x = self.plant.travel - margin - x + x_err
        e, th, v, w = x_err, theta_w, x_dot, theta_dot
        # the commands in flight: the first samples act with the command of before (0)
        in_flight = [0.0] * int(round(dead_time / h))
        force = 0.0  # the first sample: the command of before (one sample late)
        settled = 0
        for _ in range(int(round(HORIZON / h))):
            if in_flight:
                in_flight.append(force)
                force = in_flight.pop(0)
            # midpoint rule over the sample, the force held
            a1, b1 = acc(e, th, v, w, force)
            e_m, th_m = e + 0.5 * h * v, th + 0.5 * h * w
            v_m, w_m = v + 0.5 * h * a1, w + 0.5 * h * b1
            a2, b2 = acc(e_m, th_m, v_m, w_m, force)
            e, th, v, w = e + h * v_m, th + h * w_m, v + h * a2, w + h * b2
            if not (lo_x <= e <= hi_x) or abs(th) > 1.0:
                return False
            integral += h * e
            force = min(max(-(k0 * e + k1 * th + k2 * v + k3 * w + k_i * integral), low), high)
            if abs(th) <= SETTLED_ANGLE and abs(w) <= SETTLED_RATE and low < force < high:
                settled += 1
                if settled >= SETTLED_STEPS:
                    return True  # settled, the force no longer saturated: the linear loop holds
            else:
                settled = 0
        return abs(th) <= SETTLED_ANGLE and abs(w) <= SETTLED_RATE

    def admits(self, state, x_ref: float, omega_sq: float, gain: float, guard=None) -> bool:
        """:meth:`holds` for a :class:`~cartpole_control.controller.ControllerState` on the plant
        estimate (omega_0^2 [1/s^2], the actuator gain G), with the cart reference ``x_ref``.

        With the manager's :class:`~cartpole_control.rail_guard.RailGuard`, the catch must
        keep the cart inside its limiter's band (a cart held there cannot balance the
        pendulum) under the actuator's dead time its envelope assumes.
        """
        self.set_plant(omega_sq, gain)
        if guard is None:
            return self.holds(state.x - x_ref, state.x, state.theta_w, state.x_dot,
                              state.theta_dot)
        margin = guard.margin + (guard.limit_reserve if guard.limit else 0.0)
        return self.holds(state.x - x_ref, state.x, state.theta_w, state.x_dot, state.theta_dot,
                          min(guard.extra_dead_time, DEAD_TIME_MAX), margin)

    def value(self, x_err: float, theta_w: float, x_dot: float, theta_dot: float) -> float:
        """V = x' P x of the state (for the status and the docs' figures)."""
        z = np.array([x_err, theta_w, x_dot, theta_dot])
        return float(z @ self.lyapunov @ z)
