"""The EKF's output for one sample: :class:`StateEstimate`.

No ROS import.
"""
from __future__ import annotations

from dataclasses import dataclass

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
