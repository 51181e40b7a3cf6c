"""Our graph on a real UR cell: graph.launch.py use_sim:=false, remapped to the real drivers.

    ros2 launch ur_rg2_hardware real_robot.launch.py [params_file:=FILE] [port:=N] ...

Starts ur_rg2_bringup's graph without the sim (vision, motion, viewer) with every name the
real drivers use instead of the sim's (the table in docs/real-robot.md), and the RG2 adapter
(rg2_adapter) in front of OnRobot's driver. Started on their own: ur_robot_driver (its
``scaled_joint_trajectory_controller``), OnRobot's RG2 driver in the namespace ``onrobot``,
realsense2_camera with ``align_depth.enable:=true``, and the hand-eye static transform.
Action names cannot be remapped in Jazzy (ros2/ros2#1312): the action's five topics and
services are, one by one.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node, SetRemap
from launch_ros.substitutions import FindPackageShare

OURS = 'joint_trajectory_controller/follow_joint_trajectory'
THEIRS = 'scaled_joint_trajectory_controller/follow_joint_trajectory'
ACTION_PARTS = ('_action/send_goal', '_action/cancel_goal', '_action/get_result',
                '_action/feedback', '_action/status')
# Our name -> the real driver's (realsense2_camera with camera_namespace and camera_name both
# 'camera'; ur_robot_driver's default controller, which follows the pendant's speed slider).
REMAPS = (
    ('camera/color/image_raw', '/camera/camera/color/image_raw'),
    ('camera/color/camera_info', '/camera/camera/color/camera_info'),
    ('camera/depth/image_raw', '/camera/camera/aligned_depth_to_color/image_raw'),
    *((f'{OURS}/{part}', f'{THEIRS}/{part}') for part in ACTION_PARTS),
)


def generate_launch_description() -> LaunchDescription:
    """Return the arguments, the remapped graph and the RG2 adapter."""
    params_file = LaunchConfiguration('params_file')
    namespace = LaunchConfiguration('namespace')
    graph = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(PathJoinSubstitution(
            [FindPackageShare('ur_rg2_bringup'), 'launch', 'graph.launch.py'])),
        launch_arguments={'use_sim': 'false', 'params_file': params_file,
                          'port': LaunchConfiguration('port'), 'namespace': namespace}.items())
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution(
                [FindPackageShare('ur_rg2_bringup'), 'config', 'graph.yaml']),
            description="Parameters YAML of every node: a copy of ur_rg2_bringup's "
                        "config/graph.yaml with your cell's values (tcp_offset, ball colour)"),
        DeclareLaunchArgument(
            'port', default_value='8080',
            description='TCP port of the viewer, http://127.0.0.1:PORT/; 0: any free port'),
        DeclareLaunchArgument(
            'namespace', default_value='',
            description='Namespace of every node and its topics (empty: none)'),
        GroupAction([*(SetRemap(src=ours, dst=theirs) for ours, theirs in REMAPS), graph]),
        Node(package='ur_rg2_hardware', executable='rg2_adapter', name='ur_rg2_rg2_adapter',
             namespace=namespace, parameters=[params_file], output='screen'),
    ])
