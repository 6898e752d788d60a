"""Extended Kalman Filter of the cart-pendulum state from the two encoders (chapter 5).

The filter estimates ``[x, theta, x_dot, theta_dot]`` (4.34) from the
quantised cart position and pendulum angle, with the model of
:mod:`cartpole_sim.model` discretised by forward Euler (5.6)-(5.9), a
numerical Jacobian (5.20)/(5.21), the Kalman gain (5.12) and the Joseph form
of the covariance update (5.14).

One call of :meth:`ExtendedKalmanFilter.update` per sample does the time
update from the previous sample to this one under the force applied in that
interval, (5.15)/(5.16), then the measurement update, (5.10)-(5.14). The
thesis writes the same two steps in the other order (correction, then
prediction for the next sample, (5.17)); the result is identical.

Noise covariances. The thesis tuned, on the rig, ``R = diag(0.01, 0.1)``
(9.1) and ``Q = diag(1, 1, 50, 50)`` (9.2), and uses them as the discrete
``Q_k``/``R_k`` of (5.6)/(5.7), added once per sample period (5.16). Here Q
is exactly that: the covariance added per nominal period ``Ts``; a step of
another length ``h`` (a missed sample, jitter) adds ``Q h / Ts``, i.e. Q is
treated as a random walk whose intensity is ``Q / Ts`` per second. R is the
covariance of one measurement.

Friction in the filter's model. The plant's Coulomb friction uses
``tanh(k v)`` with ``k = 1000`` (a near step). Its slope at rest,
``c_c k / m_c`` = 716 1/s for the cart, makes the forward-Euler prediction
at ``Ts`` = 5 ms unstable (|1 - Ts 716| > 1; the limit is
k < 2 m_c / (c_c Ts) = 559). The filter uses its own steepness
(:attr:`EkfConfig.friction_steepness`, 200 s/m and s/rad by default: Euler
factor 1 - 0.72 = 0.28 at rest, still stable for sub-steps up to 2.8 Ts and
+20 % friction). Smaller values (10-50) are stable too but let the modelled
cart slide under forces below the stiction level (a 2 N push gives a
0.03 m/s velocity bias at k = 20); 200 gave the smallest velocity errors on
the free-swing, forced-cart and stuck-cart tests (see
the README, "State estimation").

No ROS import: the node :mod:`cartpole_estimation.ekf_node` and the offline
closed loop both use this module. Deterministic: the same inputs give the
same estimates bit for bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from cartpole_sim.model import CartPoleParameters, acceleration_function, wrap_angle

__all__ = ['EkfConfig', 'StateEstimate', 'ExtendedKalmanFilter']

_TWO_PI = 2.0 * math.pi


def _positive_tuple(name: str, value, length: int) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in value)
    except TypeError as exc:
        raise ValueError(f'{name} must be a sequence of {length} numbers, got {value!r}') from exc
    if len(values) != length:
        raise ValueError(f'{name} must have {length} entries, got {len(values)}')
    if not all(math.isfinite(v) and v > 0.0 for v in values):
        raise ValueError(f'{name} entries must be finite and > 0, got {values}')
    return values


@dataclass(frozen=True)
class EkfConfig:
    """Tuning and safety limits of the EKF (section 5.2, 9.2.1).

    Every field is validated on construction; a bad value raises
    :class:`ValueError` naming it.
    """

    q_diag: tuple[float, float, float, float] = (1.0, 1.0, 50.0, 50.0)
    """Diagonal of Q_k (9.2): covariance added to the state per nominal sample
    period Ts, in m^2, rad^2, (m/s)^2, (rad/s)^2. A step of length h adds
    Q h / Ts."""
    r_diag: tuple[float, float] = (0.01, 0.1)
    """Diagonal of R_k (9.1): measurement covariance of x [m^2] and theta [rad^2]."""
    p0_diag: tuple[float, float, float, float] = (1.0e-6, 1.0e-5, 1.0e3, 1.0e5)
    """Diagonal of P_0|0 after an (re)initialisation from a measurement:
    positions about one encoder tick; velocities practically unknown (the
    state is initialised with zero velocities, possibly mid-swing), so that
    the next few samples set them: with Q and R of the thesis a prior of
    (1 rad/s)^2 takes about 0.4 s to recover from a reset at 10 rad/s, this
    one about 0.05 s."""
    jacobian_step: float = 1.0e-6
    """epsilon of the forward difference (5.21)."""
    friction_steepness: float = 200.0
    """k of tanh(k v) in the filter's Coulomb friction of cart [s/m] and
    pendulum [s/rad], (4.20)/(4.21); replaces the plant's near-step 1000,
    with which forward Euler at Ts is unstable near rest (see the module
    docstring)."""
    sample_time: float | None = None
    """Nominal Ts [s]; None takes ``params.sample_time`` (5 ms)."""
    max_dt: float = 0.25
    """Largest gap between two samples that is bridged by prediction [s];
    a longer gap (or a clock jump backwards by more than this) re-initialises
    the filter from the measurement."""
    innovation_sigma: float = 6.0
    """N: an innovation beyond N standard deviations of (5.12)'s
    H P H^T + R counts as an outlier."""
    innovation_count: int = 5
    """M: this many consecutive outlier samples re-initialise the filter."""
    max_innovation: tuple[float, float] = (0.05, 1.0)
    """An innovation of x [m] / wrapped theta [rad] larger than this in one
    sample (10 m/s resp. 200 rad/s over Ts) is an outlier whatever P says."""
    max_covariance: float = 1.0e9
    """Any diagonal entry of P above this (or non-finite) re-initialises;
    must exceed every entry of ``p0_diag``."""
    max_speed: tuple[float, float] = (20.0, 200.0)
    """|x_dot| [m/s] / |theta_dot| [rad/s] above which the estimate is
    considered diverged and re-initialised."""
    max_position_excursion: float = 1.0
    """The estimate of x may leave [0, travel] by at most this [m]."""

    def __post_init__(self) -> None:
        object.__setattr__(self, 'q_diag', _positive_tuple('q_diag', self.q_diag, 4))
        object.__setattr__(self, 'r_diag', _positive_tuple('r_diag', self.r_diag, 2))
        object.__setattr__(self, 'p0_diag', _positive_tuple('p0_diag', self.p0_diag, 4))
        object.__setattr__(self, 'max_innovation',
                           _positive_tuple('max_innovation', self.max_innovation, 2))
        object.__setattr__(self, 'max_speed', _positive_tuple('max_speed', self.max_speed, 2))
        for name in ('jacobian_step', 'friction_steepness', 'max_dt', 'innovation_sigma',
                     'max_covariance', 'max_position_excursion'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value <= 0.0:
                raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
        if self.sample_time is not None and not (
                isinstance(self.sample_time, (int, float)) and math.isfinite(self.sample_time)
                and self.sample_time > 0.0):
            raise ValueError(f'sample_time must be None or a finite number > 0, '
                             f'got {self.sample_time!r}')
        if self.max_covariance <= max(self.p0_diag):
            raise ValueError(f'max_covariance ({self.max_covariance}) must exceed every '
                             f'p0_diag entry {self.p0_diag}')
        if not isinstance(self.innovation_count, int) or self.innovation_count < 1:
            raise ValueError(f'innovation_count must be an integer >= 1, '
                             f'got {self.innovation_count!r}')

    def replace(self, **changes) -> 'EkfConfig':
        """Return a copy with ``changes`` applied (validated again)."""
        import dataclasses
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True, slots=True)
class StateEstimate:
    """The filter's output for one sample (all SI units).

    ``theta`` is continuous (not wrapped); ``theta_w`` is it wrapped to
    (-pi, pi]. ``x_ddot``/``theta_ddot`` are the model accelerations
    f(x_hat) + g(x_hat) u (4.40) at the corrected estimate under the force
    that was applied in the interval ending at this sample, what (7.10)
    needs.
    """

    t: float
    x: float
    theta: float
    x_dot: float
    theta_dot: float
    theta_w: float
    x_ddot: float
    theta_ddot: float
    covariance_diagonal: tuple[float, float, float, float]
    """Diagonal of P_k|k (5.14)."""
    innovation: tuple[float, float]
    """y_k - h(x_hat_k|k-1) (5.11): x [m] and theta [rad] (wrapped); zeros
    after an initialisation."""
    dt: float
    """Time since the previous accepted sample [s]; 0 on an initialisation."""
    missed_samples: int = 0
    """Samples missing in the interval that ended here (round(dt / Ts) - 1)."""
    missed_samples_total: int = 0
    """Missed samples since the filter was made."""
    reset: bool = False
    """The filter was (re)initialised from this sample's measurement."""
    reset_reason: str = ''
    """Why: 'initialisation', 'non-finite ...', 'innovation ...', 'covariance ...',
    'state ...', 'gap ...', 'clock jumped back ...', 'requested'; '' otherwise."""
    resets: int = 0
    """Re-initialisations since the filter was made (the first one excluded)."""
    rejected: str = ''
    """Non-empty if this sample was refused (stamp not increasing or not
    finite, measurement not finite): the estimate is the previous one,
    unchanged (its ``t`` is the previous sample's)."""
    warning: str = ''
    """A repaired input, e.g. a non-finite force taken as 0 N."""
    valid: bool = True
    """False when no finite measurement backs this estimate (none seen yet,
    or the state was dropped after a non-finite measurement)."""

    def as_array(self) -> np.ndarray:
        """The state [x, theta, x_dot, theta_dot] (4.34)."""
        return np.array([self.x, self.theta, self.x_dot, self.theta_dot])


