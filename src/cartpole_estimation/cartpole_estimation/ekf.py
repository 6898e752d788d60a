"""Extended Kalman Filter of the cart-pendulum state from the two encoders (chapter 5).

The filter estimates ``[x, theta, x_dot, theta_dot]`` (4.34), and the pendulum encoder's
offset b (Appendix H), from the quantised cart position and pendulum angle, with the model
of :mod:`cartpole_core.model` discretised (5.6)-(5.9) by the explicit midpoint rule (forward
Euler, the thesis's (5.8), one parameter away), a numerical Jacobian (5.20)/(5.21), the
Kalman gain (5.12) and the Joseph form of the covariance update (5.14)
(:mod:`cartpole_estimation.covariance`), b corrected only near an equilibrium
(``EkfConfig.offset_gate_*``) and R matched to the encoders' scatter there
(:mod:`~cartpole_estimation.measurement_noise`). One :meth:`ExtendedKalmanFilter.update`
per sample: the time update (5.15)/(5.16) under the force applied in the interval, then the
measurement update (5.10)-(5.14). Q as a random walk per sample period with a random force
on the cart, the offset state, the filter's friction steepness and the fault handling:
docs/estimation.md.

No ROS import: the node :mod:`cartpole_estimation.ekf_node` and the offline closed loop
both use this module. Deterministic: the same inputs give the same estimates bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cartpole_core.model import CartPoleParameters, acceleration_function, wrap_angle

from .covariance import correct, predict_covariance
from .ekf_config import EkfConfig
from .measurement_noise import MeasurementNoise
from .state_estimate import StateEstimate

__all__ = ['EkfConfig', 'StateEstimate', 'ExtendedKalmanFilter']


@dataclass
class ExtendedKalmanFilter:
    """The EKF of section 5.2 on the model of section 4.4.

    Parameters
    ----------
    params
        The filter's model of the plant (nominal parameters). Its Coulomb
        friction steepness is replaced by ``config.friction_steepness``.
    config
        Q, R, the offset prior, limits; see :class:`EkfConfig`.

    Notes
    -----
    Use :meth:`update` once per sample with the measured positions and the
    force command that was held during the interval that ended at this
    sample. The first update (and every re-initialisation) sets the state to
    the measurement with zero velocities.

    The state is ``z = [x, m, x_dot, theta_dot, b]`` with ``m = theta - b``
    the angle as the encoder reads it and b its offset
    (:mod:`cartpole_estimation.covariance`); the estimates handed out carry
    ``theta = m + b``, the pendulum's own angle.

    Why one class of about 430 lines: the filter is one state (estimate, covariance,
    offset prior, the last accepted sample) that prediction (5.6), correction (5.7)
    and the refusal of implausible samples all read and write; the covariance algebra
    is :mod:`cartpole_estimation.covariance`, the configuration :mod:`~cartpole_estimation.ekf_config`.
    """

    params: CartPoleParameters = field(default_factory=CartPoleParameters)
    config: EkfConfig = field(default_factory=EkfConfig)

    def __post_init__(self) -> None:
        self.resets = 0
        self.missed_samples_total = 0
        self.rejected_samples = 0
        self.input_faults = 0
        self.pushed_samples = 0
        """Samples predicted again with ``push_q_force`` (their cart innovation was large)."""
        self._configure()
        self.reset()

    # -- configuration ---------------------------------------------------------------
    def _configure(self) -> None:
        cfg = self.config
        k = cfg.friction_steepness
        self.model = self.params.replace(friction_steepness_cart=k,
                                         friction_steepness_pendulum=k)
        self._acc = acceleration_function(self.model)  # (4.18) with the filter's friction
        self.sample_time = cfg.sample_time if cfg.sample_time is not None \
            else self.params.sample_time
        offset = cfg.estimates_angle_offset
        self._q_force = cfg.q_force
        self._push_q_force = cfg.push_q_force if cfg.push_q_force > cfg.q_force else 0.0
        self._push_innovation = cfg.push_innovation
        self._push_ratio2 = cfg.push_ratio * cfg.push_ratio
        self._push_window = cfg.push_window
        self._push_cos = math.cos(cfg.push_angle)
        self._m_c, self._m_p, self._l = self.params.m_c, self.params.m_p, self.params.l
        self._midpoint = cfg.discretisation == 'midpoint'
        self._q = (*cfg.q_diag, cfg.angle_offset_q if offset else 0.0)
        self._gate_rate = cfg.offset_gate_rate
        self._gate_sin = math.sin(cfg.offset_gate_angle)
        self._gate_force = cfg.offset_gate_force
        self._gate_noise = cfg.offset_gate_noise * cfg.r_diag[1]
        # Thresholds of _check, read once per configuration.
        self._n2 = cfg.innovation_sigma * cfg.innovation_sigma
        self._x_low = -cfg.max_position_excursion
        self._x_high = self.params.travel + cfg.max_position_excursion
        self._r_x, self._r_theta = cfg.r_diag
        self._noise = MeasurementNoise(cfg.r_diag, cfg.r_diag[1] / cfg.noise_variance_theta,
                                       cfg.noise_window, cfg.noise_limit, self.sample_time)
        d0, d1, d2, d3 = cfg.p0_diag
        # P_0|0 in the packed symmetric layout of :attr:`_pc` (see reset()), the
        # offset's prior last and uncorrelated with the measured angle m.
        self._offset_p0 = cfg.angle_offset_p0 if offset else 0.0
        self._p0 = (d0, 0.0, 0.0, 0.0, 0.0, d1, 0.0, 0.0, 0.0, d2, 0.0, 0.0, d3, 0.0,
                    self._offset_p0)

    def set_config(self, config: EkfConfig) -> None:
        """Use another configuration from the next update on (state and P kept).

        Switching the offset state off forgets the offset (b = 0, certain).
        """
        if not isinstance(config, EkfConfig):
            raise TypeError(f'config must be an EkfConfig, got {type(config).__name__}')
        self.config = config
        self._configure()
        if not config.estimates_angle_offset:
            self._forget_offset()

    def set_noise(self, q_diag=None, r_diag=None) -> None:
        """Change Q (9.2) and/or R (9.1) between two updates; validated first.

        Raises :class:`ValueError` (nothing changed) on a wrong length or a
        non-positive entry.
        """
        changes = {}
        if q_diag is not None:
            changes['q_diag'] = q_diag
        if r_diag is not None:
            changes['r_diag'] = r_diag
        if changes:
            self.config = self.config.replace(**changes)
            self._configure()

    # -- state -------------------------------------------------------------------------
    def reset(self, x0=None) -> None:
        """Forget the estimate; the next :meth:`update` initialises from its measurement.

        With ``x0`` (a 4-vector) the state is set to it instead, with P_0|0 =
        diag(p0_diag), and the next update predicts from it (its time is the
        next sample's minus Ts).
        """
        self._t: float | None = None
        self._outliers = 0
        self._nu_x_ms = 0.0  # mean square of the cart's innovations (EkfConfig.push_window)
        self._last: StateEstimate | None = None
        self._pending_reason = ''
        # The offset b and its variance carried over a re-initialisation (the
        # encoders were not reset then); forgotten here, the prior is taken.
        self._offset = (0.0, self._offset_p0)
        # P is symmetric; it is kept as its 15 upper-triangle entries, a tuple
        # of floats (:mod:`cartpole_estimation.covariance`).
        if x0 is None:
            self._s: list[float] | None = None
            self._pc = self._p0
            return
        s = [float(v) for v in np.asarray(x0, dtype=float).reshape(4)]
        if not all(math.isfinite(v) for v in s):
            raise ValueError(f'x0 must be finite, got {s}')
        self._s = s + [0.0]
        self._pc = self._p0

    def _forget_offset(self) -> None:
        """b = 0 with no uncertainty and no correlation (the thesis's 4-state filter)."""
        self._offset = (0.0, 0.0)
        if self._s is not None:
            self._s[4] = 0.0
        pc = list(self._pc)
        for i in (4, 8, 11, 13, 14):
            pc[i] = 0.0
        self._pc = tuple(pc)

    def request_reset(self, reason: str = 'requested') -> None:
        """Re-initialise from the next measurement, reported as ``reason``."""
        self.reset()
        self.resets += 1
        self._pending_reason = reason

    @property
    def initialised(self) -> bool:
        return self._t is not None

    @property
    def covariance(self) -> np.ndarray:
        """P_k|k (5.14) of z = [x, m, x_dot, theta_dot, b], a new 5x5 array (symmetric)."""
        p00, p01, p02, p03, p04, p11, p12, p13, p14, p22, p23, p24, p33, p34, p44 = self._pc
        return np.array([[p00, p01, p02, p03, p04],
                         [p01, p11, p12, p13, p14],
                         [p02, p12, p22, p23, p24],
                         [p03, p13, p23, p33, p34],
                         [p04, p14, p24, p34, p44]])

    @property
    def angle_offset(self) -> float:
        """b, the estimated offset of the pendulum encoder [rad] (0.0 without the offset state)."""
        return 0.0 if self._s is None else self._s[4]

    @property
    def measurement_noise_factors(self) -> tuple[float, float]:
        """R in use over ``config.r_diag``, cart and pendulum (:mod:`.measurement_noise`)."""
        return self._noise.factors

    @property
    def last_estimate(self) -> StateEstimate | None:
        return self._last

    # -- the filter ----------------------------------------------------------------------
    def _linearise(self, x: float, th: float, xd: float, thd: float, force: float,
                   h: float) -> tuple[float, ...]:
        """The accelerations and the two non-trivial rows of F_k, (5.19)-(5.21).

        Returns ``(a0, b0, f21, f22, f23, f31, f32, f33)``: the model
        accelerations (4.18) at the state and rows 3 and 4 of
        F_k = I + h d(f + g u)/dx, ``[0, f21, f22, f23]`` and
        ``[0, f31, f32, f33]``, by forward differences of step
        ``config.jacobian_step`` (5.21). Rows 1 and 2 are ``[1, 0, h, 0]`` and
        ``[0, 1, 0, h]`` exactly (x + h x_dot, theta + h theta_dot).

        The accelerations (4.18) do not depend on the cart position x (the
        model is invariant to where the cart is; the end stops are not part of
        it), so the forward difference in x is exactly zero: ``acc(x + eps,
        ...)`` returns ``acc(x, ...)`` bit for bit. That evaluation is skipped
        and the first column is 0.0, the value it would give (the products with
        it are left out of :meth:`_predict`). A test checks the invariance.
        """
        acc = self._acc
        eps = self.config.jacobian_step
        a0, b0 = acc(x, th, xd, thd, force)
        a2, b2 = acc(x, th + eps, xd, thd, force)
        a3, b3 = acc(x, th, xd + eps, thd, force)
        a4, b4 = acc(x, th, xd, thd + eps, force)
        g = h / eps
        return (a0, b0,
                (a2 - a0) * g, 1.0 + (a3 - a0) * g, (a4 - a0) * g,
                (b2 - b0) * g, (b3 - b0) * g, 1.0 + (b4 - b0) * g)

    def transition(self, state, force: float, h: float) -> tuple[list[float], np.ndarray]:
        """f_k and its Jacobian F_k for a step of length h [s], (5.8), (5.19)-(5.21).

        From ``state`` [x, theta, x_dot, theta_dot] under ``force`` [N]: x + h (f(x) + g(x) u)
        as a list of 4 floats, and the 4x4 F_k = I + h d(f + g u)/dx by forward differences
        of step ``config.jacobian_step``.
        """
        x, th, xd, thd = state
        a0, b0, f21, f22, f23, f31, f32, f33 = self._linearise(x, th, xd, thd, force, h)
        f_k = np.array([[1.0, 0.0, h, 0.0],
                        [0.0, 1.0, 0.0, h],
                        [0.0, f21, f22, f23],
                        [0.0, f31, f32, f33]])
        return [x + h * xd, th + h * thd, xd + h * a0, thd + h * b0], f_k

    def _predict(self, h: float, force: float, q_force: float) -> None:
        """Time update (5.15)/(5.16) over a step of length h.

        x_k|k-1 = f_k(x_k-1|k-1, u) (5.15), the model at theta = m + b, with
        f_k the explicit midpoint rule (or forward Euler (5.8) with
        ``discretisation='euler'``), and P_k|k-1 = F_k P F_k^T + Q (5.16)
        (:func:`~cartpole_estimation.covariance.predict_covariance`, F_k's rows
        from :meth:`_linearise`). Q is added as ``Q h / Ts`` (module docstring),
        the random force on the cart with variance ``q_force``.
        """
        x, m, xd, thd, off = self._s
        a0, b0, f21, f22, f23, f31, f32, f33 = self._linearise(x, m + off, xd, thd, force, h)
        if self._midpoint:
            # Explicit midpoint rule: the model's accelerations half a step on.
            hh = 0.5 * h
            xd_m = xd + hh * a0
            thd_m = thd + hh * b0
            a0, b0 = self._acc(x + hh * xd, m + off + hh * thd, xd_m, thd_m, force)
            self._s = [x + h * xd_m, m + h * thd_m, xd + h * a0, thd + h * b0, off]
        else:
            self._s = [x + h * xd, m + h * thd, xd + h * a0, thd + h * b0, off]
        q = self._q
        if h != self.sample_time:
            ratio = h / self.sample_time
            q = tuple(v * ratio for v in q)
        pc = predict_covariance(self._pc, h, f21, f22, f23, f31, f32, f33, q)
        if q_force > 0.0:
            # + q_force b b^T, b = h g(x) (4.40): a random force on the cart.
            s_th = math.sin(m + off)
            g_c = h / (self._m_c + self._m_p * s_th * s_th)
            g_p = g_c * math.cos(m + off) / self._l
            if h != self.sample_time:
                q_force *= h / self.sample_time
            pc = (*pc[:9], pc[9] + q_force * g_c * g_c, pc[10] + q_force * g_c * g_p, pc[11],
                  pc[12] + q_force * g_p * g_p, pc[13], pc[14])
        self._pc = pc

    def _correct(self, y_x: float, y_theta: float, force: float) -> tuple:
        """Measurement update (5.10)-(5.14) (:func:`~cartpole_estimation.covariance.correct`),
        b corrected only near an equilibrium (``EkfConfig.offset_gate_*``); returns the
        innovation (5.11), the innovation variances and whether it was near one."""
        s = self._s
        # The encoders' angle m, not m + b: a wrong b must not shut its own gate.
        near = abs(s[3]) <= self._gate_rate and abs(force) <= self._gate_force \
            and abs(math.sin(s[1])) <= self._gate_sin
        noisy = self._r_theta >= self._gate_noise  # the encoder's noise outweighs the model's
        self._s, self._pc, nu_x, nu_t, s00, s11 = correct(
            s, self._pc, y_x, y_theta, self._r_x, self._r_theta, not (near or noisy))
        return nu_x, nu_t, s00, s11, near

    def _initialise(self, t: float, y_x: float, y_theta: float, force: float,
                    reason: str, warning: str = '') -> StateEstimate:
        """Set the state to the measurement, velocities zero, P = P_0|0.

        The offset estimate and its variance carry over (the encoders were
        not reset, only the filter), or the prior after :meth:`reset`.
        """
        offset, variance = self._offset
        self._s = [y_x, y_theta, 0.0, 0.0, offset]
        self._pc = self._p0 if variance == self._offset_p0 else self._p0[:14] + (variance,)
        self._t = t
        self._outliers = 0
        return self._estimate(t, force, (0.0, 0.0), 0.0, 0, True, reason, warning)

    def _reinitialise(self, t: float, y_x: float, y_theta: float, force: float,
                      reason: str, warning: str = '') -> StateEstimate:
        self.resets += 1
        offset, variance = self._s[4], self._pc[14]
        if self._offset_p0 > 0.0 and math.isfinite(offset) and 0.0 <= variance <= self._offset_p0:
            self._offset = (offset, variance)
        return self._initialise(t, y_x, y_theta, force, reason, warning)

    def _estimate(self, t: float, force: float, innovation: tuple[float, float], dt: float,
                  missed: int, reset: bool, reason: str, warning: str = '') -> StateEstimate:
        x, m, xd, thd, off = self._s
        th = m + off
        x_ddot, theta_ddot = self._acc(x, th, xd, thd, force)
        pc = self._pc
        est = StateEstimate(t, x, th, xd, thd, wrap_angle(th), x_ddot, theta_ddot,
                            (pc[0], pc[5] + 2.0 * pc[8] + pc[14], pc[9], pc[12]), innovation,
                            dt, missed, self.missed_samples_total, reset, reason, self.resets,
                            '', warning, True, off)
        self._last = est
        return est

    def _refuse(self, t: float, reason: str, reset: bool = False) -> StateEstimate:
        """The previous estimate, unchanged, marked as refused (never NaN)."""
        self.rejected_samples += 1
        last = self._last
        if last is None:
            return StateEstimate(
                t=t if math.isfinite(t) else 0.0, x=0.0, theta=math.pi, x_dot=0.0,
                theta_dot=0.0, theta_w=math.pi, x_ddot=0.0, theta_ddot=0.0,
                covariance_diagonal=tuple(self.config.p0_diag), innovation=(0.0, 0.0), dt=0.0,
                missed_samples_total=self.missed_samples_total, reset=reset,
                reset_reason=reason if reset else '', resets=self.resets, rejected=reason,
                valid=False)
        return StateEstimate(
            t=last.t, x=last.x, theta=last.theta, x_dot=last.x_dot, theta_dot=last.theta_dot,
            theta_w=last.theta_w, x_ddot=last.x_ddot, theta_ddot=last.theta_ddot,
            covariance_diagonal=last.covariance_diagonal, innovation=last.innovation,
            dt=0.0, missed_samples_total=self.missed_samples_total, reset=reset,
            reset_reason=reason if reset else '', resets=self.resets, rejected=reason,
            valid=last.valid and not reset, angle_offset=last.angle_offset)

    def update(self, t: float, x_meas: float, theta_meas: float, force: float) -> StateEstimate:
        """Process one sample: time update over [t_prev, t], then measurement update.

        Parameters
        ----------
        t
            Sample time [s]; must increase from sample to sample.
        x_meas, theta_meas
            Measured cart position [m] and pendulum angle [rad] (continuous,
            pi hanging after reset), the y_k of (5.7).
        force
            The force command [N] held during the interval that ended at
            this sample, u_{k-1}, the input of the prediction (5.8)/(5.15).

        Returns
        -------
        StateEstimate
            Never carries NaN. ``reset``/``reset_reason`` report a
            (re)initialisation from this sample's measurement, ``rejected`` a
            refused sample (the previous estimate is returned unchanged).
        """
        t = float(t)
        y_x = float(x_meas)
        y_theta = float(theta_meas)
        force = float(force)
        if not math.isfinite(t):
            return self._refuse(t, f'non-finite stamp {t!r}')
        if not (math.isfinite(y_x) and math.isfinite(y_theta)):
            # Nothing to correct with: forget the state, re-initialise from the
            # next finite measurement; meanwhile hand out the last estimate,
            # marked invalid.
            reason = f'non-finite measurement ({y_x!r}, {y_theta!r})'
            last = self._last
            had_state = self._t is not None
            pending = self._pending_reason
            kept = (self._s[4], self._pc[14]) if self._s is not None else self._offset
            self.reset()
            if self._offset_p0 > 0.0 and math.isfinite(kept[0]) \
                    and 0.0 <= kept[1] <= self._offset_p0:
                self._offset = kept  # the encoders were not reset: keep what is known of b
            if had_state:
                self.resets += 1
                pending = 'recovery after non-finite measurement'
            self._pending_reason = pending
            self._last = last
            est = self._refuse(t, reason, reset=had_state)
            self._last = est
            return est
        warning = ''
        if not math.isfinite(force):
            # What the plant and the hardware bridge apply instead (zero force).
            warning = f'non-finite force {force!r} taken as 0 N'
            force = 0.0
            self.input_faults += 1
        if self._t is None:
            reason = self._pending_reason or 'initialisation'
            self._pending_reason = ''
            if self._s is not None and reason == 'initialisation':
                # reset(x0): predict one nominal period from the given state.
                self._t = t - self.sample_time
            else:
                return self._initialise(t, y_x, y_theta, force, reason, warning)
        dt = t - self._t
        ts = self.sample_time
        if dt <= 0.0:
            if dt < -self.config.max_dt:
                return self._reinitialise(t, y_x, y_theta, force,
                                          f'clock jumped back by {-dt:.3f} s')
            return self._refuse(t, f'stamp not increasing (dt = {dt:.6f} s)')
        if dt > self.config.max_dt:
            return self._reinitialise(t, y_x, y_theta, force, f'gap of {dt:.3f} s')
        # Time update (5.15)/(5.16) over the real dt, in Euler steps of about Ts.
        n = max(1, int(round(dt / ts)))
        missed = n - 1
        self.missed_samples_total += missed
        h = dt / n
        before = (self._s, self._pc)  # _predict and _correct build new ones
        for _ in range(n):
            self._predict(h, force, self._q_force)
        nu_x, nu_t, s11, s22, near = self._correct(y_x, y_theta, force)
        nu2 = nu_x * nu_x
        pushed = self._push_q_force and abs(nu_x) > self._push_innovation \
            and nu2 > self._push_ratio2 * self._nu_x_ms \
            and math.cos(self._s[1] + self._s[4]) > self._push_cos
        if not pushed:  # the statistics of the model's own error, not of the push
            self._nu_x_ms += min(1.0, dt / self._push_window) * (nu2 - self._nu_x_ms)
        else:
            # A push: this sample again with the push's force variance, so that the
            # gain follows the cart now and not 40-50 ms later (EkfConfig.push_q_force).
            self._s, self._pc = before
            for _ in range(n):
                self._predict(h, force, self._push_q_force)
            nu_x, nu_t, s11, s22, near = self._correct(y_x, y_theta, force)
            self.pushed_samples += 1
        self._t = t
        reason = self._check(nu_x, nu_t, s11, s22)
        if reason:
            return self._reinitialise(t, y_x, y_theta, force, reason, warning)
        self._r_x, self._r_theta = self._noise.update(
            t, y_x, y_theta, near and not pushed and not self._outliers)
        return self._estimate(t, force, (nu_x, nu_t), dt, missed, False, '', warning)

    def _check(self, nu_x: float, nu_t: float, s11: float, s22: float) -> str:
        """Divergence tests: state, covariance, innovation; '' if all is well."""
        cfg = self.config
        x, m, xd, thd, off = self._s
        isfinite = math.isfinite
        if not (isfinite(x) and isfinite(m) and isfinite(xd) and isfinite(thd)
                and isfinite(off)):
            return 'state not finite'
        pc = self._pc
        d0, d1, d2, d3, d4 = pc[0], pc[5], pc[9], pc[12], pc[14]
        max_cov = cfg.max_covariance
        # 0 <= d <= max_cov is false for a negative, infinite or NaN entry.
        if not (0.0 <= d0 <= max_cov and 0.0 <= d1 <= max_cov and 0.0 <= d2 <= max_cov
                and 0.0 <= d3 <= max_cov and 0.0 <= d4 <= max_cov):
            return f'covariance blow-up (diag P = {(d0, d1, d2, d3, d4)})'
        max_speed = cfg.max_speed
        if abs(xd) > max_speed[0] or abs(thd) > max_speed[1]:
            return f'state out of bounds (x_dot = {xd:.3g} m/s, theta_dot = {thd:.3g} rad/s)'
        if x < self._x_low or x > self._x_high:
            return f'state out of bounds (x = {x:.3g} m)'
        n2 = self._n2
        max_innovation = cfg.max_innovation
        outlier = (nu_x * nu_x > n2 * s11 or nu_t * nu_t > n2 * s22
                   or abs(nu_x) > max_innovation[0] or abs(nu_t) > max_innovation[1])
        if outlier:
            self._outliers += 1
            if self._outliers >= cfg.innovation_count:
                return (f'innovation beyond bounds for {self._outliers} samples '
                        f'(x {nu_x:.3g} m, theta {nu_t:.3g} rad)')
        else:
            self._outliers = 0
        return ''
