"""The controller manager's parameters as ROS parameters: descriptors and value conversions.

Every :class:`~cartpole_control.controller.ParameterSpec` (the manager's and each
plugin's) becomes a ROS parameter with a descriptor that states its range or
choices, so rclpy and ``ros2 param describe`` show what the manager accepts;
values cross between the ROS types (arrays) and the manager's (tuples) here.
"""
from __future__ import annotations

import array
import sys
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from .controller import ParameterSpec


def descriptor_for(spec: ParameterSpec) -> ParameterDescriptor:
    """A ROS parameter descriptor from a :class:`ParameterSpec` (ranges, constraints text)."""
    d = ParameterDescriptor(description=spec.description, dynamic_typing=spec.auto)
    default = spec.default
    constraints = []
    if spec.auto:  # a string or a double: the range is checked by the manager
        d.additional_constraints = f"'auto' or a number in [{_fmt(spec.low)}, {_fmt(spec.high)}]"
        return d
    if spec.choices is not None:
        constraints.append('one of: ' + ', '.join(spec.choices))
    if isinstance(default, bool) or isinstance(default, str):
        pass
    elif isinstance(default, (tuple, list)):
        count = f'{spec.length} numbers' if spec.length is not None else 'numbers'
        bounds = f' in [{_fmt(spec.low)}, {_fmt(spec.high)}]' if (
            spec.low is not None or spec.high is not None) else ''
        constraints.append(count + (' each' + bounds if bounds else ''))
    elif isinstance(default, int):
        if spec.low is not None and spec.high is not None:
            d.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                            step=1)]
    elif spec.low is not None or spec.high is not None:
        low = -sys.float_info.max if spec.low is None else float(spec.low)
        high = sys.float_info.max if spec.high is None else float(spec.high)
        d.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    d.additional_constraints = '; '.join(constraints)
    return d


def _fmt(value: float | None) -> str:
    return '-inf' if value is None else f'{value:g}'


def ros_value(spec: ParameterSpec, value: Any) -> Any:
    """A manager value as the ROS parameter type fixed by the spec's default."""
    if spec.auto:
        return value if isinstance(value, str) else float(value)
    if isinstance(spec.default, (tuple, list)):
        return [float(v) for v in value]
    if isinstance(spec.default, bool) or isinstance(spec.default, str):
        return value
    if isinstance(spec.default, int):
        return int(value)
    return float(value)


def manager_value(value: Any) -> Any:
    """A ROS parameter value as the manager takes it (arrays as tuples)."""
    if isinstance(value, (array.array, list, tuple)):
        return tuple(value)
    return value
