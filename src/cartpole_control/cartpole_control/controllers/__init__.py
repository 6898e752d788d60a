"""The controller plugins of the thesis, one module a law.

Swing-up laws (chapter 7), entry-point group ``cartpole_control.swingup``:

- :mod:`.pendulum_energy` -- pendulum energy method with integral action and
  cart P-term (7.32);
- :mod:`.full_energy` -- full energy method with integral action (7.27) and
  the singularity guard (7.28)-(7.30);
- :mod:`.sign_based` -- sign-based method (7.36), sign replaced by a saturation.

Design notes: docs/controller_manager.md ("Design notes by module", ``cartpole_control.controllers``).
"""
from __future__ import annotations

import math

from cartpole_core import model
from cartpole_core.model import CartPoleParameters, force_for_acceleration

from ..controller import CommandFeedback, ControlContext, ControllerState, ParameterSpec

__all__ = ['acceleration_to_force', 'saturation', 'StepClock', 'ConditionalIntegrator',
           'ADAPTIVE_TARGET', 'energy_and_target']

ADAPTIVE_TARGET = ParameterSpec(
    'adaptive_target', True, "aim at the energy that reaches the top of the pendulum on the "
    "rig: E_p (7.3) and E* (6.8) with its natural frequency omega_0^2 = m_p g l / J estimated "
    "on line from the encoders (cartpole_control.natural_frequency), which the catch trigger "
    "(6.4) then uses too; false: the thesis's fixed E* = 2 m_p g l [J] of the nominal model")
"""The energy laws' switch between the estimated pendulum's target and the thesis's."""


def energy_and_target(theta: float, theta_dot: float, context: ControlContext,
                      adaptive: bool) -> tuple[float, float]:
    """(E_p, E*) of (7.3)/(6.8): of the estimated pendulum if ``adaptive`` and the
    context carries the manager's estimate, else of the nominal model."""
    pendulum = context.pendulum
    if adaptive and pendulum is not None:
        return pendulum.energy(theta, theta_dot), pendulum.upright_energy
    p = context.plant
    # (model.pendulum_energy: the name pendulum_energy here is the submodule of that law)
    return model.pendulum_energy(theta, theta_dot, p), p.upright_energy


def acceleration_to_force(u: float, state: ControllerState, params: CartPoleParameters) -> float:
    """Force [N] for a desired cart acceleration ``u`` [m/s^2], (7.10) (section 7.1.1).

    As in the thesis, ``theta``, ``theta_dot`` and ``theta_ddot`` come from the
    estimate; ``theta_ddot`` is the model's angular acceleration under the
    last applied force (:attr:`ControllerState.theta_ddot`).
    """
    return force_for_acceleration(u, state.theta, state.theta_dot, state.theta_ddot, params)


def saturation(value: float) -> float:
    """sat(v) = v clipped to [-1, 1], the continuous replacement of sgn(v)."""
    return max(-1.0, min(1.0, value))


class StepClock:
    """Time since the previous update, for the discrete integrators.

    The step is the difference of the states' stamps; the first update after
    :meth:`reset`, a stamp that does not increase, or a gap longer than
    ``max_gap`` uses the nominal sample time instead (a gap is not integrated).
    """

    def __init__(self, max_gap: float = 0.1) -> None:
        self.max_gap = max_gap
        self._last: float | None = None

    def reset(self, t: float | None = None) -> None:
        self._last = t

    def step(self, t: float, sample_time: float) -> float:
        last, self._last = self._last, t
        if last is None or not math.isfinite(t):
            return sample_time
        dt = t - last
        if not (0.0 < dt <= self.max_gap):
            return sample_time if dt > self.max_gap else 0.0
        return dt


class ConditionalIntegrator:
    """``value = int e dt`` with anti-windup by conditional integration.

    Each cycle :meth:`step` adds ``e dt`` at once (the law's force of this
    cycle already contains it, no extra delay) and remembers how much that
    increment changed the force (``effect``, [N], from the law's gain on the
    integral). :meth:`feedback`, with the manager's
    :class:`~cartpole_control.controller.CommandFeedback` of the same cycle,
    takes the increment back when the command was limited in the direction
    the increment pushed it, or held by the rail guard (the classic
    conditional integration, e.g. Astrom & Hagglund, "Advanced PID control",
    section 3.5). Without feedback (a law used without the manager) it is a
    plain integrator. :meth:`reset` starts from zero: bumpless activation,
    the first force equals the law without its integral.
    """

    __slots__ = ('value', '_previous', '_effect')

    def __init__(self) -> None:
        self.value = 0.0
        self._previous = 0.0
        self._effect = 0.0

    def reset(self) -> None:
        self.value = self._previous = self._effect = 0.0

    def step(self, error: float, dt: float, force_per_unit: float) -> float:
        """Add ``error dt``; ``force_per_unit`` is d(force)/d(value) of the law [N per unit]."""
        self._previous = self.value
        increment = error * dt
        self.value += increment
        self._effect = force_per_unit * increment
        return self.value

    def hold(self) -> None:
        """Take back this cycle's increment (the law's own limit was reached)."""
        self.value = self._previous
        self._effect = 0.0

    def feedback(self, feedback: CommandFeedback) -> None:
        """Take back this cycle's increment if ``feedback.blocks`` it."""
        if feedback.blocks(self._effect):
            self.value = self._previous
        self._previous = self.value
        self._effect = 0.0


def integral_property(attribute: str, doc: str) -> property:
    """A property for the value of the :class:`ConditionalIntegrator` ``self.<attribute>``.

    Reading gives its ``value``; setting it (a test, a take-over of a running
    state) resets the integrator and starts it from the given value.
    """
    def get(self: object) -> float:
        return getattr(self, attribute).value

    def put(self: object, value: float) -> None:
        integrator = getattr(self, attribute)
        integrator.reset()
        integrator.value = float(value)

    return property(get, put, doc=doc)
