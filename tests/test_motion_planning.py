"""ur_rg2_motion's transform buffer, TCP trajectories and pick plan, without ROS."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer, pose_matrix, transform_point
from ur_rg2_motion.kinematics import ArmKinematics, Box, KinematicsError
from ur_rg2_motion.planning import grasp_check, gripper_down, interpolate, plan_move, plan_pick
from ur_rg2_sim.robot_model import write_robot_urdf

PEDESTAL = 0.12
VELOCITY = np.full(6, 3.15)


@pytest.fixture(scope='module')
def arm(tmp_path_factory) -> ArmKinematics:
    """Return the UR5's kinematics on the sim's pedestal."""
    urdf = write_robot_urdf('ur5', tmp_path_factory.mktemp('ur5')).read_text()
    return ArmKinematics.from_urdf(urdf, floor_z=-PEDESTAL, clearance=0.005, keep_out=[
        Box((-0.11, -0.11, -PEDESTAL - 1), (0.11, 0.11, 0.0))])


def tf_message(*edges):
    """Return a TFMessage-like object of (parent, child, xyz, xyzw) edges."""
    return SimpleNamespace(transforms=[SimpleNamespace(
        header=SimpleNamespace(frame_id=parent), child_frame_id=child,
        transform=SimpleNamespace(translation=SimpleNamespace(x=t[0], y=t[1], z=t[2]),
                                  rotation=SimpleNamespace(x=q[0], y=q[1], z=q[2], w=q[3])))
        for parent, child, t, q in edges])


def test_buffer_composes_chains_between_any_two_frames():
    buffer = TransformBuffer()
    quarter = (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4))  # 90 deg about z
    buffer.add_message(tf_message(('world', 'base_link', (0, 0, 0.12), (0, 0, 0, 1)),
                                  ('world', 'camera_link', (1.0, 0, 0.5), quarter)))
    buffer.add_message(tf_message(('camera_link', 'optical', (0, 0, 0), (0, 0, 0, 1))))
    pose = buffer.lookup('base_link', 'optical')
    assert np.allclose(pose[:3, 3], (1.0, 0.0, 0.38))
    assert np.allclose(transform_point(pose, (1.0, 0, 0)), (1.0, 1.0, 0.38))
    assert np.allclose(buffer.lookup('optical', 'base_link') @ pose, np.eye(4))
    assert buffer.frames() == {'world', 'base_link', 'camera_link', 'optical'}
    # The latest transform of a child replaces the one before.
    buffer.add_message(tf_message(('world', 'base_link', (0, 0, 0.2), (0, 0, 0, 1))))
    assert buffer.lookup('world', 'base_link')[2, 3] == pytest.approx(0.2)


def test_buffer_names_unknown_and_unconnected_frames():
    buffer = TransformBuffer()
    buffer.add_message(tf_message(('world', 'a', (0, 0, 0), (0, 0, 0, 1)),
                                  ('elsewhere', 'b', (0, 0, 0), (0, 0, 0, 1))))
    with pytest.raises(FrameLookupError, match="unknown frame 'nowhere'"):
        buffer.lookup('world', 'nowhere')
    with pytest.raises(FrameLookupError, match='not connected'):
        buffer.lookup('a', 'b')


def test_interpolation_follows_the_line_and_turns_about_one_axis():
    start = gripper_down((0.4, 0.0, 0.1), 0.0)
    end = gripper_down((0.4, 0.2, 0.3), math.pi / 2)
    poses = interpolate(start, end, [0.0, 0.5, 1.0])
    assert np.allclose(poses[0], start) and np.allclose(poses[-1], end)
    assert np.allclose(poses[1][:3, 3], (0.4, 0.1, 0.2))
    assert np.allclose(poses[1][:3, :3], gripper_down((0, 0, 0), math.pi / 4)[:3, :3])


def test_a_short_move_is_a_straight_line_within_the_speed_limits(arm):
    start = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.2])
    begin = arm.tcp_pose(start)
    target = begin.copy()
    target[:3, 3] += (0.0, 0.0, -0.1)
    trajectory = plan_move(arm, start, target, VELOCITY, 0.5, 0.2)
    assert trajectory.straight
    assert np.all(np.diff(trajectory.times) > 0)
    tcp = arm.tcp_pose(trajectory.positions)[:, :3, 3]
    assert np.abs(tcp[:, :2] - begin[:2, 3]).max() < 1e-3  # straight down
    assert np.allclose(arm.tcp_pose(trajectory.positions[-1]), target, atol=1e-9)
    path = np.vstack([start, trajectory.positions])
    speeds = np.abs(np.diff(path, axis=0)) / np.diff(np.concatenate([[0], trajectory.times]))[
        :, None]
    assert speeds.max() <= 0.5 * 3.15


def test_a_move_the_line_cannot_follow_goes_through_the_joints(arm):
    # From one side of the base to the other: the line passes the base's axis, out of reach.
    start = arm.solve(gripper_down((0.4, 0.3, 0.1), 0.0), [0.0, -1.2, 1.5, -1.9, -1.57, 0.0])
    target = gripper_down((-0.4, -0.3, 0.1), 0.0)
    trajectory = plan_move(arm, start, target, VELOCITY, 0.5, 0.2)
    assert not trajectory.straight and len(trajectory.positions) == 1
    assert np.allclose(arm.tcp_pose(trajectory.positions[-1]), target, atol=1e-9)
    # Slowest joint at half its limit on a minimum-jerk profile.
    assert trajectory.duration == pytest.approx(
        1.875 * np.abs(trajectory.positions[-1] - start).max() / (0.5 * 3.15))


@pytest.mark.parametrize('radius', [0.015, 0.03, 0.05])
def test_pick_plan_grasps_the_equator_from_above(arm, radius):
    ball = (0.4, -0.3, -PEDESTAL + radius)
    plan = plan_pick(arm, np.zeros(6), ball, 0.1, 0.15)
    assert plan.radius == pytest.approx(radius)
    for pose in (plan.above, plan.grasp, plan.lift):
        assert np.allclose(pose[:3, 2], (0, 0, -1))  # pointing down
        assert np.allclose(pose[:2, 3], ball[:2])
    # At the equator, unless the finger tips would touch the floor.
    lowest = -PEDESTAL + arm.finger_length + 0.005
    assert plan.grasp[2, 3] == pytest.approx(max(ball[2], lowest))
    assert plan.above[2, 3] == pytest.approx(plan.grasp[2, 3] + 0.1)
    assert plan.lift[2, 3] == pytest.approx(plan.grasp[2, 3] + 0.15)


def test_pick_plan_refuses_a_ball_out_of_reach(arm):
    with pytest.raises(KinematicsError) as error:
        plan_pick(arm, np.zeros(6), (1.5, 0.0, -PEDESTAL + 0.03), 0.1, 0.15)
    assert error.value.reason == 'unreachable'


@pytest.mark.parametrize(('opening', 'stalled', 'held'), [
    (0.060, True, True),
    (0.052, True, True),
    (0.030, True, False),  # stopped on something smaller than the ball
    (0.0005, False, False),  # closed on nothing
    (0.060, False, False),  # never stopped on anything
])
def test_grasp_check(opening, stalled, held):
    reason = grasp_check(opening, stalled, 0.03, 0.012)
    assert (reason is None) == held
    assert reason is None or reason.startswith('missed')


def test_pose_matrix_is_a_rotation():
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q /= np.linalg.norm(q)
    m = pose_matrix((1, 2, 3), q)
    assert np.allclose(m[:3, :3].T @ m[:3, :3], np.eye(3))
