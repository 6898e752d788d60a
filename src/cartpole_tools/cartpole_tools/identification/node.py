"""The pulse player node ``pulse_player``: an open-loop pulse test on the rig or the simulator.

A thin adapter around :class:`cartpole_tools.identification.pulse_player.PulsePlayer`: it
answers every ``/joint_states`` sample with one ``/cartpole/force_command`` stamped with
that sample, as the controller manager does, so a lockstep simulator steps on it and the
hw bridge's stale-command check applies. :func:`play_pulse_plan` runs it (with a recorder,
optionally arming the hw bridge) for ``cartpole identify --pulse-plan``.

Arming is the bridge's lifecycle ``activate``
(:class:`cartpole_hw.lifecycle_client.LifecycleClient`), which needs a warm loop: the
node answers with zero force first, then asks. When the plan ends, or on any error or
Ctrl-C, it publishes zero force once, stops publishing and deactivates a bridge it
activated (the bridge's watchdog disarms it 50 ms later should that fail). Its names are
relative, so ``cartpole identify --namespace rig2`` plays on that graph.
The test step by step: (docs/identification.md, "1. Record the tests on the rig").
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Sequence

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from cartpole_core.spin import spin_until as spin_executor_until

from .pulse_player import PulsePlayer

CART = 'cart'
PENDULUM = 'pendulum'
WARM_ANSWERS = 30
"""Zero-force answers before the bridge is asked to activate (its rule: 20 timely ones)."""
ACTIVATE_ATTEMPTS = 10
ACTIVATE_RETRY = 0.2
"""Wall seconds between two activation requests the bridge refused."""
BRIDGE_TIMEOUT = 5.0
"""Wall seconds for the bridge's lifecycle services to answer."""


class PulsePlayerNode(Node):
    """Answers each sample with the plan's force once :attr:`playing` is set."""

    def __init__(self, player: PulsePlayer, **kwargs) -> None:
        super().__init__('pulse_player', **kwargs)
        self.player = player
        self.playing = False
        """Set to start answering samples (before, samples are only watched)."""
        self.warming = False
        """Set to answer samples with zero force before :attr:`playing` (the bridge's
        warm-loop rule for its activation)."""
        self.first_sample: tuple[float, float, float] | None = None
        """(t, x, theta) of the first sample seen."""
        self.answered = 0
        self._pub = self.create_publisher(JointState, 'cartpole/force_command', 10)
        self.create_subscription(JointState, 'joint_states', self._on_sample, 10)

    def _on_sample(self, msg: JointState) -> None:
        try:
            x = float(msg.position[list(msg.name).index(CART)])
            theta = float(msg.position[list(msg.name).index(PENDULUM)])
        except (ValueError, IndexError):
            return
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if self.first_sample is None:
            self.first_sample = (t, x, theta)
        if not self.playing:
            if self.warming:
                self.publish_force(0.0, msg.header.stamp)
                self.answered += 1
            return
        force = self.player.update(t, x) if math.isfinite(x) else 0.0
        self.publish_force(force, msg.header.stamp)
        self.answered += 1

    def publish_force(self, force: float, stamp=None) -> None:
        msg = JointState(name=[CART], effort=[float(force)])
        if stamp is not None:
            msg.header.stamp = stamp
        else:
            msg.header.stamp = self.get_clock().now().to_msg()
        self._pub.publish(msg)


