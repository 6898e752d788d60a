"""The bridge's health on /diagnostics without a device (in process, no emulator): idle
while unconfigured, an ERROR naming the port once a configure was refused."""
import pytest

pytestmark = pytest.mark.ros


def test_a_bridge_without_its_device_is_idle_then_error_after_a_refused_configure(ros_context,
                                                                                  tmp_path):
    from diagnostic_msgs.msg import DiagnosticStatus
    from rclpy.lifecycle import TransitionCallbackReturn
    from rclpy.parameter import Parameter

    from cartpole_hw.hw_node import HwBridgeNode

    port = str(tmp_path / 'no-such-device')
    node = HwBridgeNode(context=ros_context, parameter_overrides=[Parameter('port', value=port)])
    try:
        (status,) = node.diagnostics.publish().status
        assert (status.name, status.hardware_id) == ('hw_bridge: serial link', port)
        assert (status.level, status.message) == (DiagnosticStatus.OK, 'unconfigured: port closed')
        values = {kv.key: kv.value for kv in status.values}
        assert (values['state'], values['connected']) == ('unconfigured', 'false')
        assert node.trigger_configure() == TransitionCallbackReturn.FAILURE
        (status,) = node.diagnostics.publish().status
        assert status.level == DiagnosticStatus.ERROR
        assert status.message.startswith(f'unconfigured: configure refused: cannot open {port}')
    finally:
        node.destroy_node()
