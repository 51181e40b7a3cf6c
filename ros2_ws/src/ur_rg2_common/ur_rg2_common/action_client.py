"""An action client whose requests may be sent from any thread while the executor spins.

rclpy's ActionClient sends a goal, cancel or result request and only then records its
sequence number; a response taken by the executor thread in between is dropped as
"unexpected" ("Ignoring unexpected goal response. There may be more than one action server")
and the request's future never completes (ros2/rclpy#1123). rclpy fixed it with a lock
(ros2/rclpy#1308, backported to Jazzy in #1519); the Jazzy wheels on PyPI (rclpy 7.1.6)
predate that, so :class:`ThreadSafeActionClient` takes the same lock around each request and
around the handling of what the executor took.
"""

import threading
from typing import Any

from rclpy.action import ActionClient


class ThreadSafeActionClient(ActionClient):
    """rclpy's ActionClient, with requests and the handling of responses mutually exclusive."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # Reentrant: a feedback or done callback run under execute may send a request.
        self._request_lock = threading.RLock()

    def send_goal_async(self, *args: Any, **kwargs: Any):
        """Send a goal (see ActionClient.send_goal_async), its sequence number recorded first."""
        with self._request_lock:
            return super().send_goal_async(*args, **kwargs)

    def _cancel_goal_async(self, goal_handle):
        with self._request_lock:
            return super()._cancel_goal_async(goal_handle)

    def _get_result_async(self, goal_handle):
        with self._request_lock:
            return super()._get_result_async(goal_handle)

    async def execute(self, taken_data):
        """Handle the responses the executor took, never between a request and its record."""
        with self._request_lock:
            # It suspends only in a coroutine feedback callback (ours are plain functions).
            return await super().execute(taken_data)
