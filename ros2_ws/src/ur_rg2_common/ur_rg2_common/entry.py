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


def run_main(module: str) -> int:
    """Import ``module`` and return what its ``main()`` returns; 0 if stopped by Ctrl-C/SIGINT."""
    try:
        return importlib.import_module(module).main()
    except KeyboardInterrupt:
        return 0
