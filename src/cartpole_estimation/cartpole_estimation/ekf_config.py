"""Tuning and safety limits of the EKF (section 5.2, 9.2.1): :class:`EkfConfig`.

No ROS import.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

__all__ = ['EkfConfig', 'DISCRETISATIONS', 'FORCE_INPUTS', 'ROS_PARAMETERS',
           'changes_from_parameters', 'check_force_input', 'q_parameter']

DISCRETISATIONS = ('midpoint', 'euler')
"""The prediction's f_k: the explicit midpoint rule, or forward Euler (5.8)."""
FORCE_INPUTS = ('acting', 'command')
"""The force the filter predicts with: as the controller manager estimates it acts, or as sent."""


def check_force_input(value: str) -> None:
    """ValueError unless ``value`` is one of :data:`FORCE_INPUTS`."""
    if value not in FORCE_INPUTS:
        raise ValueError(f'force_input must be one of {list(FORCE_INPUTS)}, got {value!r}')


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


def _check_number(name: str, value, positive: bool = False, finite: bool = True) -> None:
    """ValueError unless ``value`` is a number (not a bool) >= 0 (> 0 if ``positive``), finite
    if ``finite`` (else inf is allowed, NaN never)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or (not math.isfinite(value) if finite else math.isnan(value)) \
            or (value <= 0.0 if positive else value < 0.0):
        kind = 'a finite number' if finite else 'a number'
        bound = '> 0' if positive else '>= 0'
        raise ValueError(f'{name} must be {kind} {bound}{"" if finite else " (inf allowed)"}, '
                         f'got {value!r}')


@dataclass(frozen=True)
class EkfConfig:
    """Tuning and safety limits of the EKF (section 5.2, 9.2.1).

    Every field is validated on construction; a bad value raises
    :class:`ValueError` naming it.
    """

    q_diag: tuple[float, float, float, float] = (1.0e-5, 1.0e-5, 0.01, 0.01)
    """Diagonal of Q_k (9.2): covariance added to the state per nominal sample
    period Ts, in m^2, rad^2, (m/s)^2, (rad/s)^2. A step of length h adds
    Q h / Ts."""
    q_force: float = 1.0e6
    """Variance of a random force on the cart per sample period [N^2, on the
    scale of P]; added to Q as ``q_force b b^T`` with b the force's effect on
    the velocities over a step, ``h [1, cos(theta)/l] / (m_c + m_p sin^2 theta)``
    (4.40): the process noise of a friction or force error, which moves the
    cart and the pendulum together as the model couples them. 0 is the
    thesis's diagonal Q (9.2)."""
    push_q_force: float = 1.0e9
    """``q_force`` of a sample whose cart innovation exceeds ``push_innovation``: that
    sample is predicted again with it and corrected (an innovation-gated Q). A push, a
    hand or a stop moves the cart by millimetres within 10-15 ms, far more than the
    model's force error; with ``q_force`` alone the estimate shows a 60 N push 40-50 ms
    late. 0 (or not above ``q_force``) turns it off."""
    push_innovation: float = 1.0e-3
    """|y_x - x_k|k-1| [m] beyond which a sample may count as pushed: above the balancing
    loop's own cart innovations (at most 0.6 mm nominal with noise, 7 encoder ticks)."""
    push_ratio: float = 4.0
    """... and beyond this many times the root mean square of the cart's recent
    innovations (over ``push_window``, the samples taken for pushes left out): a push is
    a change, not the model's error on a plant unlike the model, millimetres all along."""
    push_window: float = 0.5
    """Time constant [s] of that mean square (an exponential average)."""
    push_angle: float = 0.5
    """... and only with the pendulum within this of upright [rad] (about 29 deg, the
    catch window): in the swing-up the cart's innovations are the model's error at full
    force, and a few samples corrected as pushed there change which swing is caught."""
    r_diag: tuple[float, float] = (0.01, 0.1)
    """Diagonal of R_k (9.1): measurement covariance of x [m^2] and theta [rad^2]."""
    p0_diag: tuple[float, float, float, float] = (1.0e-6, 1.0e-5, 1.0e3, 1.0e5)
    """Diagonal of P_0|0 after an (re)initialisation from a measurement:
    positions about one encoder tick; velocities practically unknown (the
    state is initialised with zero velocities, possibly mid-swing), so that
    the next few samples set them: with Q and R of the thesis a prior of
    (1 rad/s)^2 takes about 0.4 s to recover from a reset at 10 rad/s, this
    one about 0.05 s."""
    angle_offset_p0: float = 100.0
    """Variance of the prior of the encoder's angle offset b (Appendix H), on
    the scale of P; 0 leaves the offset state out: the thesis's 4-state filter.
    The filter runs on the scale of the thesis's R (9.1), where R_theta =
    0.1 rad^2 stands for the pendulum encoder's quantisation and noise (about
    3e-6 rad^2 in fact): only ratios matter. 100 is 1000 R_theta, a prior wide
    enough for offsets of 0.1 rad, which the model's gravity then resolves
    within about 0.3 s of a hanging or swinging pendulum."""
    angle_offset_q: float = 1.0e-5
    """Random walk of the offset added per sample period, on the scale of P
    (ignored without the offset state). Small: the offset is a constant of the
    encoder reset; this keeps the estimate from freezing once P_b is small."""
    offset_gate_rate: float = 1.0
    """The offset b is corrected only while |theta_dot| is below this [rad/s] and the
    encoders' angle (m, not m + b: a wrong b must not shut its own gate) within
    ``offset_gate_angle`` of hanging or upright: near an equilibrium,
    where the model's error on a plant unlike it (length, masses, amplifier) does not
    lean on b. Elsewhere b is a considered state (its gain zero, its covariance kept by
    the Joseph form). inf for the rate and the force and pi/2 for the angle: b corrected
    always (as before 2026-12-05)."""
    offset_gate_angle: float = 0.26
    """... within this of hanging or upright [rad] (15 deg; at most pi/2: any angle) ..."""
    offset_gate_force: float = 10.0
    """... and under a force command below this [N] (a kick at full force on an
    amplifier weaker than the model's is read as an offset otherwise)."""
    offset_gate_noise: float = 4.0
    """... unless the pendulum encoder is noisy: with R_theta at or above this times its
    configured value (``noise_window``), b is corrected everywhere. A noisy start leaves
    b hardly known after 0.2 s, and where the encoder's noise outweighs the model's error
    the swing is where b is observed best (with 9-15 mrad of noise the gate alone let
    12 of 36 grid runs swing up, b corrected everywhere 35). inf: never."""
    noise_window: float = 1.0
    """Time constant [s] of the mean of the encoders' scatter (neighbouring second
    differences) near an equilibrium (the offset gate's, no push) to which R is matched,
    never below ``r_diag`` (:mod:`~cartpole_estimation.measurement_noise`). 0: R fixed,
    the thesis's."""
    noise_variance_theta: float = 3.0e-6
    """The real variance of the pendulum angle [rad^2] that R_theta stands for: the scale
    of the filter, by which the measured scatter [m^2, rad^2] compares with R (the
    thesis's R_theta = 0.1 for an encoder of about 1.7 mrad noise and quantisation)."""
    noise_limit: float = 1000.0
    """R never above this times ``r_diag`` (>= 1)."""
    discretisation: str = 'midpoint'
    """f_k of the prediction (5.15): 'midpoint', the explicit midpoint rule
    (second order, one more model evaluation), or 'euler', forward Euler as in
    the thesis (5.8). Euler's error over a 5 ms step of a swinging pendulum is
    the largest model error the filter sees: its velocities lag and the offset
    state takes up a few mrad of it (free swing: theta_dot RMSE 0.071 rad/s
    with Euler, 0.0055 with the midpoint rule). The covariance (5.16) uses the
    Jacobian of the Euler step (5.19) either way."""
    force_input: str = 'acting'
    """The force the adapters (the EKF node, ``cartpole offline``) predict with: 'acting',
    the force the controller manager estimates the cart feels over the interval
    (``cartpole/force_acting``: its commands in flight, each acting the measured latency
    plus the actuator's dead time after its sample, times the estimated gain), or
    'command', the command as sent, applied at once at gain 1 (the thesis's). Without a
    ``force_acting`` for the interval the command is used. The filter takes the force it
    is given."""
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
        if self.discretisation not in DISCRETISATIONS:
            raise ValueError(f'discretisation must be one of {list(DISCRETISATIONS)}, '
                             f'got {self.discretisation!r}')
        check_force_input(self.force_input)
        for name in ('q_force', 'push_q_force', 'angle_offset_p0', 'angle_offset_q'):
            _check_number(name, getattr(self, name))
        for name in ('offset_gate_rate', 'offset_gate_force', 'offset_gate_angle',
                     'offset_gate_noise'):
            _check_number(name, getattr(self, name), finite=False)
        if self.offset_gate_angle > 0.5 * math.pi:
            raise ValueError(f'offset_gate_angle must be <= pi/2, got {self.offset_gate_angle!r}')
        _check_number('noise_window', self.noise_window)
        _check_number('noise_variance_theta', self.noise_variance_theta, positive=True)
        _check_number('noise_limit', self.noise_limit)
        if self.noise_limit < 1.0:
            raise ValueError(f'noise_limit must be >= 1, got {self.noise_limit!r}')
        for name in ('jacobian_step', 'friction_steepness', 'push_innovation', 'push_ratio',
                     'push_window', 'push_angle', 'max_dt',
                     'innovation_sigma', 'max_covariance', 'max_position_excursion'):
            _check_number(name, getattr(self, name), positive=True)
        if self.sample_time is not None and not (
                isinstance(self.sample_time, (int, float)) and math.isfinite(self.sample_time)
                and self.sample_time > 0.0):
            raise ValueError(f'sample_time must be None or a finite number > 0, '
                             f'got {self.sample_time!r}')
        if self.max_covariance <= max(*self.p0_diag, self.angle_offset_p0):
            raise ValueError(f'max_covariance ({self.max_covariance}) must exceed every '
                             f'p0_diag entry {self.p0_diag} and angle_offset_p0')
        if not isinstance(self.innovation_count, int) or self.innovation_count < 1:
            raise ValueError(f'innovation_count must be an integer >= 1, '
                             f'got {self.innovation_count!r}')

    @property
    def estimates_angle_offset(self) -> bool:
        """The filter carries the encoder's angle offset as a fifth state."""
        return self.angle_offset_p0 > 0.0

    def replace(self, **changes) -> 'EkfConfig':
        """Return a copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)


ROS_PARAMETERS = ('q', 'r', 'push_q_force', 'push_innovation', 'friction_steepness',
                  'angle_offset_p0', 'angle_offset_q', 'offset_gate_rate', 'offset_gate_angle',
                  'offset_gate_force', 'offset_gate_noise', 'noise_window',
                  'noise_variance_theta', 'noise_limit', 'discretisation', 'force_input')
"""The ``ekf`` node's parameters that configure the filter (the same names in a
``--params`` file's ``ekf`` section for ``cartpole offline``)."""


def q_parameter(config: EkfConfig) -> list[float]:
    """The ROS parameter ``q``: the diagonal of Q and, as a fifth entry, ``q_force``."""
    return [*config.q_diag, config.q_force]


def changes_from_parameters(values) -> dict:
    """EkfConfig changes from ROS parameter values by name (:data:`ROS_PARAMETERS`).

    ``q`` takes 4 entries, the diagonal of Q with no force noise (the
    thesis's (9.2) is ``q: [1, 1, 50, 50]``), or 5, the fifth being
    ``q_force``. Raises ValueError with the reason on a bad value.
    """
    changes = {}
    for name, value in dict(values).items():
        if name == 'q':
            q = [float(v) for v in value]
            if len(q) not in (4, 5):
                raise ValueError(f'q needs 4 entries (the diagonal of Q) or 5 (and q_force), '
                                 f'got {len(q)}')
            changes['q_diag'] = tuple(q[:4])
            changes['q_force'] = q[4] if len(q) == 5 else 0.0
        elif name == 'r':
            changes['r_diag'] = tuple(float(v) for v in value)
        elif name in ('discretisation', 'force_input'):
            changes[name] = str(value)
        elif name in ROS_PARAMETERS:
            changes[name] = float(value)
    return changes
