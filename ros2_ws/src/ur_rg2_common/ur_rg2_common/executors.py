"""An executor that keeps callbacks on the spinning thread except those allowed to block."""

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Optional

from rclpy.callback_groups import CallbackGroup
from rclpy.context import Context
from rclpy.executors import (
    ConditionReachedException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)


class BlockingGroupExecutor(SingleThreadedExecutor):
    """Run callbacks on the spinning thread, but those of blocking groups on worker threads.

    rclpy's MultiThreadedExecutor hands every callback to a thread pool, which here added up to
    50 ms between a ``joint_jog`` arriving and its callback running (p50 1 ms). Only the
    services wait (for the simulation to finish a motion), so only they leave this thread.
    """

    def __init__(self, workers: int = 4, *, context: Optional[Context] = None) -> None:
        super().__init__(context=context)
        self._blocking_groups: list[CallbackGroup] = []
        self._workers = ThreadPoolExecutor(workers, thread_name_prefix='service')

    def add_blocking_group(self, group: CallbackGroup) -> None:
        """Run the callbacks of ``group`` on worker threads from now on."""
        self._blocking_groups.append(group)

    def _spin_once_impl(self, timeout_sec: Optional[float] = None,
                        wait_condition: Callable[[], bool] = lambda: False) -> None:
        try:
            handler, entity, _ = self.wait_for_ready_callbacks(timeout_sec, None,
                                                               wait_condition)
        except (ShutdownException, TimeoutException, ConditionReachedException):
            return
        if entity is not None and any(entity.callback_group is group
                                      for group in self._blocking_groups):
            self._workers.submit(handler)
            return
        handler()
        handler.result()  # raise what the callback raised

    def shutdown(self, timeout_sec: Optional[float] = None) -> bool:
        """Shut down, and stop taking blocking callbacks (running ones finish on their own)."""
        self._workers.shutdown(wait=False, cancel_futures=True)
        return super().shutdown(timeout_sec)
