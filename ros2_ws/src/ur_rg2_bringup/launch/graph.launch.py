"""The UR + RG2 node graph: sim, vision, motion and viewer (``use_sim:=false``: without sim).

    ros2 launch ur_rg2_bringup graph.launch.py [NAME:=VALUE ...] [NODE:NAME:=VALUE ...]

Every parameter a node declares is a launch argument of the same name, routed to the nodes
that declare it (``ros2 launch ur_rg2_bringup graph.launch.py --show-args`` lists them);
``NODE:NAME:=VALUE`` sets a parameter of one node (``sim:ball_radius:=0.05``). A name that no
node declares is reported. The keyboard teleop is not started here: it needs a terminal of its
own (``ros2 run ur_rg2_teleop keys``), and ``ros2 run ur_rg2_bringup graph`` (``scripts/run``)
runs this file with keys in the foreground.

A node that exits on its own stops the graph: launch logs which node, how it ended and the
last error it logged, and shuts down with that reason. Ctrl-C stops every node (SIGINT, then
SIGTERM after ``sigterm_timeout`` s, then SIGKILL).
"""

import re
import shlex
import signal

from launch import LaunchContext, LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    OpaqueFunction,
    RegisterEventHandler,
    Shutdown,
)
from launch.event_handlers import OnProcessExit, OnProcessIO, OnProcessStart, OnShutdown
from launch.events import matches_action
from launch.events.process import ProcessExited, ProcessIO, SignalProcess
from launch.events.shutdown import Shutdown as ShutdownEvent
import launch.logging
from launch_ros.actions import Node
from ur_rg2_bringup.graph import (
    NAMESPACE_ARGUMENT,
    PARAMETER_ARGUMENTS,
    ROS_ARGS_ARGUMENT,
    USE_SIM_ARGUMENT,
    describe_exit,
    graph_nodes,
    route_parameters,
)

# An error in a ROS log line, as rcutils prints it, once colour codes are removed.
_ERROR_LINE = re.compile(r'\[(ERROR|FATAL)\]')
_COLOR_CODE = re.compile(r'\x1b\[[0-9;]*m')


def generate_launch_description() -> LaunchDescription:
    """Declare the arguments; the nodes are made once their values are known."""
    arguments = [DeclareLaunchArgument(argument.name, default_value='',
                                       description=argument.description)
                 for argument in PARAMETER_ARGUMENTS]
    arguments.append(DeclareLaunchArgument(USE_SIM_ARGUMENT[0], default_value='true',
                                           description=USE_SIM_ARGUMENT[1],
                                           choices=['true', 'false', 'True', 'False']))
    arguments += [DeclareLaunchArgument(name, default_value='', description=description)
                  for name, description in (NAMESPACE_ARGUMENT, ROS_ARGS_ARGUMENT)]
    return LaunchDescription([*arguments, OpaqueFunction(function=_graph)])


def _graph(context: LaunchContext) -> list:
    logger = launch.logging.get_logger('graph.launch.py')
    given = {name: value for name, value in context.launch_configurations.items()
             if value != ''}
    nodes = graph_nodes(given[USE_SIM_ARGUMENT[0]])
    ros_arguments, unknown = route_parameters(given, nodes)
    for message in unknown:
        logger.warning(f'{message}: ignored')
    extra = shlex.split(given.get(ROS_ARGS_ARGUMENT[0], ''))
    last_errors: dict[str, str] = {}
    started: list[Node] = []
    actions: list = []
    for spec in nodes:
        node = Node(package=spec.package, executable=spec.executable, name=spec.node_name,
                    namespace=given.get(NAMESPACE_ARGUMENT[0], ''), output='screen',
                    ros_arguments=ros_arguments[spec.name] + extra)
        actions += [
            node,
            RegisterEventHandler(OnProcessStart(
                target_action=node, on_start=lambda _event, _context, node=node: started.append(
                    node))),
            RegisterEventHandler(OnProcessIO(
                target_action=node,
                on_stdout=lambda event, name=spec.name: _remember_error(event, name, last_errors),
                on_stderr=lambda event, name=spec.name: _remember_error(event, name, last_errors),
            )),
            RegisterEventHandler(OnProcessExit(
                target_action=node,
                on_exit=lambda event, context, name=spec.name: _stop_graph(
                    event, context, name, last_errors, logger),
            )),
        ]
    # On SIGINT launch sends its nodes nothing, trusting the terminal's Ctrl-C to have reached
    # them too; a SIGINT to launch alone (a script, a test harness, a service manager) would
    # then stop them only by SIGTERM after sigterm_timeout. So every node gets SIGINT here;
    # one that had it from the terminal already takes the second in its stride.
    actions.append(RegisterEventHandler(OnShutdown(
        on_shutdown=lambda event, _context: _interrupt(event, started))))
    return actions


def _interrupt(event: ShutdownEvent, started: list[Node]) -> list | None:
    """On a SIGINT to launch, SIGINT to every node started (launch signals no unstarted one)."""
    if not event.due_to_sigint:
        return None
    return [EmitEvent(event=SignalProcess(signal_number=signal.SIGINT,
                                          process_matcher=matches_action(node)))
            for node in started]


def _remember_error(event: ProcessIO, name: str, last_errors: dict[str, str]) -> None:
    text = _COLOR_CODE.sub('', event.text.decode(errors='replace'))
    for line in text.splitlines():
        if _ERROR_LINE.search(line):
            last_errors[name] = line.strip()


def _stop_graph(event: ProcessExited, context: LaunchContext, name: str,
                last_errors: dict[str, str], logger) -> list | None:
    """Shut the graph down when a node ends on its own, saying which one and why."""
    if context.is_shutdown:
        return None
    reason = f'{name} {describe_exit(event.returncode)}'
    if name in last_errors:
        reason += f': {last_errors[name]}'
    logger.error(f'{reason}; stopping the graph')
    return [Shutdown(reason=reason)]
