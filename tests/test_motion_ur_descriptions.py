"""Kinematics and the motion node on Universal Robots' own descriptions (UR5, UR3, UR5e, UR3e).

The descriptions are shaped as ur_description's ``ur_macro.xacro`` renders them
(tests/real_robot_standins.py says what they were checked against): ``base_link_inertia``,
``flange`` -> ``tool0``, no ``rg2_tcp``. Where ur_description and xacro are installed (a ROS
install), its own xacro output is checked too. Every tool pose is judged by forward kinematics
along the description's own chain, not by the DH model under test.
"""

import math
import xml.etree.ElementTree as ET

from conftest import wait_for
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from real_robot_standins import (
    MODELS,
    UrDriver,
    action_remaps,
    add,
    chain_pose,
    ur_description,
)
from ur_rg2_common.tf_buffer import set_pose
from ur_rg2_motion import kinematics
from ur_rg2_motion.kinematics import ArmKinematics, KinematicsError
from ur_rg2_motion.motion_node import MotionNode
from ur_rg2_motion.planning import gripper_down

TCP_OFFSET = (0.0, 0.0, 0.18)  # m from tool0: about an RG2's grasp point
TOLERANCE = 0.001  # m, the issue's
TIMEOUT = 60.0  # s on a loaded machine
# A bent, elbow-up start: the wrist pointing down, the TCP in front of the base.
START = (0.0, -1.9, 1.9, -1.57, -1.57, 0.0)


def tcp_by_chain(urdf: str, joints) -> np.ndarray:
    tcp = np.eye(4)
    tcp[:3, 3] = TCP_OFFSET
    return chain_pose(urdf, joints) @ tcp


@pytest.mark.parametrize('model', MODELS)
def test_the_model_is_told_by_the_chain_and_ik_lands_by_the_chains_fk(model):
    urdf = ur_description(model)
    arm = ArmKinematics.from_urdf(urdf, tcp_offset=TCP_OFFSET)
    assert arm.model == model
    rng = np.random.default_rng(32)
    landed = 0
    for q in rng.uniform(-math.pi, math.pi, size=(300, 6)):
        target = tcp_by_chain(urdf, q)
        try:
            solved = arm.solve(target, np.zeros(6))
        except KinematicsError:
            continue  # beyond a joint limit or singular: not a question of the chain
        reached = tcp_by_chain(urdf, solved)
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < TOLERANCE, (q, solved)
        assert kinematics.rotation_angle(reached, target) < 1e-3
        landed += 1
    assert landed > 250


def _joints(urdf: str) -> dict:
    return {joint.get('name'): (joint.get('type'), joint.find('parent').get('link'),
                                joint.find('child').get('link'),
                                *(np.array([float(v) for v in element.get(key).split()])
                                  for element, key in ((joint.find('origin'), 'xyz'),
                                                       (joint.find('origin'), 'rpy'))),
                                {k: float(v) for k, v in (joint.find('limit').attrib.items()
                                                          if joint.find('limit') is not None
                                                          else ()) if k != 'effort'})
            for joint in ET.fromstring(urdf).iter('joint')}


@pytest.mark.parametrize('model', MODELS)
def test_urs_own_xacro_output_is_the_stand_ins_and_ik_lands_on_it(model):
    xacro = pytest.importorskip('xacro')
    share = pytest.importorskip('ament_index_python.packages')
    try:
        package = share.get_package_share_directory('ur_description')
    except share.PackageNotFoundError:
        pytest.skip('ur_description is not installed')
    urdf = xacro.process_file(f'{package}/urdf/ur.urdf.xacro',
                              mappings={'ur_type': model, 'name': model}).toxml()
    ours, theirs = _joints(ur_description(model)), _joints(urdf)
    assert ours.keys() == theirs.keys()
    for name, (kind, parent, child, xyz, rpy, limit) in theirs.items():
        assert ours[name][:3] == (kind, parent, child), name
        assert np.allclose(ours[name][3], xyz) and np.allclose(ours[name][4], rpy), name
        assert ours[name][5] == pytest.approx(limit), name
    arm = ArmKinematics.from_urdf(urdf, tcp_offset=TCP_OFFSET)
    assert arm.model == model
    for q in np.random.default_rng(5).uniform(-math.pi, math.pi, size=(50, 6)):
        target = tcp_by_chain(urdf, q)
        try:
            reached = tcp_by_chain(urdf, arm.solve(target, np.zeros(6)))
        except KinematicsError:
            continue
        assert np.linalg.norm(reached[:3, 3] - target[:3, 3]) < TOLERANCE


