"""One encoder tick's effect on the force command, measured: the chatter that
docs/controllers.md, "lqg", describes.

While balancing, the pendulum sits within a tick or two of upright, and the
measured angle steps by a whole tick (2 pi / 2000 rad) now and then. What
the stabiliser commands in answer is the floor of its chatter: the filter's
gain from that step to the angle and rate estimates, times K_theta and
K_theta_dot, plus the feedforward (6.12) if the command changes sign.

:func:`tick_response` runs the EKF and the controller manager, without a
plant, at the upright equilibrium: the cart at rest at x*, the pendulum
measured exactly upright, zero force, until the filter has settled; then the
pendulum encoder reads one tick more and stays there. The loop is open (the
force does not move anything), so the numbers are the step response of the
estimator and the law alone, the same for every run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from cartpole_control.controllers.lqg import ROBUST_GAIN
from cartpole_control.manager import STABILIZING, ControllerManager
from cartpole_estimation.ekf import EkfConfig, ExtendedKalmanFilter
from cartpole_core.model import CartPoleParameters

SETTLE_S = 2.0
"""Samples at equilibrium before the tick [s]."""
WINDOW_S = 0.05
"""The response is followed for this long after the tick [s]."""


@dataclass(frozen=True)
class TickResponse:
    """The command's answer to one pendulum encoder tick (see the module docstring)."""

    first_n: float
    """Force change at the first sample after the tick [N]."""
    peak_n: float
    """Largest |force change| within :data:`WINDOW_S` [N]."""
    feedforward_n: float
    """Largest |feedforward change| within the window [N] (6.12's sign flip shows here)."""
    theta_dot_step: float
    """Largest |theta_dot estimate| within the window [rad/s]."""


def tick_response(manager_parameters: Mapping[str, Any] | None = None,
                  ekf_config: EkfConfig | None = None,
                  params: CartPoleParameters | None = None) -> TickResponse:
    """The stabiliser's force after one tick of the pendulum encoder, from equilibrium."""
    params = params or CartPoleParameters()
    ekf = ExtendedKalmanFilter(params, ekf_config or EkfConfig())
    manager = ControllerManager(params, params.sample_time, **dict(manager_parameters or {}))
    x_ref = float(manager.get_parameters()['x_ref'])
    ts = params.sample_time
    tick = params.pendulum_resolution
    settle = int(round(SETTLE_S / ts))
    before = None
    first = peak = ff_peak = rate_peak = 0.0
    for k in range(settle + int(round(WINDOW_S / ts)) + 1):
        theta = 0.0 if k < settle else tick
        est = ekf.update(k * ts, x_ref, theta, 0.0)
        out = manager.update_values(est.t, est.x, est.theta, est.x_dot, est.theta_dot)
        if out.mode != STABILIZING:
            raise RuntimeError(f'the manager is not stabilising at upright rest: {out.mode}')
        if k == settle - 1:
            before = out
        elif k >= settle:
            change = out.force - before.force
            if k == settle:
                first = change
            peak = max(peak, abs(change))
            ff_peak = max(ff_peak, abs(out.feedforward - before.feedforward))
            rate_peak = max(rate_peak, abs(est.theta_dot))
    return TickResponse(first, peak, ff_peak, rate_peak)


THESIS_SETTINGS: dict[str, tuple[dict[str, Any], EkfConfig]] = {
    "thesis: LQR (8.24), EKF (9.1)/(9.2), feedforward (6.12)": (
        {'lqg.q': [100.0, 400.0, 100.0, 400.0], 'feedforward.velocity_band': 0.0},
        EkfConfig(q_diag=(1.0, 1.0, 50.0, 50.0), q_force=0.0, push_q_force=0.0,
                  angle_offset_p0=0.0, discretisation='euler')),
    "earlier default: LQR Q = diag(400, 400, 400, 400), thesis EKF and feedforward": (
        {'lqg.q': [400.0, 400.0, 400.0, 400.0], 'feedforward.velocity_band': 0.0},
        EkfConfig(q_diag=(1.0, 1.0, 50.0, 50.0), q_force=0.0, push_q_force=0.0,
                  angle_offset_p0=0.0, discretisation='euler')),
    "robust gain (lqg's default until 2026-12-05): LQI, EKF with force noise and offset "
    "state, velocity band": ({f'lqg.{k}': v for k, v in ROBUST_GAIN.items()}, EkfConfig()),
    "default: the precise gain (pendulum weights x3), the same EKF and feedforward": (
        {}, EkfConfig()),
}
"""The settings of the README's table, by label."""


def tick_table(settings: Mapping[str, tuple[dict[str, Any], EkfConfig]] = THESIS_SETTINGS
               ) -> list[str]:
    """Markdown lines: one row a setting, its :class:`TickResponse`."""
    out = [f'| setting | first sample [N] | peak within {1000 * WINDOW_S:g} ms [N] '
           '| of it feedforward [N] | theta_dot estimate [rad/s] |', '|---|---|---|---|---|']
    for label, (parameters, config) in settings.items():
        r = tick_response(parameters, config)
        out.append(f'| {label} | {r.first_n:+.2f} | {r.peak_n:.2f} | {r.feedforward_n:.2f} '
                   f'| {r.theta_dot_step:.3f} |')
    return out


def main() -> None:  # pragma: no cover - a documentation helper: python -m ...tick_response
    print('\n'.join(tick_table()))
    print(f'(one tick = {math.degrees(CartPoleParameters().pendulum_resolution):.3f} deg)')


if __name__ == '__main__':  # pragma: no cover
    main()
