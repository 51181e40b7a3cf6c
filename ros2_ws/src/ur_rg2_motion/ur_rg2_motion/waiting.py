"""Requests that wait a bounded moment for what they need from the graph.

A ``tool_command`` sent right after the graph starts may come before the latched
``/tf_static``, ``robot_description`` or the first ``joint_states`` has reached the motion
node. Its callback runs on the executor's thread, which must not block while those messages
are on their way, so the request is held and tried again (as tf2_ros's MessageFilter holds a
message until its frame can be transformed) and refused only once its time is up.
Plain Python: the node calls :meth:`WaitingRequests.submit` from its callbacks and
:meth:`WaitingRequests.retry` from a timer, on one thread.
"""

from collections.abc import Callable
from dataclasses import dataclass
import time


@dataclass
class _Request:
    source: str
    attempt: Callable[[], None]
    deadline: float


class WaitingRequests:
    """Attempts retried in the order they came until they no longer raise ``waits_on``.

    An attempt that still raises one of ``waits_on`` after ``timeout`` s is given up:
    ``on_expired(source, error)`` reports it. Beyond ``limit`` waiting, the oldest is given
    up the same way.
    """

    def __init__(self, timeout: float, waits_on: tuple[type[Exception], ...],
                 on_expired: Callable[[str, Exception], None], limit: int = 100,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.timeout = timeout
        self._waits_on, self._on_expired = waits_on, on_expired
        self._limit, self._clock = limit, clock
        self._waiting: list[_Request] = []

    def __len__(self) -> int:
        return len(self._waiting)

    def submit(self, source: str, attempt: Callable[[], None]) -> None:
        """Run ``attempt`` (after those still waiting); keep it if it raises ``waits_on``."""
        self._waiting.append(_Request(source, attempt, self._clock() + self.timeout))
        while len(self._waiting) > self._limit:
            dropped = self._waiting.pop(0)
            self._on_expired(dropped.source, OverflowError(
                f'more than {self._limit} requests waiting'))
        self.retry()

    def retry(self) -> None:
        """Run every waiting attempt once, in order; give up those whose time is up."""
        waiting, self._waiting = self._waiting, []
        for request in waiting:
            try:
                request.attempt()
            except self._waits_on as error:
                if self._clock() >= request.deadline:
                    self._on_expired(request.source, error)
                else:
                    self._waiting.append(request)