def play_pulse_plan(player: PulsePlayer, *, context=None, record: Path | None = None,
                    arm: bool = False, sample_wait: float = 5.0, timeout: float = 120.0,
                    check: Callable[[float, float], list[str]] | None = None,
                    extra_nodes: Sequence[Node] = (),
                    log: Callable[[str], None] = print) -> dict:
    """Play a pulse test on whatever publishes ``/joint_states`` (hw bridge or simulator).

    Steps: wait up to ``sample_wait`` s for the first sample; ``check(x,
    theta)`` (e.g. a rehearsal on the model from that state) may refuse with
    reasons; arm the bridge (its lifecycle ``activate``, after
    :data:`WARM_ANSWERS` zero-force answers) if asked; answer samples
    until the plan is done or ``timeout`` wall seconds passed. ``record``
    adds a :class:`~cartpole_bringup.graph.recorder.RecorderNode` writing that bag.
    ``extra_nodes`` (e.g. a simulator) are spun in the same executor.

    Returns a summary dict; raises RuntimeError with the reason on failure
    (no sample, refused check, arming refused, timeout).
    """
    nodes: list[Node] = []
    executor = SingleThreadedExecutor(context=context)
    node = PulsePlayerNode(player, context=context)
    nodes.append(node)
    recorder = None
    bridge = None
    try:
        if record is not None:
            from cartpole_bringup.graph.recorder import RecorderNode
            recorder = RecorderNode(context=context, parameter_overrides=[
                Parameter('output', value=str(record))])
            nodes.append(recorder)
        for n in (*nodes, *extra_nodes):
            executor.add_node(n)

        def spin_until(predicate, seconds: float) -> bool:
            return spin_executor_until(executor, predicate, seconds)

        if not spin_until(lambda: node.first_sample is not None, sample_wait):
            raise RuntimeError(f'no /joint_states sample within {sample_wait:g} s: is the hw '
                               'bridge (or the simulator) running?')
        _, x0, theta0 = node.first_sample
        if check is not None:
            problems = check(x0, theta0)
            if problems:
                raise RuntimeError('refused, the rehearsal on the model says: '
                                   + '; '.join(problems))
        if arm:
            bridge = _activate_bridge(node, spin_until)
            log('hw bridge armed (lifecycle state active)')
        node.playing = True
        log(f'playing {len(player.pulses)} pulse(s) from x = {x0:.3f} m')
        if not spin_until(lambda: player.done, timeout):
            raise RuntimeError(f'the plan did not finish within {timeout:g} s')
        return {'pulses': len(player.pulses), 'samples': node.answered,
                'guard': player.reason or None,
                'bag': str(recorder.bag_path) if recorder is not None else None,
                'x0': x0, 'theta0': theta0}
    finally:
        node.playing = node.warming = False
        try:
            node.publish_force(0.0)
            if bridge is not None:
                ok, reason = bridge.change('deactivate', BRIDGE_TIMEOUT)
                log('hw bridge disarmed (inactive)' if ok else
                    f'hw bridge not deactivated ({reason}); its watchdog disarms it')
        except Exception:  # the context may already be shut down (Ctrl-C)
            pass
        for n in (*nodes, *extra_nodes):
            executor.remove_node(n)
        for n in reversed(nodes):
            n.destroy_node()
        executor.shutdown()


def _activate_bridge(node: PulsePlayerNode, spin_until: Callable[[Callable[[], bool], float], bool]):
    """Answer samples with zero force, then activate the bridge (retrying while it says
    the loop is not warm yet); its lifecycle client, or RuntimeError with the reason."""
    from cartpole_hw.lifecycle_client import LifecycleClient

    bridge = LifecycleClient(node, 'hw_bridge', spin_until)   # in the node's namespace
    state = bridge.state(BRIDGE_TIMEOUT)
    if state != 'inactive':
        raise RuntimeError(f'the hw bridge is {state or "not answering"}, not inactive: '
                           f'configure it first (ros2 lifecycle set /hw_bridge configure)')
    node.warming = True
    start = node.answered
    spin_until(lambda: node.answered >= start + WARM_ANSWERS, BRIDGE_TIMEOUT)
    ok, reason = bridge.change_retrying('activate', ACTIVATE_ATTEMPTS, ACTIVATE_RETRY,
                                        BRIDGE_TIMEOUT)
    if not ok:
        raise RuntimeError(f'the hw bridge refused to arm: {reason}')
    return bridge


def run_pulse_plan(player: PulsePlayer, *, ros_arguments: Sequence[str] = (),
                   **kwargs) -> dict:
    """:func:`play_pulse_plan` in its own rclpy context (the command line); ``ros_arguments``
    apply to its nodes (the graph's namespace:
    :func:`cartpole_core.namespaces.ros_arguments`)."""
    rclpy.init(args=['cartpole', '--ros-args', *ros_arguments] if ros_arguments else None)
    try:
        return play_pulse_plan(player, **kwargs)
    finally:
        rclpy.try_shutdown()
