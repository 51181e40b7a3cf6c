"""Episode markers: where a demonstration or a policy's attempt starts and how it ends.

``episode`` (std_msgs/msg/String, a relative name): ``start`` when an episode starts,
``success`` or ``failure`` when it ends. ``keys`` (a person's keys), the pick of
``ur_rg2_motion`` and the policy node publish them; ``record --all`` records them beside the
rest and ``to_lerobot`` cuts a recording into episodes by them (ur_rg2_tools.lerobot).
"""

from collections.abc import Iterator
from contextlib import contextmanager

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

EPISODE_TOPIC = 'episode'
START = 'start'
SUCCESS = 'success'
FAILURE = 'failure'
MARKERS = (START, SUCCESS, FAILURE)
# Every marker counts and none is old news to a late joiner: reliable, not latched.
EPISODE_QOS = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


class EpisodeMarkers:
    """Publishes a node's episode markers on ``episode``."""

    def __init__(self, node: Node) -> None:
        self._publisher = node.create_publisher(String, EPISODE_TOPIC, EPISODE_QOS)

    def start(self) -> None:
        """Mark the start of an episode."""
        self._publisher.publish(String(data=START))

    def end(self, success: bool) -> None:
        """Mark the end of the episode: a success or a failure."""
        self._publisher.publish(String(data=SUCCESS if success else FAILURE))

    @contextmanager
    def marked(self) -> Iterator[None]:
        """Mark an episode around a block: a success when it returns, a failure when it raises."""
        self.start()
        try:
            yield
        except BaseException:
            self.end(success=False)
            raise
        self.end(success=True)
