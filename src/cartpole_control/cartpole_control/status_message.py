"""The ``cartpole/controller_status`` message of one control cycle (diagnostic_msgs).

One DiagnosticStatus ``controller_manager`` per cycle, with the keys of
:data:`cartpole_control.manager.STATUS_KEYS` in that order and the active
plugins' own figures after them: the loop's 200 Hz telemetry, which
``cartpole analyze`` and the run summary read from the bag.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from cartpole_core.diagnostics import plain

from .manager import FAULT, STATUS_KEYS, ManagerOutput

NODE_NAME = 'controller_manager'


def _stamp_seconds(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


def status_message(out: ManagerOutput, stamp, longest_cycle_gap: float = 0.0,
                   extra_event: str = '', cycle_compute: float = 0.0,
                   max_cycle_compute: float = 0.0) -> DiagnosticArray:
    """The ``/cartpole/controller_status`` message of one cycle (counts as integers, other
    numbers as repr(float)).

    ``extra_event`` (the node's own, e.g. ``plant_reset``) goes before the
    manager's events in ``event``.
    """
    event = ';'.join(e for e in (extra_event, out.event) if e)
    if out.mode == FAULT:
        level = DiagnosticStatus.ERROR
    else:  # idle (control disabled, or the run stopped) is no trouble
        level = DiagnosticStatus.OK
    values = {
        'mode': out.mode,
        'swingup': out.swingup,
        'stabilizer': out.stabilizer,
        'enabled': 'true' if out.enabled else 'false',
        'energy': repr(float(out.energy)),
        'energy_error': repr(float(out.energy_error)),
        'raw_force': repr(float(out.raw_force)),
        'feedforward': repr(float(out.feedforward)),
        'force': repr(float(out.force)),
        'catch_count': plain(out.catch_count),
        'fall_count': plain(out.fall_count),
        'event': event,
        'state_stamp': repr(_stamp_seconds(stamp)),
        'swingup_law': out.swingup_law,
        'longest_cycle_gap_s': repr(float(longest_cycle_gap)),
        'cycle_compute_s': repr(float(cycle_compute)),
        'max_cycle_compute_s': repr(float(max_cycle_compute)),
        'latency_s': repr(float(out.latency)),
        'predict_horizon_s': repr(float(out.horizon)),
        'omega0_sq': repr(float(out.omega_sq)),
        'actuator_gain': repr(float(out.actuator_gain)),
        'actuator_delay_s': repr(float(out.actuator_delay)),
        'friction_scale': repr(float(out.friction_scale)),
    }
    status = DiagnosticStatus(level=level, name=NODE_NAME, message=out.mode,
                              hardware_id='cartpole',
                              values=[KeyValue(key=k, value=values[k]) for k in STATUS_KEYS]
                              + [KeyValue(key=k, value=repr(float(v)))
                                 for k, v in out.plugin_status.items()])
    array_msg = DiagnosticArray(status=[status])
    array_msg.header.stamp = stamp
    return array_msg