_ESTIMATE_FIELDS = ('t', 'x', 'theta', 'x_dot', 'theta_dot', 'theta_w', 'x_ddot', 'theta_ddot',
                    'covariance_diagonal', 'innovation', 'dt', 'missed_samples',
                    'missed_samples_total', 'reset', 'reset_reason', 'resets', 'rejected',
                    'warning', 'valid')


def _estimate_factory():
    """A positional constructor of :class:`StateEstimate`, all 19 fields in order.

    The same object the dataclass ``__init__`` makes (no ``__post_init__``,
    no defaults involved), built by the slots' own descriptors: a frozen
    dataclass's generated ``__init__`` goes through ``object.__setattr__``
    once per field and costs about 4 us, this about 1.5 us, once per sample.
    A test checks both give equal objects.
    """
    names = tuple(f.name for f in fields(StateEstimate))
    if names != _ESTIMATE_FIELDS:  # the signature below must list every field, in order
        raise RuntimeError(f'StateEstimate fields changed: {names}')
    setters = [getattr(StateEstimate, name).__set__ for name in names]
    (s0, s1, s2, s3, s4, s5, s6, s7, s8, s9, s10, s11, s12, s13, s14, s15, s16, s17,
     s18) = setters
    new = object.__new__

    def make(t, x, theta, x_dot, theta_dot, theta_w, x_ddot, theta_ddot, covariance_diagonal,
             innovation, dt, missed_samples, missed_samples_total, reset, reset_reason, resets,
             rejected, warning, valid) -> StateEstimate:
        est = new(StateEstimate)
        s0(est, t)
        s1(est, x)
        s2(est, theta)
        s3(est, x_dot)
        s4(est, theta_dot)
        s5(est, theta_w)
        s6(est, x_ddot)
        s7(est, theta_ddot)
        s8(est, covariance_diagonal)
        s9(est, innovation)
        s10(est, dt)
        s11(est, missed_samples)
        s12(est, missed_samples_total)
        s13(est, reset)
        s14(est, reset_reason)
        s15(est, resets)
        s16(est, rejected)
        s17(est, warning)
        s18(est, valid)
        return est

    return make


