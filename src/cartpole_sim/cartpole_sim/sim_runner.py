"""The simulator's sampling logic without ROS: sample clock, held command, watchdog.

:class:`SimRunner` wraps a :class:`~cartpole_sim.plant.Plant` the way the simulator node
drives it: the plant is sampled every Ts (5 ms, section 9.2), the latest force command is
held over the next period (zero-order hold), and a watchdog in simulated time sets zero
force when no command has arrived for ``command_timeout`` (50 ms, as the device:
docs/rig.md, "The Joint protocol"). All numerical work stays in the plant; this class only
counts samples and decides which force is held.

The watchdog decides at the sample that crosses the deadline, so the first sample at zero
force comes at most 50 ms after the last command arrived. The sample clock never goes
backwards: a reset puts the plant back to its initial state but the sample index (hence
the stamps and ``/clock``) keeps counting. Why the watchdog counts 9 periods, and how the
node stamps samples after a stall: (docs/simulator.md, "The simulator node").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from cartpole_core.model import CartPoleParameters
from .plant import Measurement, Plant, Scenario

CART_JOINT = 'cart'
PENDULUM_JOINT = 'pendulum'


def force_from_command(names: Sequence[str], efforts: Sequence[float]) -> float | None:
    """The force [N] of a ``/cartpole/force_command`` message, or None if it has none.

    The contract (docs/architecture.md) is ``name=['cart']``, ``effort=[F]``;
    a message without a finite effort for the joint ``cart`` is not a command.
    """
    try:
        index = list(names).index(CART_JOINT)
    except ValueError:
        return None
    if index >= len(efforts):
        return None
    force = float(efforts[index])
    return force if math.isfinite(force) else None


class SampleClock:
    """Real time: the plant sampled every Ts of wall time, as a device on its own clock.

    A rig samples its encoders every Ts whatever the host does; a host that
    stalls (a loaded machine, a descheduled process) receives the samples it
    missed late, in a burst, each stamped with its own sample time. The
    simulator does the same: :meth:`due` says which sample index wall time
    has reached, the node steps the plant up to it (a late timer steps it
    several times, with the held command and the watchdog deciding the force
    of each period), and :meth:`stamp_ns` stamps sample k with
    ``t_0 + (k - k_0) Ts``: the stamps are the plant's time, exactly Ts apart,
    so the EKF, which integrates over stamp differences, predicts over the
    time the plant really moved. (Stamping each sample with the host clock
    when it is published made a late sample look like a long period with a
    plant that had moved only one Ts.)
    """

    def __init__(self, period_ns: int) -> None:
        self.period_ns = int(period_ns)
        self._origin: tuple[int, int, int] | None = None

    @property
    def started(self) -> bool:
        return self._origin is not None

    def start(self, steady_ns: int, stamp_ns: int, index: int) -> None:
        """Sample ``index`` is due at ``steady_ns`` (a steady clock) and stamped ``stamp_ns``."""
        self._origin = (int(steady_ns), int(stamp_ns), int(index))

    def due(self, steady_ns: int) -> int:
        """The last sample index due at ``steady_ns`` (a tenth of Ts early counts as due:
        a timer's call that comes a hair before its period still takes its sample)."""
        steady0, _, index0 = self._origin
        return index0 + (int(steady_ns) - steady0 + self.period_ns // 10) // self.period_ns

    def stamp_ns(self, index: int) -> int:
        """Stamp of sample ``index`` [ns]: t_0 + (index - k_0) Ts."""
        _, stamp0, index0 = self._origin
        return stamp0 + (int(index) - index0) * self.period_ns


@dataclass(frozen=True)
class Sample:
    """One published sample: index, stamp and what the plant shows then."""

    index: int
    stamp_ns: int
    measurement: Measurement
    true_state: tuple[float, float, float, float]
    actuator_force: float
    end_stop_force: float = 0.0
    """The stops' peak spring force on the cart over the period that ended here
    [N]; 0.0 unless the cart was pressed into a stop (:attr:`Plant.end_stop_force`)."""
    lost: bool = False
    """The sample is lost on its way to the host (scenario ``drop``,
    :meth:`Plant.sample_lost`): not published, and no command is awaited for it."""


class SimRunner:
    """Plant plus sample clock, held command and command watchdog.

    Parameters
    ----------
    params : CartPoleParameters
        Nominal plant parameters (``sample_time`` is Ts).
    scenario : Scenario
        Initial state and uncertainties of the run.
    integration_step : float
        RK4 step of the plant [s].
    command_timeout : float
        Simulated seconds after the last command at which the held force
        falls to zero (watchdog).
    """

    def __init__(self, params: CartPoleParameters, scenario: Scenario,
                 integration_step: float = 0.001, command_timeout: float = 0.05) -> None:
        self.plant = Plant(params=params, scenario=scenario, integration_step=integration_step)
        self.sample_period_ns = int(round(params.sample_time * 1e9))
        self.command_timeout = float(command_timeout)
        self.index = 0
        self.steps = 0
        self.watchdog_trips = 0
        self._held_force = 0.0
        self._command_index: int | None = None
        self._watchdog_tripped = False
        self._source_ns: int | None = None
        self.applied: list[tuple[int, int, int]] = []
        """``(source_ns, index, offset_ns)``: the command computed from the sample
        stamped ``source_ns`` took effect ``offset_ns`` after sample ``index`` (at the
        start of the next period, or later with a scenario delay): the plant's report
        of the loop's latency; its reader clears it."""
        self._sample = self._take_sample()

    # -- clock ---------------------------------------------------------------------
    @property
    def params(self) -> CartPoleParameters:
        return self.plant.params

    @property
    def stamp_ns(self) -> int:
        """Simulated time of the current sample [ns]: index x Ts."""
        return self.index * self.sample_period_ns

    @property
    def sample(self) -> Sample:
        """The current sample (taken once, so the encoders' noise is drawn once)."""
        return self._sample

    # -- commands ------------------------------------------------------------------
    def command(self, force: float, source_ns: int | None = None) -> None:
        """Hold ``force`` [N] from now on (received while the current sample is out).

        ``source_ns``: the stamp of the sample the command was computed from;
        when the command takes effect it is listed in :attr:`applied`.
        """
        self._held_force = float(force) if math.isfinite(force) else 0.0
        self._source_ns = source_ns
        self._command_index = self.index
        self._watchdog_tripped = False

    def held_force(self) -> float:
        """The force command applied over the next period, after the watchdog.

        Zero when the sample closing the *next* period, ``index + 2``, would
        come later than ``command_timeout`` after the command (which acts from
        ``t_{command_index}``), i.e. when this period's closing sample is the
        last one inside the deadline; a command is always held over the
        period it arrived in.
        """
        if self._command_index is None:
            return 0.0
        periods = self.index - self._command_index
        if periods > 0 and (periods + 2) * self.params.sample_time > self.command_timeout + 1e-12:
            if not self._watchdog_tripped:
                self._watchdog_tripped = True
                self.watchdog_trips += 1
            return 0.0
        return self._held_force

    @property
    def watchdog_tripped(self) -> bool:
        return self._watchdog_tripped

    # -- stepping ------------------------------------------------------------------
    def advance(self) -> Sample:
        """Step the plant one Ts with the held command and sample it (index + 1)."""
        force = self.held_force()
        source = self._source_ns if force == self._held_force else None
        self._source_ns = None
        plant = self.plant
        start = plant.t
        plant.step(force, None, source)
        for tag, applied in plant.applied_commands():
            self.applied.append((tag, self.index, int(round((applied - start) * 1e9))))
        self.index += 1
        self.steps += 1
        self._sample = self._take_sample()
        return self._sample

    def reset(self, params: CartPoleParameters | None = None,
              scenario: Scenario | None = None,
              integration_step: float | None = None) -> Sample:
        """Plant back to the scenario's initial state (new parameters if given).

        The held command is dropped (zero force) and the sample index moves on
        by one, so the reset state is a new sample with a later stamp.
        """
        if params is not None or scenario is not None or integration_step is not None:
            new_params = self.plant.params if params is None else params
            if int(round(new_params.sample_time * 1e9)) != self.sample_period_ns:
                raise ValueError('sample_time cannot change at a reset')
            self.plant = Plant(
                params=new_params,
                scenario=self.plant.scenario if scenario is None else scenario,
                integration_step=(self.plant.integration_step if integration_step is None
                                  else integration_step))
        else:
            self.plant.reset()
        self._held_force = 0.0
        self._command_index = None
        self._watchdog_tripped = False
        self._source_ns = None
        self.index += 1
        self._sample = self._take_sample()
        return self._sample

    def _take_sample(self) -> Sample:
        return Sample(index=self.index, stamp_ns=self.stamp_ns,
                      measurement=self.plant.measure(),
                      true_state=tuple(float(v) for v in self.plant.state),
                      actuator_force=self.plant.force,
                      end_stop_force=self.plant.end_stop_force,
                      lost=self.plant.sample_lost())
