"""The direct DiagnosticArray reader against rosbags' serialiser (both byte orders)."""
import pytest
from rosbags.typesys import Stores, get_typestore

from cartpole_analysis.viewer.diagnostics_cdr import parse_diagnostic_array

TS = get_typestore(Stores.ROS2_JAZZY)


def message(statuses):
    kv = TS.types['diagnostic_msgs/msg/KeyValue']
    status = TS.types['diagnostic_msgs/msg/DiagnosticStatus']
    header = TS.types['std_msgs/msg/Header'](
        stamp=TS.types['builtin_interfaces/msg/Time'](sec=1_700_000_123, nanosec=456_789),
        frame_id='frame')
    return TS.types['diagnostic_msgs/msg/DiagnosticArray'](header=header, status=[
        status(level=level, name=name, message=text, hardware_id='cartpole',
               values=[kv(key=k, value=v) for k, v in values.items()])
        for level, name, text, values in statuses])


STATUSES = [(0, 'controller_manager', 'swingup',
             {'mode': 'swingup', 'energy': '0.125', 'event': '', 'force': '-3.5'}),
            (2, 'other', 'fault: ünïcode', {'x': 'y'}),
            (1, 'empty', '', {})]


@pytest.mark.parametrize('little_endian', [True, False])
def test_reads_what_rosbags_writes(little_endian):
    msg = message(STATUSES)
    serialize = TS.serialize_cdr
    data = serialize(msg, 'diagnostic_msgs/msg/DiagnosticArray', little_endian=little_endian)
    stamp, statuses = parse_diagnostic_array(data)
    assert stamp == 1_700_000_123 * 10**9 + 456_789
    assert [(s.level, s.name, s.message, s.values) for s in statuses] == \
        [(level, name, text, values) for level, name, text, values in STATUSES]
    assert all(s.hardware_id == 'cartpole' for s in statuses)


def test_truncated_message_is_refused():
    data = TS.serialize_cdr(message(STATUSES), 'diagnostic_msgs/msg/DiagnosticArray')
    for cut in (8, 30, len(data) - 3):
        with pytest.raises(ValueError):
            parse_diagnostic_array(data[:cut])
