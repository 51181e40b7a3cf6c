"""tf2_msgs and control_msgs as the nodes use them: importable, Jazzy's types, across processes.

On the pip path scripts/build-interfaces builds them from interfaces/ into the venv; in a ROS
install they are the distribution's. Either way these tests hold.
"""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys

from ament_index_python.packages import get_package_share_directory
from builtin_interfaces.msg import Duration
from conftest import wait_for
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointComponentTolerance
import pytest
from tf2_msgs.msg import TFMessage
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_rg2_common.action_client import ThreadSafeActionClient

# ROS Jazzy's type hashes (REP 2011). TFMessage's is the one real Jazzy publishes. The control_msgs
# ones equal those in public code generated from control_msgs 5.x: the messages' from Jazzy's
# rosidl (description.c), the actions' from a rosidl that still wrote them into struct.h.
JAZZY_TYPE_HASHES = {
    'tf2_msgs/msg/TFMessage':
        'RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087',
    'control_msgs/msg/JointTolerance':
        'RIHS01_c254f9cece0f3b733017b6990fd46d1326e25242d6b8844398c97d9a88e7d648',
    'control_msgs/msg/JointComponentTolerance':
        'RIHS01_739ea7566931944d33830fa10f1bf5e7a7fbdc3172bce7a7eaac642bd6e3ffa4',
    'control_msgs/msg/GripperCommand':
        'RIHS01_57eb8f326c9889ca8bb34ead82cc94cc09bf6bc5c3b6c09546dca3a00b589890',
    'control_msgs/action/FollowJointTrajectory':
        'RIHS01_738ebcb7a2d7cfa42f9f1001cc99ce3a4383d1cfe508015d9be8485e4b1c66f6',
    'control_msgs/action/GripperCommand':
        'RIHS01_e17c0e644eccf14bea84a0a93e0977182872c2eb7873ca6694900059b46dbc84',
}
# The action types that travel as topics (feedback), as advertised on the graph.
FEEDBACK_TYPE_HASHES = {
    'control_msgs/action/FollowJointTrajectory_FeedbackMessage':
        'RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71',
    'control_msgs/action/GripperCommand_FeedbackMessage':
        'RIHS01_392ff03fcd872f9dc2405cbeb2897fcf011ad9998458b6aa85c603b8a49e431d',
}
TRAJECTORY_ACTION = 'joint_trajectory_controller/follow_joint_trajectory'
GRIPPER_ACTION = 'gripper_controller/gripper_cmd'
TIMEOUT = 30.0  # s, for discovery and replies on a loaded machine

# Run in a separate interpreter: publishes one TFMessage on /tf ten times a second.
TF_PUBLISHER = """
import rclpy
from geometry_msgs.msg import TransformStamped
from rclpy.executors import ExternalShutdownException
from tf2_msgs.msg import TFMessage

rclpy.init()
node = rclpy.create_node('interfaces_test_tf_publisher')
publisher = node.create_publisher(TFMessage, '/tf', 10)
transform = TransformStamped(child_frame_id='tool0')
transform.header.frame_id = 'base'
transform.header.stamp.sec = 42
transform.transform.translation.x = 0.5
transform.transform.rotation.w = 1.0
message = TFMessage(transforms=[transform])
node.create_timer(0.1, lambda: publisher.publish(message))
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""

# Run in a separate interpreter: both controller actions, answering from the goal's content.
ACTION_SERVER = f"""
import rclpy
from control_msgs.action import FollowJointTrajectory, GripperCommand
from rclpy.action import ActionServer
from rclpy.executors import ExternalShutdownException


def follow(goal_handle):
    trajectory = goal_handle.request.trajectory
    feedback = FollowJointTrajectory.Feedback(joint_names=trajectory.joint_names)
    feedback.desired = trajectory.points[-1]
    goal_handle.publish_feedback(feedback)
    goal_handle.succeed()
    tolerance = goal_handle.request.component_goal_tolerance[0]
    return FollowJointTrajectory.Result(
        error_code=FollowJointTrajectory.Result.SUCCESSFUL,
        error_string=f'{{len(trajectory.points)}} points, component {{tolerance.component}}')


