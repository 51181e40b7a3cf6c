"""The keys process's two loops: the ROS executor on a thread, the keys on the main one."""

from collections.abc import Callable
import threading

from rclpy.executors import Executor, ExternalShutdownException

from ur_rg2_teleop.terminal import KeyReader

# How often the key loop looks up from the keyboard to check that ROS is still being spun.
_SPIN_CHECK_PERIOD = 0.5


def spin(executor: Executor, errors: list[BaseException]) -> None:
    """Spin ``executor`` until it is shut down; keep what it raised in ``errors``."""
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except BaseException as error:  # noqa: BLE001 - handed to the main thread, which raises it
        errors.append(error)


def key_loop(handle_key: Callable[[str], bool], reader: KeyReader, spinner: threading.Thread,
             spin_errors: list[BaseException]) -> None:
    """Hand each key to ``handle_key`` until it returns False; raise if ``spinner`` stops."""
    while spinner.is_alive():
        for key in reader.read(timeout=_SPIN_CHECK_PERIOD):
            if not handle_key(key):
                return
    raise RuntimeError('the ROS executor stopped') from (spin_errors[0] if spin_errors else None)
