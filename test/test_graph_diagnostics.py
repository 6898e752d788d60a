"""``/diagnostics`` of a running graph (one process, lockstep): every node reports one
status a second, by the stamps (simulated time); OK while the loop runs, the controller
manager ERROR once a plugin raises (its traceback on ``/rosout``) and OK again when
control is disabled (idle)."""
from __future__ import annotations

import pytest

pytestmark = [pytest.mark.ros]

NODES = {'sim: simulation', 'ekf: estimation', 'controller_manager: control'}
S = 1_000_000_000


def test_every_node_reports_once_a_second_with_levels_that_mean_what_they_say(
        ros_context, monkeypatch):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rcl_interfaces.msg import Log
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from cartpole_bringup.graph.graph import Graph, GraphSpec

    g = Graph(GraphSpec(plant='sim', lockstep=True), ros_context)
    reports: dict[str, list[tuple[int, bytes, str, str]]] = {}
    sizes, logs = [], []

    def on_diagnostics(msg):
        sizes.append(len(msg.status))
        stamp = msg.header.stamp.sec * S + msg.header.stamp.nanosec
        for s in msg.status:
            reports.setdefault(s.name, []).append((stamp, s.level, s.message, s.hardware_id))

    g.monitor.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 100)
    g.monitor.create_subscription(Log, '/rosout', logs.append, QoSProfile(
        depth=1000, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))

    def sim_time() -> int:
        return g.monitor.last_stamp_ns or 0

    def boom(state):
        raise RuntimeError('injected')

    try:
        g.start()
        assert g.spin_until(lambda: sim_time() >= 2 * S + S // 10, 120.0), 'the graph did not run'
        manager = g.nodes['controller_manager']
        for plugin in manager.manager.active_plugins().values():
            monkeypatch.setattr(plugin, 'update', boom)      # the next cycle faults
        fault_at = sim_time()
        assert g.spin_until(lambda: sim_time() >= 3 * S + S // 10, 120.0)
        manager.set_parameters([Parameter('enabled', value=False)])   # fault cleared: idle
        idle_at = sim_time()
        assert g.spin_until(lambda: set(reports) >= NODES and all(
            reports[n][-1][0] >= 4 * S for n in NODES), 120.0), reports
    finally:
        g.close()
    assert set(reports) == NODES and set(sizes) == {1}, (set(reports), set(sizes))
    for name in NODES:
        stamps = [r[0] for r in reports[name]]
        assert S <= stamps[0] < S + S // 10, (name, stamps)      # the first after 1 s
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        assert gaps and all(0.9 * S < gap < 1.1 * S for gap in gaps), (name, stamps)
        assert {r[3] for r in reports[name]} == {'cartpole'}
    for name in NODES - {'controller_manager: control'}:
        assert {r[1] for r in reports[name]} == {DiagnosticStatus.OK}, reports[name]
    control = reports['controller_manager: control']
    before = [r for r in control if r[0] < fault_at]
    faulted = [r for r in control if fault_at < r[0] < idle_at]
    idle = [r for r in control if r[0] > idle_at]
    assert before and {r[1] for r in before} == {DiagnosticStatus.OK}, control
    assert faulted and all(r[1] == DiagnosticStatus.ERROR and 'RuntimeError: injected' in r[2]
                           for r in faulted), control
    assert idle and all(r[1] == DiagnosticStatus.OK and 'control disabled' in r[2]
                        for r in idle), control
    assert [log for log in logs if log.name == 'controller_manager' and log.level == Log.ERROR
            and 'failed' in log.msg and 'Traceback' in log.msg
            and 'RuntimeError: injected' in log.msg], [log.msg for log in logs]
