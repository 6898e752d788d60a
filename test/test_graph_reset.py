"""``/sim/reset`` while balancing hands over cleanly (``~/reset`` in docs/architecture.md,
"ROS interfaces"): the simulator announces the
reset, the EKF re-initialises from the reset sample and the controller manager starts a new
swing-up instead of its rail guard seeing the jump of the estimate (one-process graph,
lockstep, ground truth).
"""
from __future__ import annotations

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_sim_reset_while_balancing_restarts_the_swingup_without_a_fault(ros_context):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger

    from cartpole_bringup.graph.graph import Graph, GraphSpec

    g = Graph(GraphSpec(plant='sim', lockstep=True), ros_context)
    status, health = [], []

    def on_status(msg):
        for s in msg.status:
            kv = {v.key: v.value for v in s.values}
            status.append((float(kv['state_stamp']), kv['mode'], kv['event']))

    g.monitor.create_subscription(DiagnosticArray, '/cartpole/controller_status', on_status, 200)
    g.monitor.create_subscription(
        DiagnosticArray, '/cartpole/ekf/health',
        lambda msg: health.extend({v.key: v.value for v in s.values} for s in msg.status), 10)
    try:
        g.start()
        b = g.monitor.builder
        assert g.spin_until(lambda: b.catch_ns is not None, 120.0), 'no catch'
        balanced = b.catch_ns + 1_000_000_000
        assert g.spin_until(lambda: g.monitor.last_stamp_ns >= balanced, 120.0)
        assert status[-1][1] == 'stabilizing'
        client = g.monitor.create_client(Trigger, '/sim/reset')
        assert g.spin_until(client.service_is_ready, 10.0)
        future = client.call_async(Trigger.Request())
        assert g.spin_until(future.done, 10.0) and future.result().success
        reset_at = g.monitor.last_stamp_ns
        assert g.spin_until(lambda: g.monitor.last_stamp_ns >= reset_at + 2_000_000_000, 120.0)
        assert g.spin_until(lambda: any(h.get('reset_reason') == 'plant reset' for h in health),
                            10.0), 'the EKF did not re-initialise for the reset'
    finally:
        g.close()
    after = [row for row in status if row[0] * 1e9 >= reset_at - 10_000_000]
    handover = [row for row in after if 'plant_reset' in row[2].split(';')]
    assert len(handover) == 1, after[:5]
    assert handover[0][1] == 'swingup'
    assert not [row for row in after if row[1] == 'fault'], \
        [row for row in after if row[1] == 'fault'][:3]
    # Swinging up from the handover to the run's stop (which switches control off: idle).
    stopped = g.stop_stamp_ns / 1e9  # as the status stamps parse (5.8, not 5.800000000000001)
    assert all(row[1] == 'swingup' for row in after if handover[0][0] <= row[0] < stopped)
    truth = [r for r in g.monitor.builder.states['/cartpole/true_state'] if r[0] >= reset_at]
    assert truth and all(0.0 <= r[1] <= 0.769 for r in truth)    # inside the travel
    assert max(r[1] for r in truth) > 0.05                         # the swing-up drives again