def grip(goal_handle):
    command = goal_handle.request.command
    goal_handle.publish_feedback(GripperCommand.Feedback(position=command.position))
    goal_handle.succeed()
    return GripperCommand.Result(position=command.position, effort=command.max_effort,
                                 stalled=True, reached_goal=False)


rclpy.init()
node = rclpy.create_node('interfaces_test_action_server')
ActionServer(node, FollowJointTrajectory, {TRAJECTORY_ACTION!r}, follow)
ActionServer(node, GripperCommand, {GRIPPER_ACTION!r}, grip)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""


@pytest.fixture
def run_python(tmp_path):
    """Start Python source in a subprocess of a given environment; stop them all afterwards."""
    processes: list[tuple[subprocess.Popen, Path]] = []

    def start(source: str, env: dict[str, str]) -> subprocess.Popen:
        log = tmp_path / f'process{len(processes)}.log'
        with log.open('w') as out:
            process = subprocess.Popen([sys.executable, '-c', source], env=env,
                                       stdin=subprocess.DEVNULL, stdout=out,
                                       stderr=subprocess.STDOUT)
        processes.append((process, log))
        return process

    yield start
    for process, log in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        assert 'Traceback' not in log.read_text(), log.read_text()


def installed_type_hash(type_name: str) -> str:
    """Return the hash of ``pkg/kind/Type`` from its type description in the ament index."""
    package, kind, name = type_name.split('/')
    description = Path(get_package_share_directory(package)) / kind / f'{name}.json'
    hashes = json.loads(description.read_text())['type_hashes']
    return next(h['hash_string'] for h in hashes if h['type_name'] == type_name)


def advertised_type_hash(node, topic: str) -> str:
    """Wait for a publisher of ``topic`` on the graph; return the type hash it advertises."""
    publishers = wait_for(lambda: node.get_publishers_info_by_topic(topic), TIMEOUT,
                          f'a publisher of {topic}')
    return str(publishers[0].topic_type_hash)


