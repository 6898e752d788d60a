"""The ``viewer_tap`` node: hosts :class:`cartpole_analysis.viewer.feed.FeedTap` in the graph.

``cartpole run --view`` adds it to the graph's own executor, so its
subscriptions are the process's own (no extra remote DDS reader, nothing
more on the loop's critical path than a stamp read per message), and it
forwards the samples to draw to the viewer process through the feed socket
(:mod:`cartpole_analysis.viewer.feed`). It subscribes ``/cartpole/state``,
``/cartpole/controller_status`` and the plant's state: ``/cartpole/true_state``
on the simulator, ``/joint_states`` on the rig (relative names: those of the
graph's namespace).
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from ..analysis.analyze import JOINTS, STATE, STATUS, TRUE_STATE
from cartpole_core.namespaces import relative
from .server import MAX_RATE_HZ
from .feed import MEASUREMENT, TRUTH, FeedSender, FeedTap

NODE_NAME = 'viewer_tap'


class ViewerTapNode(Node):
    """Forwards the graph's samples to a viewer process (see the module docstring).

    Parameters
    ----------
    feed
        Path of the viewer's feed socket.
    plant_topic
        ``/cartpole/true_state`` (simulator) or ``/joint_states`` (rig).
    max_rate
        The viewer's ``max_rate`` [Hz].
    """

    def __init__(self, feed: str, plant_topic: str = TRUE_STATE,
                 max_rate: float = MAX_RATE_HZ, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        if plant_topic not in (TRUE_STATE, JOINTS):
            raise ValueError(f'plant_topic must be {TRUE_STATE} or {JOINTS}, got {plant_topic!r}')
        self.sender = FeedSender(feed)
        self.tap = FeedTap(self.sender, max_rate)
        kind = TRUTH if plant_topic == TRUE_STATE else MEASUREMENT
        qos = QoSProfile(depth=20, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.create_subscription(JointState, relative(plant_topic),
                                 lambda data: self.tap.plant(kind, data), qos, raw=True)
        self.create_subscription(JointState, relative(STATE), self.tap.estimate, qos, raw=True)
        self.create_subscription(DiagnosticArray, relative(STATUS), self.tap.status,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT),
                                 raw=True)

    def destroy_node(self) -> None:
        self.sender.close()
        super().destroy_node()
