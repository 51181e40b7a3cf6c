"""Process entry point shared by the package's nodes: create, spin, shut down cleanly."""

from collections.abc import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], args: list[str] | None, logger_name: str,
             startup_errors: tuple[type[BaseException], ...] = ()) -> int:
    """Create a node and spin it until Ctrl-C or SIGTERM; return the process exit code.

    An exception of ``startup_errors`` raised while creating the node (a bad parameter, a busy
    port) is logged as one line and gives exit code 1, with no traceback.
    """
    rclpy.init(args=args)
    # Before the node: an executor created after a signal has shut the context down fails
    # half-built and prints a traceback from its __del__.
    executor = SingleThreadedExecutor()
    node = None
    try:
        try:
            node = make_node()
        except startup_errors as error:
            get_logger(logger_name).error(f'cannot start: {error}')
            return 1
        executor.add_node(node)
        # Not executor.spin(): now and then (about 1 stop in 10 on a loaded machine) the
        # executor slept on in its wait set after a signal had shut the context down. A
        # bounded wait notices the shutdown within a quarter second whatever happens.
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.25)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # SIGINT/SIGTERM shut the context down; during start-up or mid-spin that surfaces as
        # an RCLError, which is no error of ours.
        if rclpy.ok():
            raise
    finally:
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