def test_types_load_in_a_fresh_interpreter():
    # Without the inherited library path: the venv's start-up hook must find the typesupport
    # libraries on its own, as in a new shell.
    env = {k: v for k, v in os.environ.items()
           if k not in ('LD_LIBRARY_PATH', '_ROS_WHEELS_BOOTSTRAP_COMPLETE')}
    probe = ('from rclpy.type_support import check_for_type_support\n'
             'from rclpy.serialization import serialize_message, deserialize_message\n'
             'from tf2_msgs.msg import TFMessage\n'
             'from control_msgs.action import FollowJointTrajectory, GripperCommand\n'
             'from control_msgs.msg import JointTolerance, JointComponentTolerance\n'
             'for t in (TFMessage, FollowJointTrajectory, GripperCommand, JointTolerance,\n'
             '          JointComponentTolerance):\n'
             '    check_for_type_support(t)\n'
             'data = serialize_message(FollowJointTrajectory.Goal())\n'
             'print(type(deserialize_message(data, FollowJointTrajectory.Goal)).__name__)\n')
    out = subprocess.run([sys.executable, '-c', probe], env=env, capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == 'FollowJointTrajectory_Goal'


def test_definitions_have_jazzys_fields_and_constants():
    assert TFMessage.get_fields_and_field_types() == {
        'transforms': 'sequence<geometry_msgs/TransformStamped>'}
    assert list(FollowJointTrajectory.Goal.get_fields_and_field_types()) == [
        'trajectory', 'multi_dof_trajectory', 'path_tolerance', 'component_path_tolerance',
        'goal_tolerance', 'component_goal_tolerance', 'goal_time_tolerance']
    result = FollowJointTrajectory.Result
    assert [result.SUCCESSFUL, result.INVALID_GOAL, result.INVALID_JOINTS,
            result.OLD_HEADER_TIMESTAMP, result.PATH_TOLERANCE_VIOLATED,
            result.GOAL_TOLERANCE_VIOLATED] == [0, -1, -2, -3, -4, -5]
    assert list(result.get_fields_and_field_types()) == ['error_code', 'error_string']
    assert [JointComponentTolerance.X_AXIS, JointComponentTolerance.Y_AXIS,
            JointComponentTolerance.Z_AXIS, JointComponentTolerance.TRANSLATION,
            JointComponentTolerance.ROTATION] == [1, 2, 3, 4, 5]
    assert GripperCommand.Result.get_fields_and_field_types() == {
        'position': 'double', 'effort': 'double', 'stalled': 'boolean',
        'reached_goal': 'boolean'}


@pytest.mark.parametrize('type_name', sorted(JAZZY_TYPE_HASHES))
def test_type_hash_is_jazzys(type_name):
    assert installed_type_hash(type_name) == JAZZY_TYPE_HASHES[type_name]


def test_tf_message_crosses_processes_with_jazzys_type_hash(ros_graph, run_python):
    received: list[TFMessage] = []
    node = ros_graph.node('tf_listener')
    node.create_subscription(TFMessage, '/tf', received.append, 10)
    publisher = run_python(TF_PUBLISHER, ros_graph.env)

    assert advertised_type_hash(node, '/tf') == JAZZY_TYPE_HASHES['tf2_msgs/msg/TFMessage']
    wait_for(lambda: received or publisher.poll() is not None, TIMEOUT, 'a TFMessage')
    transform, = received[0].transforms
    assert (transform.header.frame_id, transform.child_frame_id) == ('base', 'tool0')
    assert transform.header.stamp.sec == 42
    assert transform.transform.translation.x == 0.5
    assert transform.transform.rotation.w == 1.0


def call(client: ThreadSafeActionClient, goal, feedback: list) -> object:
    """Send ``goal``; return the result once the server has answered (wrapped, with status)."""
    sent = client.send_goal_async(goal, feedback_callback=feedback.append)
    handle = wait_for(lambda: sent.done() and sent.result(), TIMEOUT, 'the goal response')
    assert handle.accepted
    result = handle.get_result_async()
    return wait_for(lambda: result.done() and result.result(), TIMEOUT, 'the result')


def test_controller_actions_cross_processes(ros_graph, run_python):
    node = ros_graph.node('action_client')
    trajectory_client = ThreadSafeActionClient(node, FollowJointTrajectory, TRAJECTORY_ACTION)
    gripper_client = ThreadSafeActionClient(node, GripperCommand, GRIPPER_ACTION)
    server = run_python(ACTION_SERVER, ros_graph.env)
    wait_for(lambda: (trajectory_client.server_is_ready() and gripper_client.server_is_ready())
             or server.poll() is not None, TIMEOUT, 'the action servers')
    assert server.poll() is None

    for action, name in ((TRAJECTORY_ACTION, 'FollowJointTrajectory'),
                         (GRIPPER_ACTION, 'GripperCommand')):
        feedback_type = f'control_msgs/action/{name}_FeedbackMessage'
        assert (advertised_type_hash(node, f'/{action}/_action/feedback')
                == FEEDBACK_TYPE_HASHES[feedback_type])

    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ['elbow_joint', 'shoulder_pan_joint']
    goal.trajectory.points = [
        JointTrajectoryPoint(positions=[0.1, 0.2], time_from_start=Duration(sec=1)),
        JointTrajectoryPoint(positions=[0.3, 0.4], time_from_start=Duration(sec=2))]
    goal.component_goal_tolerance = [JointComponentTolerance(
        joint_name='elbow_joint', component=JointComponentTolerance.ROTATION, position=0.01)]
    feedback: list = []
    answer = call(trajectory_client, goal, feedback)
    assert answer.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    assert answer.result.error_string == '2 points, component 5'
    wait_for(lambda: feedback, TIMEOUT, 'trajectory feedback')
    assert list(feedback[0].feedback.desired.positions) == [0.3, 0.4]

    feedback = []
    goal = GripperCommand.Goal()
    goal.command.position = 0.06
    goal.command.max_effort = 20.0
    answer = call(gripper_client, goal, feedback)
    assert (answer.result.position, answer.result.effort) == (0.06, 20.0)
    assert (answer.result.stalled, answer.result.reached_goal) == (True, False)
    wait_for(lambda: feedback, TIMEOUT, 'gripper feedback')
    assert feedback[0].feedback.position == 0.06
