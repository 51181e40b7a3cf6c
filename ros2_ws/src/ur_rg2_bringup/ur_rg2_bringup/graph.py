"""The node graph that ``graph.launch.py`` starts, and how its launch arguments reach the nodes.

Plain data and functions, no launch import: the launch file, the ``graph`` executable and the
tests share them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import difflib
import signal


@dataclass(frozen=True)
class GraphNode:
    """One node of the graph."""

    name: str
    """Short name: for parameters meant for this node only (``sim:camera_rate:=15.0``)."""
    package: str
    executable: str
    node_name: str
    """The ROS node name (``ur_rg2_sim:camera_rate:=15.0`` works too)."""


# What the launch file starts, in start order. keys is not here: it needs a terminal.
# ur_rg2_common has no node of its own: every node here is built on it.
NODES: tuple[GraphNode, ...] = (
    GraphNode('sim', 'ur_rg2_sim', 'sim', 'ur_rg2_sim'),
    GraphNode('vision', 'ur_rg2_vision', 'vision', 'ur_rg2_vision'),
    GraphNode('motion', 'ur_rg2_motion', 'motion', 'ur_rg2_motion'),
    GraphNode('viewer', 'ur_rg2_vision', 'viewer', 'ur_rg2_viewer'),
)
KEYS = GraphNode('keys', 'ur_rg2_teleop', 'keys', 'ur_rg2_teleop')

ALL_NODES = tuple(node.name for node in NODES)


@dataclass(frozen=True)
class ParameterArgument:
    """A launch argument that sets the parameter of the same name on the nodes that have it."""

    name: str
    description: str
    nodes: tuple[str, ...]


def _sim(name: str, description: str) -> ParameterArgument:
    return ParameterArgument(name, description, ('sim',))


def _vision(name: str, description: str) -> ParameterArgument:
    return ParameterArgument(name, description, ('vision',))


def _motion(name: str, description: str) -> ParameterArgument:
    return ParameterArgument(name, description, ('motion',))


def _viewer(name: str, description: str) -> ParameterArgument:
    return ParameterArgument(name, description, ('viewer',))


# Every parameter a node of the graph declares (tests/test_launch.py checks this against the
# running nodes). An argument left unset leaves the node's own default; the defaults are in
# the descriptions, and the nodes are where they are defined.
PARAMETER_ARGUMENTS: tuple[ParameterArgument, ...] = (
    _sim('robot_model', 'UR arm model: ur5 or ur3 (sim; default ur5)'),
    _sim('gui', 'Open the pybullet GUI window, needs a display (sim; default false)'),
    _sim('real_time_factor', 'Simulation speed relative to the wall clock; 0: as fast as '
         'possible (sim; default 1.0)'),
    _sim('physics_rate', 'Physics steps per second of simulation time (sim; default 240.0)'),
    _sim('joint_state_rate', 'joint_states and /tf rate, Hz of simulation time (sim; default '
         '100.0)'),
    _sim('camera_rate', 'Camera frame rate, Hz of simulation time; 0 turns the camera off '
         '(sim; default 30.0)'),
    _sim('camera_width', 'Image width, pixels (sim; default 640)'),
    _sim('camera_height', 'Image height, pixels (sim; default 480)'),
    _sim('camera_hfov', 'Horizontal field of view, degrees (sim; default 57.0, Kinect v1)'),
    _sim('camera_position', 'Camera position [x, y, z], world frame, m (sim)'),
    _sim('camera_look_at', 'Point the camera looks at [x, y, z], world frame, m (sim)'),
    _sim('ball_position', 'Ball centre [x, y, z], world frame, m (sim; default on the floor in '
         'front of the robot)'),
    ParameterArgument('ball_radius', 'Ball radius, m: the ball the sim makes (default 0.03) '
                      'and the radius vision assumes instead of measuring it (default 0: '
                      "measure); sim:ball_radius:=... changes the sim's ball alone",
                      ('sim', 'vision')),
    _sim('ball_color', 'Ball colour [r, g, b, a], 0-1 (sim; default red [1, 0, 0, 1])'),
    _sim('home_position', 'Arm home pose for reset, rad, joint order of joint_states (sim; '
         'default zeros)'),
    _sim('frame_prefix', 'Prepended to every frame id the sim publishes (sim; default empty)'),
    _sim('floor_color', 'Floor colour [r, g, b], 0-1 (sim; default grey)'),
    _sim('light_direction', 'Direction toward the light [x, y, z], world frame (sim)'),
    _sim('scene_objects', 'Objects on the floor that are not balls, e.g. '
         "'box 0.5 0.1 0 0.03 0.03 0.03 1 0 0; disc ...' (sim; default none)"),
    _vision('frames_dir', 'Directory for saved camera frames (vision; default frames)'),
    _vision('save_every_n', 'Save every Nth colour frame automatically; 0: off (vision; '
            'default 0)'),
    _vision('hsv_lower', 'Ball colour, lower HSV bound [H, S, V], OpenCV scale (vision; default '
            '[170, 100, 40])'),
    _vision('hsv_upper', 'Ball colour, upper HSV bound [H, S, V] (vision; default '
            '[10, 255, 255])'),
    _vision('min_radius_px', 'Smallest ball radius in pixels that counts as a ball (vision; '
            'default 4.0)'),
    _vision('detector', 'How vision finds balls: color (the colour range) or learned (the '
            'trained detector, balls of any colour) (vision; default color)'),
    _vision('model_dir', "The learned detector's directory, written by train_detector "
            '(vision; default empty: the model shipped with ur_rg2_vision)'),
    _motion('lift_height', 'How high pick_ball lifts the ball, m (motion; default 0.15)'),
    _motion('approach_height', 'pick_ball comes down onto the ball from this high above the '
            'grasp, m (motion; default 0.1)'),
    _motion('speed_scale', "Fraction of the joints' velocity limits that TCP moves and the pick "
            'use at most (motion; default 0.7)'),
    _motion('tcp_speed', 'Peak TCP speed of tool_command and tool_jog moves, m/s (motion; '
            'default 0.25)'),
    _motion('approach_speed', "Peak TCP speed of the pick's descent and lift, m/s (motion; "
            'default 0.25)'),
    _motion('ball_timeout', 'pick_ball uses a ball/position at most this old, s (motion; '
            'default 1.0)'),
    _motion('floor_clearance', 'Height above the floor that the TCP, fingers, wrist and elbow '
            'keep, m (motion; default 0.005)'),
    _motion('pedestal_half_width', 'Half the width of the pedestal kept out of, m (motion; '
            'default 0.11)'),
    _motion('grasp_tolerance', "A gripper stopped within this of the ball's diameter holds it, "
            'm (motion; default 0.02)'),
    _viewer('address', 'Address the viewer serves on (viewer; default 127.0.0.1: the page has '
            'no authentication)'),
    _viewer('port', 'TCP port of the viewer, http://127.0.0.1:PORT/; 0: any free port (viewer; '
            'default 8080)'),
    _viewer('image_topic', 'Image topic the viewer streams (viewer; default ball/image)'),
    _viewer('jpeg_quality', 'JPEG quality of the stream, 1-100 (viewer; default 80)'),
    ParameterArgument('use_sim_time', "Every node's clock follows /clock, the sim's time "
                      '(default false)', ALL_NODES),
)

# Launch arguments that are not parameters.
USE_SIM_ARGUMENT = ('use_sim', 'Start the simulator (true), or leave it out (false) for a real '
                    'arm and camera whose drivers provide its topics and actions')
NAMESPACE_ARGUMENT = ('namespace', 'Namespace of every node (default: none)')
ROS_ARGS_ARGUMENT = ('ros_args', "More ROS arguments for every node, as after --ros-args (e.g. "
                     "'--log-level debug')")
# Launch's own settings, which users may set on the command line too.
_LAUNCH_SETTINGS = frozenset({'sigterm_timeout', 'sigkill_timeout'})


def _node_by_name(name: str) -> GraphNode | None:
    for node in (*NODES, KEYS):
        if name in (node.name, node.node_name):
            return node
    return None


def _did_you_mean(name: str, candidates: list[str]) -> str:
    close = difflib.get_close_matches(name, sorted(set(candidates)), n=1)
    return f' (did you mean {close[0]}?)' if close else ''


def route_parameters(assignments: Mapping[str, str],
                     nodes: tuple[GraphNode, ...] = NODES,
                     ) -> tuple[dict[str, list[str]], list[str]]:
    """Turn launch arguments into each node's ``-p NAME:=VALUE`` ROS arguments.

    ``assignments`` maps launch argument names to the values given (unset ones left out):
    ``NAME`` goes to every node that declares parameter NAME; ``NODE:NAME`` to that node only
    (NODE a short name such as ``sim`` or a node name such as ``ur_rg2_sim``). Values stay
    YAML text for rcl to parse, as with ``ros2 run``. Returns the arguments by short node name
    and one message per assignment that no node of ``nodes`` declares.
    """
    by_parameter = {argument.name: argument for argument in PARAMETER_ARGUMENTS}
    started = {node.name for node in nodes}
    other_arguments = {USE_SIM_ARGUMENT[0], NAMESPACE_ARGUMENT[0], ROS_ARGS_ARGUMENT[0],
                       *_LAUNCH_SETTINGS}
    ros_arguments: dict[str, list[str]] = {node.name: [] for node in nodes}
    unknown: list[str] = []
    for key, value in assignments.items():
        if key in other_arguments:
            continue
        target_name, _, parameter = key.rpartition(':')
        if target_name:
            target = _node_by_name(target_name)
            if target is None or target.name not in started:
                unknown.append(f'no node {target_name!r} in the graph for {key}:=...'
                               + _did_you_mean(target_name, [n.name for n in nodes]))
                continue
            argument = by_parameter.get(parameter)
            if argument is None or target.name not in argument.nodes:
                declared = [a.name for a in PARAMETER_ARGUMENTS if target.name in a.nodes]
                unknown.append(f'{target.node_name} does not declare parameter {parameter!r}'
                               + _did_you_mean(parameter, declared))
                continue
            ros_arguments[target.name] += ['-p', f'{parameter}:={value}']
            continue
        argument = by_parameter.get(key)
        receivers = [name for name in argument.nodes if name in started] if argument else []
        if not receivers:
            if argument is None:
                unknown.append(f'no node declares parameter {key!r}'
                               + _did_you_mean(key, list(by_parameter)))
            else:
                unknown.append(f'parameter {key!r} is for {", ".join(argument.nodes)}, '
                               'which is not started')
            continue
        for name in receivers:
            ros_arguments[name] += ['-p', f'{key}:={value}']
    return ros_arguments, unknown


def graph_nodes(use_sim: str) -> tuple[GraphNode, ...]:
    """Return the nodes to start for a ``use_sim`` launch argument (true or false, any case)."""
    if use_sim.lower() == 'true':
        return NODES
    if use_sim.lower() == 'false':
        return tuple(node for node in NODES if node.package != 'ur_rg2_sim')
    raise ValueError(f'use_sim:={use_sim!r}: expected true or false')


def describe_exit(returncode: int) -> str:
    """Say how a process ended, from its return code (negative: the signal that killed it)."""
    if returncode >= 0:
        return f'exited with code {returncode}'
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        name = 'unknown signal'
    return f'was killed by signal {-returncode} ({name})'
