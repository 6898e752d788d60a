"""The bridge's health on /diagnostics without a device: a port that cannot be opened is
an ERROR named after the port (in process, no emulator)."""
import pytest

pytestmark = pytest.mark.ros


def test_a_bridge_without_its_device_reports_error_disconnected(ros_context, tmp_path):
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.parameter import Parameter

    from cartpole_hw.hw_node import HwBridgeNode

    port = str(tmp_path / 'no-such-device')
    node = HwBridgeNode(context=ros_context, parameter_overrides=[Parameter('port', value=port)])
    try:
        (status,) = node.diagnostics.publish().status
        assert (status.name, status.hardware_id) == ('hw_bridge: serial link', port)
        assert (status.level, status.message) == (DiagnosticStatus.ERROR, 'disconnected')
        values = {kv.key: kv.value for kv in status.values}
        assert (values['connected'], values['samples']) == ('false', '0')
    finally:
        node.destroy_node()
