"""Process entry point shared by the project's nodes: create, spin, shut down cleanly."""

from collections.abc import Callable
import ctypes
import faulthandler
import signal
from typing import Optional, TypeVar

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ur_rg2_common.entry import stop_requested
from ur_rg2_common.executors import BlockingGroupExecutor

N = TypeVar('N', bound=Node)

# How long the executor waits for work before the loop looks at rclpy.ok() again, s.
SPIN_WAIT_S = 0.25
# A node still running this long after a stop signal prints every thread's stack to stderr, s
# (ros2 launch escalates to SIGTERM after 5 s).
STOP_DIAGNOSIS_S = 4.0
# glibc's mallopt parameters, and what the nodes set them to.
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD = 32 * 2 ** 20  # glibc's largest
_TRIM_THRESHOLD = 64 * 2 ** 20


def keep_freed_memory() -> None:
    """Make glibc keep freed memory for reuse instead of handing it back to the kernel.

    For a process that copies camera images around at the frame rate. By default glibc maps
    a fresh block for each large allocation, or trims the heap once a few megabytes are
    free, and every frame then touches hundreds of new pages: in the vision node about 200
    page faults and 1 ms per annotated 640x480 image. (The sim measured no gain, 50 MB more
    memory.) A no-op where the C library is not glibc.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)
    mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD)


def ignore_stop_signals() -> None:
    """Ignore SIGINT and SIGTERM from now on: the process is already on its way out."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_IGN)


def _catch_stop_signals() -> list[int]:
    """Make SIGINT and SIGTERM append to the returned list; the first arms a stack dump.

    SIGINT (how ros2 launch and ros2 run stop a node, even one started with SIGINT ignored)
    and SIGTERM set a flag that :func:`run_node`'s loop sees within SPIN_WAIT_S. A
    KeyboardInterrupt could land anywhere: inside rclpy's own objects, or in a constructor that
    has started a thread. Not rclpy's handlers either: they shut the context down at once,
    under the callback or constructor that is running (its log lines and messages would fail).
    """
    interrupted: list[int] = []

    def on_stop(signum: int, frame: object) -> None:
        if not interrupted:
            faulthandler.dump_traceback_later(STOP_DIAGNOSIS_S)
        interrupted.append(signum)
        # A second SIGINT (a terminal's Ctrl-C and launch's own) changes nothing.
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_stop)
    return interrupted


def run_node(make_node: Callable[[], N], args: Optional[list[str]], logger_name: str,
             startup_errors: tuple[type[Exception], ...] = (), *,
             on_startup_error: Optional[Callable[[Exception], int]] = None,
             failure: Optional[Callable[[N], Optional[str]]] = None) -> int:
    """Create a node and spin it until Ctrl-C or SIGTERM; return the process exit code.

    An exception of ``startup_errors`` raised while creating the node (a bad parameter, a busy
    port) ends the process with no traceback: ``on_startup_error`` logs it and returns the exit
    code; by default one ``cannot start`` error line and exit code 1. The callbacks of the
    node's ``blocking_group``, if it has one, run on worker threads (BlockingGroupExecutor).
    ``failure``, if given, is asked after every wait: a message from it is logged as fatal and
    ends the process with exit code 1.
    """
    interrupted = _catch_stop_signals()
    if stop_requested():
        return 0
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    executor = BlockingGroupExecutor()
    node = None
    try:
        try:
            try:
                node = make_node()
            except startup_errors as error:
                if interrupted:
                    return 0
                if on_startup_error is not None:
                    return on_startup_error(error)
                get_logger(logger_name).error(f'cannot start: {error}')
                return 1
            blocking_group = getattr(node, 'blocking_group', None)
            if blocking_group is not None:
                executor.add_blocking_group(blocking_group)
            executor.add_node(node)
            # Not executor.spin(): a bounded wait notices a stop within SPIN_WAIT_S whatever
            # happens (docs/design.md).
            while rclpy.ok() and not interrupted:
                message = failure(node) if failure is not None else None
                if message is not None:
                    node.get_logger().fatal(message)
                    return 1
                executor.spin_once(timeout_sec=SPIN_WAIT_S)
        except Exception as error:
            # After a stop signal or an outside shutdown, an error on the way out is no error
            # of ours.
            if rclpy.ok() and not interrupted:
                get_logger(logger_name).error(f'stopped: {error}')
                raise
    except ExternalShutdownException:
        pass
    finally:
        # Teardown is short and bounded: no later signal may cut it short.
        ignore_stop_signals()
        try:
            # First, so that callbacks still running on worker threads (a pick waiting for the
            # arm) see it and end; the executor's shutdown waits for them.
            rclpy.try_shutdown()
            executor.shutdown()
            if node is not None:
                node.destroy_node()
        finally:
            # Whatever failed above: a process that exits with its context up leaves DDS's
            # threads to static destructors, which can abort it.
            rclpy.try_shutdown()
            faulthandler.cancel_dump_traceback_later()
    return 0
