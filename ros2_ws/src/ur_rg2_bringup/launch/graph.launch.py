"""The UR + RG2 node graph: sim, vision, motion and viewer, and the 3D view on request.

    ros2 launch ur_rg2_bringup graph.launch.py [ARGUMENT:=VALUE ...]

``--show-args`` lists the arguments. Every node's parameters have their defaults in
``config/graph.yaml`` of this package; ``params_file:=FILE`` uses another file (ready-made ones
are in ``config/examples/``). An argument below that sets a node's parameter overrides the file
when it is given, and takes the file's value when it is not (its own default when the file has
none). The keyboard teleop is not started here: it needs a terminal
(``ros2 run ur_rg2_teleop keys``, or ``ros2 run ur_rg2_bringup graph`` for both).
A node that exits on its own ends the graph, saying which node and how.
"""

from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, Shutdown
from launch.conditions import IfCondition
from launch.events.process import ProcessExited
import launch.logging
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare
from ur_rg2_bringup.graph import describe_exit
from ur_rg2_bringup.launch_defaults import FileParameter, NextPort

TRUE_FALSE = ['true', 'false']
# The vision node's detector unless detector:= or the parameters file says otherwise.
DEFAULT_DETECTOR = 'color'
SHIPPED_PARAMS = PathJoinSubstitution([FindPackageShare('ur_rg2_bringup'), 'config',
                                       'graph.yaml'])


def generate_launch_description() -> LaunchDescription:
    """Return the launch arguments, the nodes and what ends the graph."""
    params_file = LaunchConfiguration('params_file')

    def from_file(node: str, name: str, default) -> FileParameter:
        """Return the parameters file's value of a node's parameter, else ``default``."""
        return FileParameter(node, name, default,
                             LaunchConfiguration('params_file', default=SHIPPED_PARAMS))

    arguments = [
        DeclareLaunchArgument(
            'use_sim', default_value='true', choices=TRUE_FALSE,
            description='Start the simulator; false for a real arm and camera whose drivers '
                        'provide its topics and actions'),
        DeclareLaunchArgument(
            'robot_model', default_value=from_file('ur_rg2_sim', 'robot_model', 'ur5'),
            choices=['ur5', 'ur3'],
            description='UR arm model the sim simulates'),
        DeclareLaunchArgument(
            'gui', default_value=from_file('ur_rg2_sim', 'gui', 'false'), choices=TRUE_FALSE,
            description="Open pybullet's GUI window (needs a display)"),
        DeclareLaunchArgument(
            'camera_rate', default_value=from_file('ur_rg2_sim', 'camera_rate', '30.0'),
            description='Camera frame rate, Hz of simulation time; 0 turns the camera off'),
        DeclareLaunchArgument(
            'port', default_value=from_file('ur_rg2_viewer', 'port', '8080'),
            description='TCP port of the viewer, http://127.0.0.1:PORT/; 0: any free port'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of every node and its topics (empty: none)'),
        DeclareLaunchArgument(
            'view3d', default_value='false', choices=TRUE_FALSE,
            description='Start the 3D view (ur_rg2_tools view3d)'),
        DeclareLaunchArgument(
            'view3d_port',
            default_value=from_file('ur_rg2_view3d', 'port',
                                    NextPort(LaunchConfiguration('port'))),
            description='TCP port of the 3D view (view3d:=true), http://127.0.0.1:PORT/; '
                        "0: any free port; by default the one after the viewer's"),
        DeclareLaunchArgument(
            'detector', default_value=from_file('ur_rg2_vision', 'detector', DEFAULT_DETECTOR),
            choices=['color', 'learned'],
            description='How the vision node finds the ball: color (the colour range) or '
                        'learned (the trained network, any colour)'),
        DeclareLaunchArgument(
            'params_file', default_value=SHIPPED_PARAMS,
            description="Parameters YAML of every node (the default: this package's; "
                        'examples in its config/examples/)'),
    ]
    nodes = [
        _node('ur_rg2_sim', 'sim', 'ur_rg2_sim', [params_file, {
            'robot_model': LaunchConfiguration('robot_model'),
            'gui': LaunchConfiguration('gui'),
            'camera_rate': LaunchConfiguration('camera_rate'),
        }], condition=IfCondition(LaunchConfiguration('use_sim'))),
        _node('ur_rg2_vision', 'vision', 'ur_rg2_vision', [params_file, {
            'detector': LaunchConfiguration('detector'),
        }]),
        _node('ur_rg2_motion', 'motion', 'ur_rg2_motion', [params_file]),
        _node('ur_rg2_vision', 'viewer', 'ur_rg2_viewer', [params_file, {
            'port': LaunchConfiguration('port'),
        }]),
        _node('ur_rg2_tools', 'view3d', 'ur_rg2_view3d', [params_file, {
            'port': LaunchConfiguration('view3d_port'),
        }], condition=IfCondition(LaunchConfiguration('view3d'))),
    ]
    return LaunchDescription([*arguments, *nodes])


def _node(package: str, executable: str, name: str, parameters: list, condition=None) -> Node:
    """Return one node of the graph; its exit on its own ends the graph."""
    return Node(package=package, executable=executable, name=name,
                namespace=LaunchConfiguration('namespace'), parameters=parameters,
                output='screen', condition=condition, on_exit=_end_graph)


def _end_graph(event: ProcessExited, context: LaunchContext) -> list | None:
    """Shut the graph down when a node exits on its own, saying which one and how."""
    if context.is_shutdown:
        return None
    reason = f'{event.action.node_executable} {describe_exit(event.returncode)}'
    logger = launch.logging.get_logger('graph.launch.py')
    # Exit 0 is a stop on request, no error: a terminal's Ctrl-C reaches every node at once,
    # and launch may hear of a node's exit before its own SIGINT.
    (logger.info if event.returncode == 0 else logger.error)(f'{reason}; stopping the graph')
    return [Shutdown(reason=reason)]
