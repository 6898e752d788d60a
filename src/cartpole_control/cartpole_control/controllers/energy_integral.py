"""Integral action on the energy error, shared by the two energy swing-ups (section 7.3).

Both the pendulum energy law (7.32) and the full energy law (7.27) add
``k_i int_0^t (E* - E) dt`` to remove the steady-state energy error of the
proportional law (section 7.3.2), with E the pendulum energy (7.3) or the
system energy (7.11). The integral starts from zero at every activation (a
new swing-up), is stepped on the states' stamps (:class:`StepClock`) and is
clamped to ``+-i_max`` (anti-windup, not in the thesis: the energy error
changes sign only after E* is reached, so an unbounded integral keeps pumping
and overshoots); a law may also hold it where it should not integrate (conditional
integration: ``pendulum_energy`` far from E*). No rclpy.
"""
from __future__ import annotations

from abc import abstractmethod

from ..controller import SWINGUP, Controller, ControllerState, ParameterSpec
from . import StepClock


def i_max_parameter(default: float, energy: str) -> ParameterSpec:
    """The ``i_max`` tunable: the bound of ``int (E* - <energy>) dt`` [J s]."""
    return ParameterSpec('i_max', default, f'anti-windup: bound of the energy-error integral '
                         f'int (E* - {energy}) dt [J s] (not in the thesis)', low=0.0, high=1000.0)


class EnergyIntegralSwingUp(Controller):
    """Base of a swing-up law with integral action on its energy error E* - E.

    Subclasses define :meth:`energy_error` and list :func:`i_max_parameter`
    among their parameters; :meth:`integrate` steps :attr:`integral`.
    """

    kind = SWINGUP
    running_state = ('integral', '_clock')

    def __init__(self) -> None:
        super().__init__()
        self.integral = 0.0
        """int_0^t (E* - E) dt [J s] since activation, within +-i_max."""
        self._clock = StepClock()

    def on_activate(self, state: ControllerState) -> None:
        """Start a new swing-up: the energy integral starts from zero now."""
        self.integral = 0.0
        self._clock.reset(state.t)

    @abstractmethod
    def energy_error(self, state: ControllerState) -> float:
        """E* - E of the law's energy [J]."""

    def integrate(self, state: ControllerState, error: float, active: bool = True) -> float:
        """Add ``error`` over the step to ``state``, clamp to +-i_max; the new integral [J s].

        While not ``active`` the step passes and the integral holds (conditional integration).
        """
        dt = self._clock.step(state.t, self.context.sample_time)
        if active:
            i_max = self.gains['i_max']
            self.integral = max(-i_max, min(i_max, self.integral + error * dt))
        return self.integral
