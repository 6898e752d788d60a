"""What one control cycle of the controller manager decides, and the status it reports.

:class:`ManagerOutput` is the controller status of docs/architecture.md ("ROS
interfaces"); :class:`SetResult` answers a parameter change or a restart.

No ROS import.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Mapping

IDLE = 'idle'
SWINGUP_MODE = 'swingup'
STABILIZING = 'stabilizing'
FAULT = 'fault'
MODES = (IDLE, SWINGUP_MODE, STABILIZING, FAULT)
"""The manager's modes: disabled, swinging up, balancing, faulted (zero force)."""
STATUS_KEYS = ('mode', 'swingup', 'stabilizer', 'enabled', 'energy', 'energy_error', 'raw_force',
               'feedforward', 'force', 'catch_count', 'fall_count', 'event', 'state_stamp',
               'swingup_law', 'longest_cycle_gap_s', 'cycle_compute_s', 'max_cycle_compute_s',
               'latency_s', 'predict_horizon_s', 'omega0_sq', 'actuator_gain',
               'actuator_delay_s', 'friction_scale')
"""The KeyValues of the controller status, in this order (docs/architecture.md), published by the node as
``/cartpole/controller_status``; the
active plugin's own figures (:meth:`Controller.status_values`, e.g. ``mpc_solve_us``)
follow them."""
LOOP_FIGURES = ('latency_s', 'predict_horizon_s', 'omega0_sq', 'actuator_gain',
                'actuator_delay_s', 'friction_scale')
"""What the manager learns of the loop and reports in the status and the run summary."""


@dataclass(frozen=True)
class SetResult:
    """Outcome of :meth:`ControllerManager.set_parameters` (like rcl's SetParametersResult)."""

    successful: bool
    reason: str = ''


@dataclass(frozen=True)
class ManagerOutput:
    """Everything one control cycle decided (the controller status of docs/architecture.md,
    "ROS interfaces")."""

    t: float
    force: float
    """The force command [N] after feedforward, saturation and rail guard."""
    mode: str
    swingup: str
    stabilizer: str
    enabled: bool
    energy: float
    """E_p, the pendulum energy (7.3) [J]."""
    energy_error: float
    """E* - E_p [J]."""
    raw_force: float
    """The active plugin's output u [N] (0 when none runs)."""
    feedforward: float
    """B_ff(x_dot, u) of (6.12) [N]."""
    event: str
    """'' or 'catch', 'fall', 'restart', 'fault:<reason>', 'switch:<kind>=<name>'
    (several in one cycle joined by ';')."""
    catch_count: int
    fall_count: int
    catch_time: float | None
    """Time of the first catch since :meth:`ControllerManager.reset`, or None."""
    fault_reason: str
    swingup_law: str = ''
    """What the swing-up plugin runs (:attr:`Controller.law`): its name, or e.g.
    ``time_optimal:plan`` / ``time_optimal:fallback(no plan)``; the last one
    that ran while another mode is active."""
    latency: float = 0.0
    """The loop's measured sensor-to-actuator latency [s] (0 before enough reports)."""
    horizon: float = 0.0
    """The prediction horizon this cycle used [s]: the latency with ``predict.horizon``
    ``auto``, else the fixed value."""
    omega_sq: float = 0.0
    """The estimate of the pendulum's omega_0^2 = m_p g l / J [1/s^2]."""
    actuator_gain: float = 1.0
    """The actuator gain G the command was divided by (``actuator.gain``)."""
    actuator_delay: float = 0.0
    """The estimate of the actuator's extra dead time [s] (used with ``actuator.delay`` auto)."""
    friction_scale: float = 1.0
    """The estimate of the cart friction's scale S (used with ``actuator.friction`` auto)."""
    plugin_status: Mapping[str, float] = dataclasses.field(default_factory=dict)
    """The active plugin's :meth:`Controller.status_values` (e.g. ``mpc_solve_us``)."""


def restart_answer(mode: str, enabled: bool, fault_reason: str, braking: bool) -> SetResult:
    """What a restart request in ``mode`` will do, said truthfully for the service reply.

    ``successful`` is False when there is nothing to restart (control running,
    or idle because ``enabled`` is false); ``braking``: the rail guard is still
    braking the cart.
    """
    if mode == FAULT:
        cleared = f'fault ({fault_reason}) cleared' if fault_reason \
            else 'fault cleared'
        if not enabled:
            return SetResult(True, f'{cleared}; control is disabled (enabled = false), '
                                   'staying idle')
        if braking:
            return SetResult(True, f'{cleared}; swing-up restarts once the rail guard has '
                                   'braked the cart to rest')
        return SetResult(True, f'{cleared}; swing-up restarts at the next control cycle')
    if mode == IDLE:
        if not enabled:
            return SetResult(False, 'nothing to restart: control is disabled (enabled = '
                                    'false); set enabled to true to start a swing-up')
        return SetResult(True, 'swing-up starts at the next control cycle')
    if not enabled:
        return SetResult(False, f'nothing to restart: control ({mode}) is being disabled '
                                '(enabled = false)')
    return SetResult(False, f'already running ({mode}); nothing to restart')
