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
the encoders' samples it gives the gain, an unmodelled force and the scale of
the cart's friction (4.20) by recursive least squares for each candidate dead
time (friction changes sign with the velocity; a force does not).

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.actuator``).

No ROS import.
"""
from __future__ import annotations

import math
from collections import deque

from cartpole_core.model import CartPoleParameters

from .encoder_noise import EncoderNoise
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
RESIDUAL_FORGETTING = 0.998
"""Weight kept per window by the candidates' residual sums (memory about 50 s of windows
every 25 ms), which choose the dead time."""
PHI_MIN = 0.05
"""[N s^2] Windows whose commanded force averages less than about 5 N move only the
disturbance: there the cart's friction, known only roughly, is as large as the force."""
SPAN_MIN = 15.0
"""[N] Windows whose commanded force varies by less than this move only the disturbance:
a force held steady (the stabiliser leaning against a hand) cannot tell a weak amplifier
from a force on the cart; a varying one (a swing-up, a catch) can."""
GAIN_MIN, GAIN_MAX = 0.4, 2.5
"""The gain estimate is held inside these bounds."""
GAIN_DEADBAND = 0.03
"""What the estimate cannot tell from the model's actuator: the friction, known only
roughly, biases it by a few per cent. :meth:`ActuatorEstimator.compensation` acts only on
the part of the estimate beyond this band around 1."""
SWITCH_RATIO = 1.0
"""Another dead-time candidate is chosen when its residual sum is below this fraction of
the chosen one's: 1, the best at once (a hysteresis keeps a wrong early choice; the slew of
the gain handed out, :data:`OUTPUT_RATE`, already stops jumps)."""
OUTPUT_RATE = 0.02
"""Largest change per window of the gain handed out (:attr:`ActuatorEstimator.gain`)."""
DELAY_READY_WINDOWS = 10
"""Windows with a large varying command before the dead time is used (a quarter second of
a swing-up): the candidates' residuals part long before the gain is known to 4 %."""
GAIN_PRIOR_STD = 0.25
"""Prior standard deviation of G."""
PGG_MAX = GAIN_PRIOR_STD ** 2
"""G is never less certain than at the start (a reopened or cut step cannot make it wild)."""
GAIN_WALK_STD = 0.0005
"""Random walk of G per window: an amplifier drifts slowly (0.01 in 10 s of windows)."""
GAIN_READY_STD = 0.04
"""The estimate is used once the standard deviation of G is below this."""
GAIN_RATE = 0.02
"""Largest change of G per window while G's standard deviation is 0.1, in proportion to
it (at least :data:`GAIN_RATE_MIN`): a settled estimate moves slowly, so a burst of
unmodelled force the gate lets through cannot throw it."""
GAIN_RATE_MIN = 0.001
DISTURBANCE_PRIOR_STD = 2.0
"""[N] Prior standard deviation of the disturbance D."""
DISTURBANCE_WALK_STD = 0.5
"""[N] Random walk of D per window (3 N in a second): friction error, cable drag; a
sudden change (a hand, a push) passes the gate (:data:`GATE`)."""
DISTURBANCE_MAX = 40.0
"""[N] The disturbance estimate is held inside +-this."""
NOISE_STD = 0.004
"""[N s^2] Standard deviation of Y's error beyond the encoders' measured noise: the friction
model's error that a constant D does not take up (a 1 N error over the window is 0.01 N s^2)."""
NOISE_GAIN = 6.0
"""Var(Y) from the encoders' noise over (m_c + m_p)^2 sigma_x^2 + (m_p l)^2 sigma_theta^2: Y
is a second difference of the momentum at the window's ends and centre (1 + 4 + 1)."""
GATE = 4.0
"""An innovation beyond this many standard deviations is a change of the disturbance (a
push, a hand), not news of the gain: it moves D alone."""
GATE_PERSISTENCE = 4
"""So many gated windows in a row (0.1 s) with the disturbance moved each time: the model
itself is off (the gain changed); G's uncertainty grows by :data:`GAIN_REOPEN_STD`."""
GAIN_REOPEN_STD = 0.1
FRICTION_PRIOR_STD = 0.3
"""Prior standard deviation of the friction scale S (the cart's friction is S times the
model's (4.20); a rig's friction is known to a few tens of per cent)."""
FRICTION_WALK_STD = 0.0005
"""Random walk of S per window: friction drifts slowly (warming, wear)."""
FRICTION_SPEED_MIN = 0.05
"""[m/s] Samples slower than this (their velocity over five samples) tell nothing of S: the
encoders' noise decides the sign of their friction, and y shares that noise; their friction
is counted at the estimated S. Taken as news, or at the model's S = 1, they pulled S
towards 2.4 on the nominal plant, or from 1.5 towards 1, in minutes of balancing."""
FRICTION_MIN, FRICTION_MAX = 0.3, 3.0
"""The friction scale estimate is held inside these bounds."""
FRICTION_READY_STD = 0.1
"""The friction scale is used once its standard deviation is below this."""
FRICTION_DEADBAND = 0.1
"""What the estimate cannot tell from the model's friction; :meth:`ActuatorEstimator.friction_compensation`
acts only beyond this band around 1."""


