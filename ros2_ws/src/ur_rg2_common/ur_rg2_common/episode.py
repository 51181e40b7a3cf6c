"""Episode markers: where a demonstration or a policy's attempt starts and how it ends.

``episode`` (std_msgs/msg/String, a relative name; its names in ur_rg2_common.contract):
``start`` when an episode starts, ``success`` or ``failure`` when it ends. ``keys`` (a
person's keys), the pick of ``ur_rg2_motion`` and the policy node publish them; ``record
--all`` records them beside the rest and ``to_lerobot`` cuts a recording into episodes by
them (ur_rg2_tools.lerobot).
"""

from collections.abc import Iterator
from contextlib import contextmanager

from rclpy.node import Node
from std_msgs.msg import String

from ur_rg2_common.contract import (
    EPISODE_FAILURE,
    EPISODE_QOS,
    EPISODE_START,
    EPISODE_SUCCESS,
    EPISODE_TOPIC,
)


class EpisodeMarkers:
    """Publishes a node's episode markers on ``episode``."""

    def __init__(self, node: Node) -> None:
        self._publisher = node.create_publisher(String, EPISODE_TOPIC, EPISODE_QOS)

    def mark(self, marker: str) -> None:
        """Publish ``marker``: EPISODE_START, EPISODE_SUCCESS or EPISODE_FAILURE."""
        self._publisher.publish(String(data=marker))

    def start(self) -> None:
        """Mark the start of an episode."""
        self.mark(EPISODE_START)

    def end(self, success: bool) -> None:
        """Mark the end of the episode: a success or a failure."""
        self.mark(EPISODE_SUCCESS if success else EPISODE_FAILURE)

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
