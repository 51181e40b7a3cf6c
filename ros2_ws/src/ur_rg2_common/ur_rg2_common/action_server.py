"""An action server whose execute callbacks run on a thread pool (the sim's, the RG2 adapter's).

rclpy schedules execute callbacks as executor tasks on the spinning thread, where a callback
that waits would hold up every other callback of the node (and one that awaits is polled by
the executor in a busy loop). Goal, cancel and result requests stay on the spinning thread:
they are quick.
"""

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Optional

from rclpy.action import ActionServer
from rclpy.action.server import ServerGoalHandle
from rclpy.task import Task


class WorkerActionServer(ActionServer):
    """ActionServer running each goal's execute callback on a thread of ``workers``."""

    def __init__(self, *args, workers: ThreadPoolExecutor, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._workers = workers

    def notify_execute(self, goal_handle: ServerGoalHandle,
                       execute_callback: Optional[Callable] = None) -> None:
        """Run the goal's execute callback on a worker thread."""
        callback = execute_callback or self._execute_callback
        if callback is not None:
            # rclpy's own coroutine around the callback sets the goal's result.
            self._workers.submit(self._run, Task(self._execute_goal, (callback, goal_handle)))

    def _run(self, task: Task) -> None:
        task()
        error = task.exception()  # fetched, so that rclpy does not print it again on exit
        if error is not None and self._node.context.ok():
            self._node.get_logger().error(f'action goal failed: {error!r}')
