"""The health reports of :mod:`cartpole_core.diagnostics` and the simulator's own (in process)."""
import pytest

from cartpole_core.diagnostics import ERROR, OK, STALE, WARN, Health, HealthReport, plain


def report_of(report, level=OK, message='running', **values):
    status = report.status(Health(level, message, values))
    return status.level, status.message, {kv.key: kv.value for kv in status.values}


def test_values_are_plain_numbers_and_words():
    assert [plain(v) for v in (3, 0.25, 8.0, float('nan'), True, False, 'lqg')] == \
        ['3', '0.25', '8.0', 'nan', 'true', 'false', 'lqg']


def test_an_input_that_stopped_is_stale_an_idle_one_is_not():
    report = HealthReport('n: what', 'hw', inputs=('samples',))
    assert report_of(report, samples=0)[0] == OK                  # idle: nothing yet
    assert report_of(report, samples=0)[0] == OK                  # still idle
    assert report_of(report, samples=200)[0] == OK                # arriving
    level, message, values = report_of(report, samples=200)       # stopped
    assert level == STALE and message == 'running; no samples since the last report'
    assert values == {'samples': '200'}
    assert report_of(report, samples=400)[0] == OK                # back
    assert report_of(report, ERROR, 'fault', samples=400)[0] == ERROR  # a fault wins


def test_a_degraded_counter_that_grew_warns_once():
    report = HealthReport('n: what', 'hw', degraded=('bad_lines', 'resets'))
    assert report_of(report, bad_lines=2, resets=0)[0] == OK       # the first report: no base
    level, message, _ = report_of(report, bad_lines=5, resets=1)
    assert level == WARN and message == 'running; bad_lines +3; resets +1'
    assert report_of(report, bad_lines=5, resets=1)[0] == OK
    assert report_of(report, ERROR, 'fault', bad_lines=6, resets=1)[:2] == \
        (ERROR, 'fault; bad_lines +1')
    # The node's counters as text (the bridge's) count the same.
    assert report_of(report, bad_lines='7', resets='1')[0] == WARN


@pytest.mark.ros
def test_the_simulator_is_idle_until_a_controller_answers(ros_context):
    from cartpole_sim.sim_node import SimNode
    from rclpy.parameter import Parameter

    node = SimNode(context=ros_context, parameter_overrides=[Parameter('lockstep', value=True)])
    try:
        (status,) = node.diagnostics.publish().status
        assert (status.name, status.hardware_id, status.level) == \
            ('sim: simulation', 'cartpole', OK)
        assert 'waiting for a controller' in status.message
    finally:
        node.destroy_node()


@pytest.mark.ros
def test_a_node_in_a_namespace_reports_under_its_qualified_name(ros_context):
    from rclpy.node import Node

    from cartpole_core.diagnostics import NodeDiagnostics

    node = Node('sim', namespace='rig2', context=ros_context)
    try:
        diagnostics = NodeDiagnostics(node, 'simulation', 'cartpole', lambda: Health(OK, 'idle'))
        (status,) = diagnostics.publish().status
        assert (status.name, status.level, status.message) == ('rig2/sim: simulation', OK, 'idle')
    finally:
        node.destroy_node()


@pytest.mark.ros
def test_a_timer_that_catches_up_does_not_report_twice_at_once(ros_context):
    """An executor held up may call the timer twice in a row: the second call, less than
    half a period after the first report by the node clock, reports nothing."""
    from rclpy.node import Node

    from cartpole_core.diagnostics import NodeDiagnostics

    node = Node('held_up', context=ros_context)
    try:
        diagnostics = NodeDiagnostics(node, 'what', 'none', lambda: Health(OK, 'idle'))
        sent = []
        diagnostics._publisher.publish = sent.append
        diagnostics._on_timer()
        diagnostics._on_timer()
        assert len(sent) == 1
        diagnostics._last_ns -= 600_000_000     # the last report 0.6 s ago
        diagnostics._on_timer()
        assert len(sent) == 2
    finally:
        node.destroy_node()