def test_a_description_without_the_tcp_or_the_chain_is_refused_naming_what_is_missing():
    urdf = ur_description('ur5e')
    with pytest.raises(KinematicsError, match='no rg2_tcp frame .* no TCP offset'):
        ArmKinematics.from_urdf(urdf)
    with pytest.raises(KinematicsError, match='no tool0 frame'):
        ArmKinematics.from_urdf(urdf.replace('tool0', 'tool_flange'), tcp_offset=TCP_OFFSET)
    with pytest.raises(KinematicsError, match='lacks wrist_3_joint'):
        ArmKinematics.from_urdf(urdf.replace('"wrist_3_joint"', '"wrist_joint_3"'),
                                tcp_offset=TCP_OFFSET)
    # Forcing the wrong model: the chain says by how far it misses.
    with pytest.raises(KinematicsError, match=r'ur5, puts tool0 \d+\.\d mm from'):
        ArmKinematics.from_urdf(urdf, model='ur5', tcp_offset=TCP_OFFSET)


@pytest.mark.parametrize('model', MODELS)
def test_motion_is_ready_on_urs_description_and_a_tool_command_lands_within_1_mm(
        ros_graph, model, capfd):
    urdf = ur_description(model)
    driver = add(ros_graph, UrDriver(urdf, START, context=ros_graph.context))
    # The driver's scaled_joint_trajectory_controller, as docs/real-robot.md remaps it.
    motion = MotionNode(context=ros_graph.context, cli_args=['--ros-args', *action_remaps()],
                        parameter_overrides=[Parameter('tcp_offset', value=list(TCP_OFFSET))])
    add(ros_graph, motion)
    err: list[str] = []
    wait_for(lambda: err.append(capfd.readouterr().err) or f'ready: {model.upper()} kinematics'
             in ''.join(err), TIMEOUT, 'the motion node to be ready')
    probe = ros_graph.node('probe')
    command = probe.create_publisher(PoseStamped, 'tool_command', 10)
    wait_for(lambda: command.get_subscription_count(), TIMEOUT, 'the motion node to subscribe')
    wait_for(motion._trajectory.server_is_ready, TIMEOUT, 'the scaled trajectory controller')
    # Sent at once: the node holds a command that comes before the latched /tf_static.
    start = tcp_by_chain(urdf, START)
    reach = 0.5 if model.startswith('ur5') else 0.3
    target = gripper_down((reach * 0.8, -reach * 0.3, start[2, 3] - 0.1), 0.4)
    message = PoseStamped()
    message.header.frame_id = 'base_link'
    set_pose(message.pose, target)
    command.publish(message)

    def landed():
        return np.linalg.norm(tcp_by_chain(urdf, driver.joints())[:3, 3]
                              - target[:3, 3]) < TOLERANCE
    wait_for(landed, TIMEOUT, f'the TCP within 1 mm of {target[:3, 3]}')


def test_a_tool_command_sent_before_the_driver_is_up_is_executed_once_it_is(ros_graph):
    """A command before the robot is in the graph is held, and runs once it is.

    As in a graph's first seconds: robot_description, /tf_static, joint_states and the
    controller's action all come after the command.
    """
    urdf = ur_description('ur5e')
    motion = add(ros_graph, MotionNode(
        context=ros_graph.context, cli_args=['--ros-args', *action_remaps()],
        parameter_overrides=[Parameter('tcp_offset', value=list(TCP_OFFSET))]))
    probe = ros_graph.node('probe')
    command = probe.create_publisher(PoseStamped, 'tool_command', 10)
    wait_for(lambda: command.get_subscription_count(), TIMEOUT, 'the motion node to subscribe')
    assert motion.state.urdf is None  # no driver yet: nothing of the robot has come
    start = tcp_by_chain(urdf, START)
    target = gripper_down((0.4, -0.15, start[2, 3] - 0.1), 0.4)
    message = PoseStamped()
    message.header.frame_id = 'base_link'
    set_pose(message.pose, target)
    command.publish(message)
    driver = add(ros_graph, UrDriver(urdf, START, context=ros_graph.context))
    wait_for(lambda: np.linalg.norm(tcp_by_chain(urdf, driver.joints())[:3, 3]
                                    - target[:3, 3]) < TOLERANCE,
             TIMEOUT, f'the TCP within 1 mm of {target[:3, 3]}')
