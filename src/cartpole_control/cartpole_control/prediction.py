"""Delay compensation by prediction: the state the command will meet, not the state it was computed from.

A command computed from the estimate of sample k acts on the cart only after
the loop's latency ``tau`` (host computation, USB link, amplifier): a state
feedback then acts on a state ``tau`` old, which costs phase margin
(``-omega tau`` at the crossover) and, for the upright pendulum's fast mode,
destabilises the loop well before the sample time does. The cure is to predict the state forward over the known delay with the model
and the commands already sent, and feed the law the prediction (Smith's
predictor; for state feedback the finite spectrum assignment of Manitius &
Olbrot, IEEE TAC 24(4), 1979).

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.prediction``).

No ROS import.
"""
from __future__ import annotations

from typing import Callable, Sequence

Acceleration = Callable[[float, float, float, float, float], tuple[float, float]]


def predict_state(acceleration: Acceleration, x: float, theta: float, x_dot: float,
                  theta_dot: float, force: float, horizon: float
                  ) -> tuple[float, float, float, float]:
    """(x, theta, x_dot, theta_dot) ``horizon`` seconds ahead under ``force``, one midpoint step.

    ``acceleration(x, theta, x_dot, theta_dot, force)`` gives ``(x_ddot,
    theta_ddot)`` of the model (4.18).
    """
    if horizon <= 0.0:
        return x, theta, x_dot, theta_dot
    half = 0.5 * horizon
    x_ddot, theta_ddot = acceleration(x, theta, x_dot, theta_dot, force)
    xm_dot = x_dot + half * x_ddot
    thm_dot = theta_dot + half * theta_ddot
    xm_ddot, thm_ddot = acceleration(x + half * x_dot, theta + half * theta_dot,
                                     xm_dot, thm_dot, force)
    return (x + horizon * xm_dot, theta + horizon * thm_dot,
            x_dot + horizon * xm_ddot, theta_dot + horizon * thm_ddot)


def predict_over_commands(acceleration: Acceleration, x: float, theta: float, x_dot: float,
                          theta_dot: float, segments: Sequence[tuple[float, float]]
                          ) -> tuple[float, float, float, float]:
    """The state at the end of ``segments`` ``[(duration, force), ...]``, one midpoint step each.

    The prediction of the module docstring with the commands in flight:
    each piece holds one command over its duration (a piece is at most a
    sample period long, where one midpoint step is as good as
    :func:`predict_state`).
    """
    for duration, force in segments:
        x, theta, x_dot, theta_dot = predict_state(acceleration, x, theta, x_dot, theta_dot,
                                                   force, duration)
    return x, theta, x_dot, theta_dot
