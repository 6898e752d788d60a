"""A recording's force commands replayed on the simulated plant (no ROS)."""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from cartpole_core.model import CartPoleParameters
from cartpole_sim.plant import Plant, Scenario

from .recording import Recording, quiet_lead_in, estimate_initial_state

INITIAL_STATE_SCALE = (1.0e-3, 1.0e-2, 1.0e-2, 1.0e-1)
"""Scales of the per-recording initial state offsets [m, rad, m/s, rad/s]."""

_DIVERGED = 10.0
"""Residual [m or rad] used in place of a non-finite simulated sample."""



def fit_initial_state(rec: Recording, params: CartPoleParameters, *, window: float = 0.5,
                      weight_cart: float = 1.0, weight_pendulum: float | None = None,
                      integration_step: float = 0.001) -> np.ndarray:
    """[x, theta, x_dot, theta_dot] at ``rec.t[0]`` fitted to the start of the recording.

    Least squares of the simulated (:func:`simulate`, with ``params``) minus
    measured positions over the quiet lead-in (:func:`quiet_lead_in`: up to
    ``window`` s, ending at the first non-zero force command, so the fit
    sees no pulse whose response depends on the parameters being sought),
    starting from :func:`estimate_initial_state`. The model carries the
    estimate through the quantisation steps (a pendulum released from rest
    moves less than a tick in its first 10 ms), so a free swing starts with
    the right phase. With fewer than 10 quiet samples the quadratic estimate
    is returned as it is.
    """
    from scipy.optimize import least_squares

    guess = estimate_initial_state(rec)
    n = quiet_lead_in(rec, window)
    if n < 10:
        return guess
    head = Recording(rec.t[:n], rec.x[:n], rec.theta[:n], rec.force[:n], rec.label)
    w_theta = params.l if weight_pendulum is None else weight_pendulum
    w_x = weight_cart if weight_cart > 0 else 1.0
    w_theta = w_theta if w_theta > 0 else params.l
    scale = np.array(INITIAL_STATE_SCALE)
    lo = np.array([-guess[0] / scale[0], -np.inf, -np.inf, -np.inf])
    hi = np.array([(params.travel - guess[0]) / scale[0], np.inf, np.inf, np.inf])
    z0 = np.clip(np.zeros(4), lo + 1e-9, hi - 1e-9)

    def fun(z: np.ndarray) -> np.ndarray:
        xs, thetas = simulate(head, params, guess + z * scale, integration_step)
        r = np.concatenate([w_x * (xs - head.x), w_theta * (thetas - head.theta)])
        return np.nan_to_num(r, nan=_DIVERGED, posinf=_DIVERGED, neginf=-_DIVERGED)

    sol = least_squares(fun, z0, bounds=(lo, hi), method='trf', diff_step=1e-3,
                        x_scale=1.0, max_nfev=50)
    return guess + sol.x * scale


def simulate(rec: Recording, params: CartPoleParameters, initial_state: Sequence[float],
             integration_step: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Replay a recording's force commands on the plant: simulated (x, theta) at ``rec.t``.

    The plant (:class:`~cartpole_sim.plant.Plant`: actuator (4.4),
    saturation, end stops, mechanics (4.18)) starts from ``initial_state``
    (the cart clipped into the travel, so a start measured against a stop
    does not begin inside the stop's spring) and holds ``rec.force[k]`` over
    ``[t[k], t[k + 1])``. The true (unquantised) positions are returned;
    samples after a non-finite state are NaN.
    """
    x0, theta0, x_dot0, theta_dot0 = (float(v) for v in initial_state)
    x0 = min(max(x0, 0.0), params.travel)
    plant = Plant(params, Scenario(x0=x0, theta0=theta0, x_dot0=x_dot0, theta_dot0=theta_dot0),
                  integration_step=min(integration_step, params.sample_time))
    n = rec.t.size
    xs = np.full(n, np.nan)
    thetas = np.full(n, np.nan)
    dts = np.diff(rec.t)
    force = rec.force
    for k in range(n):
        state = plant.state
        if not (math.isfinite(state[0]) and math.isfinite(state[1])):
            break
        xs[k] = state[0]
        thetas[k] = state[1]
        if k < n - 1:
            plant.step(float(force[k]), float(dts[k]))
    return xs, thetas


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square of a - b (inf if any value is not finite)."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return float(np.sqrt(np.mean(d * d))) if np.all(np.isfinite(d)) else math.inf
