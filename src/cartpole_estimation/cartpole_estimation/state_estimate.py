"""The EKF's output for one sample: :class:`StateEstimate` and its fast constructor.

No ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ['StateEstimate']


@dataclass(frozen=True, slots=True)
class StateEstimate:
    """The filter's output for one sample (all SI units).

    ``theta`` is continuous (not wrapped), the pendulum's angle itself, the
    encoder's offset (Appendix H) taken out when the filter estimates it;
    ``theta_w`` is it wrapped to (-pi, pi]. ``x_ddot``/``theta_ddot`` are the model accelerations
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
    """Variances of x, theta, x_dot, theta_dot in P_k|k (5.14)."""
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
    angle_offset: float = 0.0
    """b, the estimated offset of the pendulum encoder (Appendix H): the
    measured angle is theta - b [rad]; 0.0 without the offset state."""

    def as_array(self) -> np.ndarray:
        """The state [x, theta, x_dot, theta_dot] (4.34)."""
        return np.array([self.x, self.theta, self.x_dot, self.theta_dot])


_ESTIMATE_FIELDS = ('t', 'x', 'theta', 'x_dot', 'theta_dot', 'theta_w', 'x_ddot', 'theta_ddot',
                    'covariance_diagonal', 'innovation', 'dt', 'missed_samples',
                    'missed_samples_total', 'reset', 'reset_reason', 'resets', 'rejected',
                    'warning', 'valid', 'angle_offset')


def _estimate_factory():
    """A positional constructor of :class:`StateEstimate`, all 20 fields in order.

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
     s18, s19) = setters
    new = object.__new__

    def make(t, x, theta, x_dot, theta_dot, theta_w, x_ddot, theta_ddot, covariance_diagonal,
             innovation, dt, missed_samples, missed_samples_total, reset, reset_reason, resets,
             rejected, warning, valid, angle_offset) -> StateEstimate:
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
        s19(est, angle_offset)
        return est

    return make


_new_estimate = _estimate_factory()
