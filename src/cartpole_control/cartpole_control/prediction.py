"""Delay compensation by prediction: the state the command will meet, not the state it was computed from.

A command computed from the estimate of sample k acts on the cart only after
the loop's latency ``tau`` (host computation, USB link, amplifier): a state
feedback then acts on a state ``tau`` old, which costs phase margin
(``-omega tau`` at the crossover) and, for the upright pendulum's fast mode,
destabilises the loop well before the sample time does. The classic cure is
to predict the state forward over the known delay with the model and the
commands already sent, and feed the law the prediction: Smith's predictor
(O. J. M. Smith, "Closer control of loops with dead time", Chem. Eng. Prog.
53, 1957), for state feedback the "finite spectrum assignment" of Manitius &
Olbrot (IEEE TAC 24(4), 1979), whose predictor is

    x_hat(t + tau) = x(t) + int_t^{t+tau} f(x(s), u(s - tau)) ds.

Here the integral is one midpoint (RK2) step of the nominal model (4.18),
the same equations the EKF predicts with (:func:`cartpole_core.model.
acceleration_function`), under the last force command (the command in
flight; with a zero-order hold it is the one the plant applies next):

    k_1 = f(x, F),  x_m = x + tau/2 k_1,  x_hat = x + tau f(x_m, F).

``tau = 0`` is the thesis's loop (no prediction). An over-estimate of the
delay acts as a phase lead, an under-estimate leaves the rest of the delay
uncompensated. The horizon is the parameter ``predict.horizon``: ``auto``
(the default) is the latency the loop measures while it runs
(:mod:`cartpole_control.latency`: the plant reports when each command took
effect), a number fixes it.

With a horizon longer than a sample period several commands are in flight:
the cart feels, over ``[t, t + tau]``, the commands computed from the samples
of ``[t - tau, t)``, each from its own arrival on.
:func:`predict_over_commands` integrates under that piecewise-constant force
(:meth:`cartpole_control.latency.CommandsInFlight.segments`), one midpoint
step a piece; :func:`predict_state` is the one-piece case.

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
