"""graph.launch.py in launch's LaunchService, with an exit status that says how the graph ended.

What ``ros2 launch ur_rg2_bringup graph.launch.py ARGS`` does, for the ``graph`` executable:
``ros2 launch`` exits 0 whatever ended the graph, while a command a user scripts around should
exit 1 when a node died. Usage: ``python -m ur_rg2_bringup.launch_graph [NAME:=VALUE ...]``.
"""

from __future__ import annotations

from collections.abc import Sequence
import os
import sys

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription, LaunchService
from launch.actions import IncludeLaunchDescription, RegisterEventHandler
from launch.event_handlers import OnShutdown
from launch.launch_description_sources import PythonLaunchDescriptionSource

# Shutdown reasons that are a normal end of the graph, in launch's own words: a SIGINT (what
# the graph executable sends to stop it), or nothing left to run.
NORMAL_ENDS = ('ctrl-c (SIGINT)', 'idle')


def graph_launch_file() -> str:
    """Return the path of graph.launch.py, found through the ament index."""
    return os.path.join(get_package_share_directory('ur_rg2_bringup'), 'launch',
                        'graph.launch.py')


def run_graph(launch_arguments: Sequence[str]) -> int:
    """Run the graph until it stops; return 1 (saying why last) if a node ended it, else 0."""
    reasons: list[str] = []
    service = LaunchService(argv=list(launch_arguments))
    service.include_launch_description(LaunchDescription([
        RegisterEventHandler(OnShutdown(
            on_shutdown=lambda event, _context: reasons.append(event.reason))),
        IncludeLaunchDescription(
            PythonLaunchDescriptionSource(graph_launch_file()),
            launch_arguments=[tuple(argument.split(':=', 1)) for argument in launch_arguments]),
    ]))
    returncode = service.run()
    if reasons and reasons[0] not in NORMAL_ENDS:
        print(f'bringup: {reasons[0]}', file=sys.stderr, flush=True)
        return 1
    return returncode


if __name__ == '__main__':
    sys.exit(run_graph(sys.argv[1:]))