def _triangle_integral(a: float, b: float, half: float) -> float:
    """int_a^b (T - |s|) ds for ``-T <= a <= b <= T``."""
    return half * (b - a) - 0.5 * (b * abs(b) - a * abs(a))


class ActuatorEstimator:
    """Gain ``G``, extra dead time ``d`` and disturbance ``D`` of the actuator's force; see the module docstring.

    Parameters
    ----------
    plant
        The nominal model: masses, length, cart friction (4.20)/(4.27).
    sample_time
        Ts [s] of the encoders' samples.
    half_window
        T of the window, in samples.
    """

    def __init__(self, plant: CartPoleParameters, sample_time: float | None = None,
                 half_window: int = HALF_WINDOW) -> None:
        self.plant = plant
        self.sample_time = float(sample_time or plant.sample_time)
        self.window = PositionWindow(self.sample_time, half_window, EVERY)
        """The encoders' samples of the next window."""
        self._mass = plant.m_c + plant.m_p
        self._m_p_l = plant.m_p * plant.l
        self.delays = tuple(round(i * DELAY_STEP, 9)
                            for i in range(int(round(DELAY_MAX / DELAY_STEP)) + 1))
        self.reset()

    def reset(self) -> None:
        """Back to the nominal actuator, no disturbance, no data."""
        n = len(self.delays)
        # Per dead-time candidate: the filter's mean (G, D, S) and covariance
        # (gg, gd, gs, dd, ds, ss).
        self._g = [1.0] * n
        self._d = [0.0] * n
        self._s = [1.0] * n
        self._pgg = [GAIN_PRIOR_STD ** 2] * n
        self._pgd = [0.0] * n
        self._pgs = [0.0] * n
        self._pdd = [DISTURBANCE_PRIOR_STD ** 2] * n
        self._pds = [0.0] * n
        self._pss = [FRICTION_PRIOR_STD ** 2] * n
        self._residual = [0.0] * n
        self._best = 0
        self.gain = 1.0
        """The estimated gain G (1 until :attr:`ready`)."""
        self.delay = 0.0
        """The estimated extra dead time d [s] (0 until :data:`DELAY_READY_WINDOWS`)."""
        self.disturbance = 0.0
        """The estimated unmodelled force D on the cart [N], positive to the right."""
        self.friction_scale = 1.0
        """The estimated scale S of the cart's friction (4.20) (1 until its standard
        deviation is below :data:`FRICTION_READY_STD`)."""
        self.windows = 0
        """Windows taken."""
        self.excited_windows = 0
        """Windows with a large varying command (the ones that tell the gain and dead time)."""
        self.gated = 0
        """Windows whose innovation, for the chosen dead time, was beyond :data:`GATE`."""
        self._gated_run = [0] * n
        self._due = False
        """The window is complete and not yet computed (:meth:`finish`)."""
        self.noise = EncoderNoise(self.sample_time)
        """The encoders' measured noise, which weighs each window's error (:data:`NOISE_GAIN`)."""
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
    def friction_compensation(self) -> float:
        """The scale of the friction feedforward (6.12): :attr:`friction_scale` less
        :data:`FRICTION_DEADBAND` towards 1, exactly 1 within the band."""
        excess = self.friction_scale - 1.0
        if abs(excess) <= FRICTION_DEADBAND:
            return 1.0
        return self.friction_scale - math.copysign(FRICTION_DEADBAND, excess)

    @property
    def delay_compensation(self) -> float:
        """The dead time added to the prediction horizon [s]: the estimate less half a candidate step.

        The commands are held over a sample, and a zero-order hold acts, on
        average, half a sample late; with candidates a sample apart a nominal
        actuator comes out at 0 or 5 ms by the noise of the windows. Half a
        step off keeps the half sample the hold really costs.
        """
        return max(self.delay - DELAY_DEADBAND_STEPS * DELAY_STEP, 0.0)

    @property
    def delay_known(self) -> bool:
        """The dead time is estimated (:data:`DELAY_READY_WINDOWS` excited windows taken)."""
        return self.excited_windows >= DELAY_READY_WINDOWS

    @property
    def gain_std(self) -> float:
        """The standard deviation of the gain estimate of the chosen dead time."""
        return math.sqrt(self._pgg[self._best])

    @property
    def ready(self) -> bool:
        """Enough excitation for the gain and dead time to be used."""
        return self._pgg[self._best] <= GAIN_READY_STD ** 2

    def applied(self, t: float, force: float) -> None:
        """The force command ``force`` [N] took effect at ``t`` [s] (in order)."""
        if self._due:
            self.finish()
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

    def _force_span(self, start: float, end: float) -> float:
        """max - min of the commands that acted in ``[start, end]`` [N]."""
        applied = self._applied
        low = high = None
        for i in range(len(applied) - 1, -1, -1):
            t, force = applied[i]
            if t < end:
                low = force if low is None else min(low, force)
                high = force if high is None else max(high, force)
            if t <= start:
                break
        return 0.0 if low is None else high - low

    def forget_samples(self) -> None:
        """Start the next window afresh (a plant reset moved the positions); the estimate stays."""
        if self._due:
            self.finish()
        self.window.clear()
        self.noise.clear()
        self._applied.clear()

    def update(self, t: float, x: float, theta: float) -> None:
        """Take the encoders' sample at ``t``: cart position [m], pendulum angle [rad].

        A window it completes is computed by :meth:`finish`: the controller manager calls
        it once the cycle's command is out (the window is the costliest part of a cycle);
        else the next sample or command taken does, first. Either way the window sees the
        same samples and commands, and its estimate serves from the next cycle on.
        """
        if self._due:
            self.finish()
        self.noise.update(t, x, theta)
        if self.window.push(t, x, theta) and self._applied:
            self._due = True

    def finish(self) -> None:
        """Compute the window the last sample completed, if any (:meth:`update`)."""
        if self._due:
            self._due = False
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
        centre = times[m]
        phi_0 = self._force_integral(centre - half, centre, half)
        if math.isnan(phi_0):
            return  # not enough commands known
        p = self.plant
        mass, m_p_l = self._mass, self._m_p_l
        cos, tanh = math.cos, math.tanh
        y = psi = slow = 0.0
        last = 2 * m
        for i in range(last):
            slope = 1.0 if i < m else -1.0
            dx = xs[i + 1] - xs[i]
            dth = ths[i + 1] - ths[i]
            y -= slope * (mass * dx - m_p_l * cos(0.5 * (ths[i] + ths[i + 1])) * dth)
            # the friction's velocity over five samples: a fifth of the noise of dx / h, and
            # little of the noise y has from this dx
            lo, hi = max(i - 2, 0), min(i + 3, last)
            v = (xs[hi] - xs[lo]) / ((hi - lo) * h)
            friction = ((p.c_c_right if v >= 0.0 else p.c_c_left)
                        * tanh(p.friction_steepness_cart * v) + p.v_c * v)
            weighed = (m - abs(i + 0.5 - m)) * h * friction * h
            if abs(v) >= FRICTION_SPEED_MIN:
                psi += weighed
            else:  # too slow to tell S from the encoders' noise: S as estimated, no news of it
                slow += weighed
        # y = G phi + D w - S (psi + slow) + e: the momentum gained, less the forces' integrals
        if abs(phi_0) < PHI_MIN or self._force_span(centre - half - DELAY_MAX,
                                                    centre + half) < SPAN_MIN:
            # A small or steady command (a balanced pendulum): news of D only. The dead time hardly
            # matters to it; the chosen candidate's integral stands for all (one integral
            # instead of one per candidate: the cost of a window in the 200 Hz loop).
            d = self.delays[self._best]
            phi = self._force_integral(centre - d - half, centre - d, half)
            if math.isnan(phi):
                return
            self._update(y, [phi] * len(self.delays), half * half, psi, slow, False)
            return
        phis = []
        for d in self.delays:
            phi = self._force_integral(centre - d - half, centre - d, half)
            if math.isnan(phi):
                return
            phis.append(phi)
        self._update(y, phis, half * half, psi, slow, True)

    def _update(self, y: float, phis: list[float], w: float, psi: float, slow: float,
                excited: bool) -> None:
        """One window into every candidate's Kalman filter of (G, D, S); choose the dead time.

        ``y = G phi_d + D w - S (psi + slow) + e`` with ``w = T^2`` (the
        triangle's integral), ``psi`` and ``slow`` the model friction's integral
        over the fast and the slow samples (only ``psi`` tells S) and ``e`` of
        standard deviation :data:`NOISE_STD`; G, D and S random walks. Unless ``excited``
        (a large, varying command) the window moves D and S alone; a gated
        innovation (a push) moves D alone.
        """
        var_x, var_theta = self.noise.variance
        r = NOISE_STD * NOISE_STD + NOISE_GAIN * (self._mass ** 2 * var_x
                                                  + self._m_p_l ** 2 * var_theta)
        q_g, q_d = GAIN_WALK_STD * GAIN_WALK_STD, DISTURBANCE_WALK_STD * DISTURBANCE_WALK_STD
        q_s = FRICTION_WALK_STD * FRICTION_WALK_STD
        lam = RESIDUAL_FORGETTING
        g_all, d_all, s_all = self._g, self._d, self._s
        pgg_all, pgd_all, pgs_all = self._pgg, self._pgd, self._pgs
        pdd_all, pds_all, pss_all = self._pdd, self._pds, self._pss
        res_all = self._residual
        runs = self._gated_run
        jumps = []
        for k, phi in enumerate(phis):
            g, d, f = g_all[k], d_all[k], s_all[k]
            pgg, pgd, pgs = pgg_all[k] + q_g, pgd_all[k], pgs_all[k]
            pdd, pds, pss = pdd_all[k] + q_d, pds_all[k], pss_all[k] + q_s
            nu = y - g * phi - d * w + f * (psi + slow)
            jump = False
            if excited:
                # P H^T with H = (phi, w, -psi)
                u_g = pgg * phi + pgd * w - pgs * psi
                u_d = pgd * phi + pdd * w - pds * psi
                u_s = pgs * phi + pds * w - pss * psi
                s = phi * u_g + w * u_d - psi * u_s + r
                z2 = nu * nu / s
                # every candidate's residual counts the same windows
                res_all[k] = lam * res_all[k] + min(z2, GATE * GATE)
            if excited and abs(phi) >= PHI_MIN:
                if runs[k] >= GATE_PERSISTENCE:
                    pgg = min(pgg + GAIN_REOPEN_STD * GAIN_REOPEN_STD, PGG_MAX)
                    runs[k] = 0
                    u_g = pgg * phi + pgd * w - pgs * psi
                    s = phi * u_g + w * u_d - psi * u_s + r
                    z2 = nu * nu / s
                if z2 <= GATE * GATE:
                    runs[k] = 0
                    k_g, k_d, k_s = u_g / s, u_d / s, u_s / s
                    rate = max(GAIN_RATE * math.sqrt(pgg) / 0.1, GAIN_RATE_MIN)
                    step = min(max(k_g * nu, -rate), rate)
                    g = min(max(g + step, GAIN_MIN), GAIN_MAX)
                    d += k_d * nu
                    if step == k_g * nu:  # a cut G step leaves an innovation S must not take
                        f += k_s * nu
                    # P - K S K^T; a step cut short leaves G that much less certain
                    cut = k_g * nu - step
                    pgg = min(pgg - k_g * u_g + cut * cut, PGG_MAX)
                    pgd, pgs = pgd - k_g * u_d, pgs - k_g * u_s
                    pdd, pds, pss = pdd - k_d * u_d, pds - k_d * u_s, pss - k_s * u_s
                    g_all[k], d_all[k] = g, min(max(d, -DISTURBANCE_MAX), DISTURBANCE_MAX)
                    s_all[k] = min(max(f, FRICTION_MIN), FRICTION_MAX)
                    pgg_all[k], pgd_all[k], pgs_all[k] = pgg, pgd, pgs
                    pdd_all[k], pds_all[k], pss_all[k] = pdd, pds, pss
                    continue
                runs[k] += 1
                jump = True
            if jump:
                # A change of the disturbance (a push, a hand): D alone, as far as this window says.
                s_d = w * w * pdd + r
                k_d = pdd * w / s_d
                d += k_d * nu
                pgd *= 1.0 - k_d * w
                pds *= 1.0 - k_d * w
                pdd *= 1.0 - k_d * w
                jumps.append(k)
                pdd += nu * nu / (w * w)
            else:
                # A window without news of G: D and S, H = (0, w, -psi).
                u_g = pgd * w - pgs * psi
                u_d = pdd * w - pds * psi
                u_s = pds * w - pss * psi
                s = w * u_d - psi * u_s + r
                k_d, k_s = u_d / s, u_s / s
                d += k_d * nu
                f += k_s * nu
                pgd, pgs = pgd - k_d * u_g, pgs - k_s * u_g
                pdd, pds, pss = pdd - k_d * u_d, pds - k_d * u_s, pss - k_s * u_s
            d_all[k] = min(max(d, -DISTURBANCE_MAX), DISTURBANCE_MAX)
            s_all[k] = min(max(f, FRICTION_MIN), FRICTION_MAX)
            pgg_all[k], pgd_all[k], pgs_all[k] = pgg, pgd, pgs
            pdd_all[k], pds_all[k], pss_all[k] = pdd, pds, pss
        self.windows += 1
        if excited:
            best = min(range(len(phis)), key=res_all.__getitem__)
            if res_all[best] < SWITCH_RATIO * res_all[self._best]:
                self._best = best  # hysteresis: a clearly better dead time only
        best = self._best
        if best in jumps:
            self.gated += 1
        self.disturbance = d_all[best]
        if excited:
            self.excited_windows += 1
        if self.excited_windows >= DELAY_READY_WINDOWS:
            self.delay = self.delays[best]
        if pgg_all[best] <= GAIN_READY_STD ** 2:
            # the estimate handed out moves at most OUTPUT_RATE a window (a change of dead time
            # candidate cannot make it jump)
            self.gain += min(max(g_all[best] - self.gain, -OUTPUT_RATE), OUTPUT_RATE)
        if pss_all[best] <= FRICTION_READY_STD ** 2:
            self.friction_scale += min(max(s_all[best] - self.friction_scale, -OUTPUT_RATE),
                                       OUTPUT_RATE)