_new_estimate = _estimate_factory()


@dataclass
class ExtendedKalmanFilter:
    """The EKF of section 5.2 on the model of section 4.4.

    Parameters
    ----------
    params
        The filter's model of the plant (nominal parameters). Its Coulomb
        friction steepness is replaced by ``config.friction_steepness``.
    config
        Q, R, limits; see :class:`EkfConfig`.

    Notes
    -----
    Use :meth:`update` once per sample with the measured positions and the
    force command that was held during the interval that ended at this
    sample. The first update (and every re-initialisation) sets the state to
    the measurement with zero velocities.
    """

    params: CartPoleParameters = field(default_factory=CartPoleParameters)
    config: EkfConfig = field(default_factory=EkfConfig)

    def __post_init__(self) -> None:
        self.resets = 0
        self.missed_samples_total = 0
        self.rejected_samples = 0
        self.input_faults = 0
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
        self._q = tuple(cfg.q_diag)
        # Thresholds of _check, read once per configuration.
        self._n2 = cfg.innovation_sigma * cfg.innovation_sigma
        self._x_low = -cfg.max_position_excursion
        self._x_high = self.params.travel + cfg.max_position_excursion
        self._r_x, self._r_theta = cfg.r_diag
        d0, d1, d2, d3 = cfg.p0_diag
        # P_0|0 in the packed symmetric layout of :attr:`_pc` (see reset()).
        self._p0 = (d0, 0.0, 0.0, 0.0, d1, 0.0, 0.0, d2, 0.0, d3)

    def set_config(self, config: EkfConfig) -> None:
        """Use another configuration from the next update on (state and P kept)."""
        if not isinstance(config, EkfConfig):
            raise TypeError(f'config must be an EkfConfig, got {type(config).__name__}')
        self.config = config
        self._configure()

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
        self._last: StateEstimate | None = None
        self._pending_reason = ''
        # P is symmetric; it is kept as its 10 upper-triangle entries
        # (p00, p01, p02, p03, p11, p12, p13, p22, p23, p33), a tuple of floats:
        # the 4x4 algebra of (5.14)/(5.16) in scalar closed form is several
        # times faster in CPython than small numpy products.
        if x0 is None:
            self._s: list[float] | None = None
            self._pc = self._p0
            return
        s = [float(v) for v in np.asarray(x0, dtype=float).reshape(4)]
        if not all(math.isfinite(v) for v in s):
            raise ValueError(f'x0 must be finite, got {s}')
        self._s = s
        self._pc = self._p0

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
        """P_k|k (5.14), a new 4x4 array (symmetric)."""
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._pc
        return np.array([[p00, p01, p02, p03],
                         [p01, p11, p12, p13],
                         [p02, p12, p22, p23],
                         [p03, p13, p23, p33]])

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
        """f_k and its Jacobian F_k for a step of length h, (5.8), (5.19)-(5.21).

        Parameters
        ----------
        state
            [x, theta, x_dot, theta_dot].
        force
            Force on the cart during the step [N].
        h
            Step length [s] (Ts normally).

        Returns
        -------
        (list, ndarray)
            x + h (f(x) + g(x) u) as a list of 4 floats, and the 4x4 F_k =
            I + h d(f + g u)/dx by forward differences of step
            ``config.jacobian_step``.
        """
        x, th, xd, thd = state
        a0, b0, f21, f22, f23, f31, f32, f33 = self._linearise(x, th, xd, thd, force, h)
        f_k = np.array([[1.0, 0.0, h, 0.0],
                        [0.0, 1.0, 0.0, h],
                        [0.0, f21, f22, f23],
                        [0.0, f31, f32, f33]])
        return [x + h * xd, th + h * thd, xd + h * a0, thd + h * b0], f_k

    def _predict(self, h: float, force: float) -> None:
        """Time update (5.15)/(5.16) over a step of length h.

        x_k|k-1 = f_k(x_k-1|k-1, u) (5.15) and P_k|k-1 = F_k P F_k^T + Q (5.16),
        the latter in closed form on the 10 entries of the symmetric P, with
        F_k = [[1, 0, h, 0], [0, 1, 0, h], [0, f21, f22, f23], [0, f31, f32, f33]]
        (:meth:`_linearise`). Q is added as ``Q h / Ts`` (module docstring).
        """
        x, th, xd, thd = self._s
        a0, b0, f21, f22, f23, f31, f32, f33 = self._linearise(x, th, xd, thd, force, h)
        self._s = [x + h * xd, th + h * thd, xd + h * a0, thd + h * b0]
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._pc
        # B = F_k P, row by row. F_k's first column is e_1, so B's first column
        # enters only P_i0 of the product, of which the upper triangle keeps
        # P_00: B_10, B_20, B_30 are not needed.
        b00 = p00 + h * p02
        b01 = p01 + h * p12
        b02 = p02 + h * p22
        b03 = p03 + h * p23
        b11 = p11 + h * p13
        b12 = p12 + h * p23
        b13 = p13 + h * p33
        b21 = f21 * p11 + f22 * p12 + f23 * p13
        b22 = f21 * p12 + f22 * p22 + f23 * p23
        b23 = f21 * p13 + f22 * p23 + f23 * p33
        b31 = f31 * p11 + f32 * p12 + f33 * p13
        b32 = f31 * p12 + f32 * p22 + f33 * p23
        b33 = f31 * p13 + f32 * p23 + f33 * p33
        # P_k|k-1 = B F_k^T + Q, upper triangle.
        q0, q1, q2, q3 = self._q
        if h != self.sample_time:
            ratio = h / self.sample_time
            q0, q1, q2, q3 = q0 * ratio, q1 * ratio, q2 * ratio, q3 * ratio
        self._pc = (b00 + h * b02 + q0,
                    b01 + h * b03,
                    f21 * b01 + f22 * b02 + f23 * b03,
                    f31 * b01 + f32 * b02 + f33 * b03,
                    b11 + h * b13 + q1,
                    f21 * b11 + f22 * b12 + f23 * b13,
                    f31 * b11 + f32 * b12 + f33 * b13,
                    f21 * b21 + f22 * b22 + f23 * b23 + q2,
                    f31 * b21 + f32 * b22 + f33 * b23,
                    f31 * b31 + f32 * b32 + f33 * b33 + q3)

    def _correct(self, y_x: float, y_theta: float) -> tuple[float, float, float, float]:
        """Measurement update (5.10)-(5.14) with H = [I 0] (5.18).

        Returns the innovation (5.11), theta's wrapped to (-pi, pi] so that
        a 2 pi jump of the measured angle is not taken for motion, and the
        innovation variances (H P H^T + R)_ii. Scalar code where H's
        structure makes it cheaper than matrix products: S = H P H^T + R is
        the upper-left 2x2 block of P plus R, K = P H^T S^-1 (5.12) uses P's
        first two columns, and the Joseph form (5.14)
        P = (I - K H) P (I - K H)^T + K R K^T is evaluated entry by entry as
        C = (I - K H) P, then C (I - K H)^T + K R K^T (upper triangle).
        """
        s = self._s
        nu_x = y_x - s[0]
        nu_t = y_theta - s[1]
        if not -math.pi < nu_t <= math.pi:
            nu_t = wrap_angle(nu_t)
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._pc
        r_x = self._r_x
        r_t = self._r_theta
        # S = H P H^T + R and its inverse in closed form.
        s00 = p00 + r_x
        s11 = p11 + r_t
        det = s00 * s11 - p01 * p01
        i00 = s11 / det
        i01 = -p01 / det
        i11 = s00 / det
        # K = P H^T S^-1 (5.12).
        k00 = p00 * i00 + p01 * i01
        k01 = p00 * i01 + p01 * i11
        k10 = p01 * i00 + p11 * i01
        k11 = p01 * i01 + p11 * i11
        k20 = p02 * i00 + p12 * i01
        k21 = p02 * i01 + p12 * i11
        k30 = p03 * i00 + p13 * i01
        k31 = p03 * i01 + p13 * i11
        # x_k|k = x_k|k-1 + K y~ (5.13).
        self._s = [s[0] + k00 * nu_x + k01 * nu_t, s[1] + k10 * nu_x + k11 * nu_t,
                   s[2] + k20 * nu_x + k21 * nu_t, s[3] + k30 * nu_x + k31 * nu_t]
        # Joseph form (5.14). A = I - K H = [[a00, -k01, 0, 0], [-k10, a11, 0, 0],
        # [-k20, -k21, 1, 0], [-k30, -k31, 0, 1]]; C = A P (C_32 is not needed).
        a00 = 1.0 - k00
        a11 = 1.0 - k11
        c00 = a00 * p00 - k01 * p01
        c01 = a00 * p01 - k01 * p11
        c02 = a00 * p02 - k01 * p12
        c03 = a00 * p03 - k01 * p13
        c10 = a11 * p01 - k10 * p00
        c11 = a11 * p11 - k10 * p01
        c12 = a11 * p12 - k10 * p02
        c13 = a11 * p13 - k10 * p03
        c20 = -k20 * p00 - k21 * p01 + p02
        c21 = -k20 * p01 - k21 * p11 + p12
        c22 = -k20 * p02 - k21 * p12 + p22
        c23 = -k20 * p03 - k21 * p13 + p23
        c30 = -k30 * p00 - k31 * p01 + p03
        c31 = -k30 * p01 - k31 * p11 + p13
        c33 = -k30 * p03 - k31 * p13 + p33
        # K R K^T with R = diag(r_x, r_theta): (K R)_i0 k_j0 + (K R)_i1 k_j1.
        kr00, kr01 = k00 * r_x, k01 * r_t
        kr10, kr11 = k10 * r_x, k11 * r_t
        kr20, kr21 = k20 * r_x, k21 * r_t
        kr30, kr31 = k30 * r_x, k31 * r_t
        self._pc = (a00 * c00 - k01 * c01 + (kr00 * k00 + kr01 * k01),
                    a11 * c01 - k10 * c00 + (kr00 * k10 + kr01 * k11),
                    -k20 * c00 - k21 * c01 + c02 + (kr00 * k20 + kr01 * k21),
                    -k30 * c00 - k31 * c01 + c03 + (kr00 * k30 + kr01 * k31),
                    a11 * c11 - k10 * c10 + (kr10 * k10 + kr11 * k11),
                    -k20 * c10 - k21 * c11 + c12 + (kr10 * k20 + kr11 * k21),
                    -k30 * c10 - k31 * c11 + c13 + (kr10 * k30 + kr11 * k31),
                    -k20 * c20 - k21 * c21 + c22 + (kr20 * k20 + kr21 * k21),
                    -k30 * c20 - k31 * c21 + c23 + (kr20 * k30 + kr21 * k31),
                    -k30 * c30 - k31 * c31 + c33 + (kr30 * k30 + kr31 * k31))
        return nu_x, nu_t, s00, s11

    def _initialise(self, t: float, y_x: float, y_theta: float, force: float,
                    reason: str, warning: str = '') -> StateEstimate:
        """Set the state to the measurement, velocities zero, P = P_0|0."""
        self._s = [y_x, y_theta, 0.0, 0.0]
        self._pc = self._p0
        self._t = t
        self._outliers = 0
        return self._estimate(t, force, (0.0, 0.0), 0.0, 0, True, reason, warning)

    def _reinitialise(self, t: float, y_x: float, y_theta: float, force: float,
                      reason: str, warning: str = '') -> StateEstimate:
        self.resets += 1
        return self._initialise(t, y_x, y_theta, force, reason, warning)

    def _estimate(self, t: float, force: float, innovation: tuple[float, float], dt: float,
                  missed: int, reset: bool, reason: str, warning: str = '') -> StateEstimate:
        x, th, xd, thd = self._s
        x_ddot, theta_ddot = self._acc(x, th, xd, thd, force)
        pc = self._pc
        est = _new_estimate(t, x, th, xd, thd, wrap_angle(th), x_ddot, theta_ddot,
                            (pc[0], pc[4], pc[7], pc[9]), innovation, dt, missed,
                            self.missed_samples_total, reset, reason, self.resets, '',
                            warning, True)
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
            valid=last.valid and not reset)

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
            self.reset()
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
        for _ in range(n):
            self._predict(h, force)
        nu_x, nu_t, s11, s22 = self._correct(y_x, y_theta)
        self._t = t
        reason = self._check(nu_x, nu_t, s11, s22)
        if reason:
            return self._reinitialise(t, y_x, y_theta, force, reason, warning)
        return self._estimate(t, force, (nu_x, nu_t), dt, missed, False, '', warning)

    def _check(self, nu_x: float, nu_t: float, s11: float, s22: float) -> str:
        """Divergence tests: state, covariance, innovation; '' if all is well."""
        cfg = self.config
        x, th, xd, thd = self._s
        isfinite = math.isfinite
        if not (isfinite(x) and isfinite(th) and isfinite(xd) and isfinite(thd)):
            return 'state not finite'
        pc = self._pc
        d0, d1, d2, d3 = pc[0], pc[4], pc[7], pc[9]
        max_cov = cfg.max_covariance
        # 0 <= d <= max_cov is false for a negative, infinite or NaN entry.
        if not (0.0 <= d0 <= max_cov and 0.0 <= d1 <= max_cov and 0.0 <= d2 <= max_cov
                and 0.0 <= d3 <= max_cov):
            return f'covariance blow-up (diag P = {(d0, d1, d2, d3)})'
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
