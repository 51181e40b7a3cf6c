"""Console-script entry points of the nodes: a stop while a node still loads ends it quietly.

A node's module imports rclpy, OpenCV or pybullet, which takes seconds on a loaded machine, and
``ros2 launch`` stops the whole graph with SIGINT as soon as one node fails (a launch argument
of the wrong type ends the sim within a second). A node still importing then died with a
KeyboardInterrupt traceback and launch reported it as 'process has died'. Each package's
``entry`` module starts its nodes through :func:`run_main`, which imports nothing heavy itself:
a stop before the node is up ends the process like a stop after it (:func:`run_node`), exit
code 0 and no traceback.
"""

import importlib
import signal

_stop_signals: list[int] = []


def stop_requested() -> bool:
    """Whether a SIGINT reached :func:`run_main` before the node installed its own handler."""
    return bool(_stop_signals)


def _on_stop(signum: int, frame: object) -> None:
    # Python drops a KeyboardInterrupt raised inside a weakref callback or a __del__ (one of
    # importlib's module locks has such a callback): the stop is remembered all the same.
    _stop_signals.append(signum)
    raise KeyboardInterrupt


def run_main(module: str) -> int:
    """Import ``module`` and return what its ``main()`` returns; 0 if stopped by Ctrl-C/SIGINT."""
    signal.signal(signal.SIGINT, _on_stop)
    try:
        main = importlib.import_module(module).main
        if stop_requested():
            return 0
        return main()
    except KeyboardInterrupt:
        return 0
