"""graph.launch.py in launch's LaunchService, with an exit status that says how the graph ended.

What ``ros2 launch --noninteractive ur_rg2_bringup graph.launch.py ARGS`` does, for the
``graph`` executable: ``ros2 launch`` exits 0 whatever ended the graph, while a command a user
scripts around should exit 1 when a node died. With ``--quiet`` (keys in the terminal) the
screen shows warnings and errors only; everything goes to the launch log file, whose path is
printed at start and on exit.
Usage: ``python -m ur_rg2_bringup.launch_graph [--quiet] [NAME:=VALUE ...]``.
"""

from __future__ import annotations

from collections.abc import Sequence
import logging
import os
import re
import signal
import sys

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription, RegisterEventHandler
from launch.event_handlers import OnShutdown
from launch.launch_description_sources import PythonLaunchDescriptionSource
import launch.logging

# Shutdown reasons that are a normal end of the graph, in launch's own words: a SIGINT (what
# the graph executable sends to stop it), or nothing left to run.
NORMAL_ENDS = ('ctrl-c (SIGINT)', 'idle')
# The start of the shutdown reason of an exception in launch, which launch logs as an error too.
LAUNCH_ERROR = 'Caught exception in launch'
# A node's routine console line, as rcutils prints it (launch puts "[sim-1] " before it), or
# the banner pybullet prints on stderr when it is imported.
_ROUTINE_LINE = re.compile(r'(\x1b\[[0-9;]*m)*\[(INFO|DEBUG)\]|pybullet build time: ')


def graph_launch_file() -> str:
    """Return the path of graph.launch.py, found through the ament index."""
    return os.path.join(get_package_share_directory('ur_rg2_bringup'), 'launch',
                        'graph.launch.py')


def warnings_and_errors(record: logging.LogRecord) -> bool:
    """Screen filter: pass what is not routine (a node's INFO/DEBUG line, launch's INFO)."""
    if record.name.endswith(('-stdout', '-stderr')):  # a node's output, a line per record
        return not _ROUTINE_LINE.match(record.getMessage().split('] ', 1)[-1])
    # Only the graph executable sends launch a SIGINT, and it says why itself.
    return record.levelno >= logging.WARNING and 'ctrl-c (SIGINT)' not in record.getMessage()


def quiet_screen() -> str:
    """Send every output line to the launch log file, nodes' warnings and errors to the screen.

    Return the log file's path. Call before the launch file is loaded: launch reads its
    ``OVERRIDE_LAUNCH_PROCESS_OUTPUT`` when each node is made.
    """
    # launch's 'log': both streams to the file, stderr (where rcutils logs) to the screen too.
    os.environ['OVERRIDE_LAUNCH_PROCESS_OUTPUT'] = 'log'
    launch.logging.launch_config.get_screen_handler().addFilter(warnings_and_errors)
    return os.path.join(launch.logging.launch_config.log_dir, 'launch.log')


def run_service(service: LaunchService) -> int:
    """Run ``service``; a SIGINT reaches launch's own handler, never as a KeyboardInterrupt.

    Launch hears a signal through the wakeup file descriptor Python writes for every signal it
    catches, and ignores the KeyboardInterrupt Python's default SIGINT handler raises too; but
    that exception first aborts whatever was running (an action half done, a weakref callback
    printing its traceback). A handler that does nothing leaves the signal to launch alone.
    """
    previous = signal.signal(signal.SIGINT, lambda _signum, _frame: None)
    try:
        return service.run()
    finally:
        signal.signal(signal.SIGINT, previous)


def run_graph(launch_arguments: Sequence[str], quiet: bool = False) -> int:
    """Run the graph until it stops; return 1 (saying why last) if a node ended it, else 0."""
    log_file = quiet_screen() if quiet else None
    if log_file:
        print(f'bringup: the log of every node is in {log_file}', file=sys.stderr, flush=True)
    reasons: list[str] = []
    # Non-interactive: launch itself sends each node SIGINT, no terminal's Ctrl-C reaches them.
    service = LaunchService(argv=list(launch_arguments), noninteractive=True)
    service.include_launch_description(LaunchDescription([
        RegisterEventHandler(OnShutdown(
            on_shutdown=lambda event, _context: reasons.append(event.reason))),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(graph_launch_file()),
            launch_arguments=[tuple(argument.split(':=', 1)) for argument in launch_arguments]),
    ]))
    returncode = run_service(service)
    if log_file:
        print(f'bringup: graph stopped; its log: {log_file}', file=sys.stderr, flush=True)
    if reasons and reasons[0] not in NORMAL_ENDS:
        if not reasons[0].startswith(LAUNCH_ERROR):  # else launch's error line said it last
            print(f'bringup: {reasons[0]}', file=sys.stderr, flush=True)
        return 1
    return returncode


if __name__ == '__main__':
    arguments = sys.argv[1:]
    quiet = '--quiet' in arguments
    sys.exit(run_graph([a for a in arguments if a != '--quiet'], quiet))
