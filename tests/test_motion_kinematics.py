"""Closed-form UR kinematics (ur_rg2_motion.kinematics) against itself and the sim's physics."""

import math

import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_common.tf_buffer import pose_matrix
from ur_rg2_motion import closed_form, kinematics
from ur_rg2_motion.kinematics import ArmKinematics, Box, KinematicsError
from ur_rg2_sim.robot_model import ROBOT_MODELS, write_robot_urdf
from ur_rg2_sim.world import SimWorld, WorldConfig

POSES = 3000
TOLERANCE = 1e-6  # m and rad


@pytest.fixture(scope='module', params=ROBOT_MODELS)
def urdf(request, tmp_path_factory) -> tuple[str, str]:
    """Return the robot description the sim runs, per arm model: (model, URDF text)."""
    path = write_robot_urdf(request.param, tmp_path_factory.mktemp(request.param))
    return request.param, path.read_text()


def random_joints(arm: ArmKinematics, rng: np.random.Generator, count: int) -> np.ndarray:
    return rng.uniform(arm.lower, arm.upper, size=(count, 6))


def pose_errors(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Largest position (m) and rotation (rad) difference between stacks of poses."""
    return (float(np.abs(a[..., :3, 3] - b[..., :3, 3]).max()),
            float(kinematics.rotation_angle(a, b).max()))


def test_model_is_read_from_the_description(urdf):
    model, text = urdf
    arm = ArmKinematics.from_urdf(text)
    assert arm.dh == closed_form.UR_DH[model]
    # base_link -> base: 180 degrees about z; the RG2's TCP straight out of the flange.
    assert np.allclose(arm.base_in_base_link, np.diag([-1.0, -1.0, 1.0, 1.0]), atol=1e-9)
    assert np.allclose(arm.tcp_in_flange[:3, :3], np.eye(3))
    assert 0.1 < arm.tcp_in_flange[2, 3] < 0.3
    assert 0.0 < arm.finger_length < 0.05


def test_every_inverse_solution_reproduces_the_pose(urdf):
    """FK(IK(pose)) = pose for all branches of thousands of random reachable poses."""
    arm = ArmKinematics.from_urdf(urdf[1])
    rng = np.random.default_rng(20261123)
    joints = random_joints(arm, rng, POSES)
    flanges = closed_form.forward(arm.dh, joints)
    counts = []
    for q, flange in zip(joints, flanges):
        solutions = closed_form.inverse(arm.dh, flange, wrist_3=q[5])
        counts.append(len(solutions))
        assert solutions, f'no solution for the pose of {q}'
        position, angle = pose_errors(closed_form.forward(arm.dh, np.array(solutions)), flange)
        assert position < TOLERANCE and angle < TOLERANCE, (q, position, angle)
        # The joints the pose came from are one of the branches (modulo 2 pi).
        wrapped = np.remainder(np.array(solutions) - q + math.pi, 2 * math.pi) - math.pi
        assert np.abs(wrapped).max(axis=1).min() < TOLERANCE
    assert np.mean(np.array(counts) == 8) > 0.5  # a generic pose has 8 solutions


def test_solve_reaches_random_tcp_poses_within_tolerance(urdf):
    """FK(solve(pose)) = pose for random TCP poses, from a start near another posture."""
    arm = ArmKinematics.from_urdf(urdf[1])
    rng = np.random.default_rng(7)
    joints = random_joints(arm, rng, POSES)
    targets = arm.tcp_pose(joints)
    starts = joints + rng.normal(0.0, 0.5, joints.shape)
    for target, start in zip(targets, starts):
        q = arm.solve(target, start)
        assert np.all((q >= arm.lower) & (q <= arm.upper))
        position, angle = pose_errors(arm.tcp_pose(q), target)
        assert position < TOLERANCE and angle < TOLERANCE


def test_solve_picks_the_solution_nearest_the_current_joints(urdf):
    arm = ArmKinematics.from_urdf(urdf[1])
    rng = np.random.default_rng(3)
    for q in random_joints(arm, rng, 200):
        assert np.allclose(arm.solve(arm.tcp_pose(q), q + 0.01), q, atol=1e-6)
    # A joint a turn away from the solution's principal angle stays on its turn.
    q = np.array([-1.0, -1.2, 1.5, -1.8, -1.57, -1.0])
    turned = q + np.array([2 * math.pi, 0, 0, 0, 0, 2 * math.pi])
    assert np.allclose(arm.solve(arm.tcp_pose(q), turned), turned)


def test_wrist_singularity_keeps_wrist_3(urdf):
    """With wrist 2 at zero wrist 1 and 3 are aligned: the current wrist 3 is kept."""
    arm = ArmKinematics.from_urdf(urdf[1])
    q = np.array([0.2, -1.0, 1.5, 0.3, 0.0, 0.7])
    assert np.allclose(arm.solve(arm.tcp_pose(q), q), q, atol=1e-6)


def test_forward_kinematics_matches_the_physics_engine(urdf):
    """tool0 and rg2_tcp in base_link as pybullet has them, for random joints."""
    model, text = urdf
    arm = ArmKinematics.from_urdf(text)
    world = SimWorld(WorldConfig(robot_model=model))
    try:
        rng = np.random.default_rng(11)
        for q in random_joints(arm, rng, 50):
            world.set_arm_positions(dict(zip(ARM_JOINTS, q)))
            base_link = pose_matrix(*world.link_pose('base_link'))
            to_base_link = np.linalg.inv(base_link)
            flange = to_base_link @ pose_matrix(*world.link_pose('tool0'))
            tcp = to_base_link @ pose_matrix(*world.link_pose('rg2_tcp'))
            for physics, ours in ((flange, arm.base_in_base_link @ closed_form.forward(arm.dh, q)),
                                  (tcp, arm.tcp_pose(q))):
                position, angle = pose_errors(physics, ours)
                # pybullet computes in single precision.
                assert position < 1e-6 and angle < 1e-6, (q, position, angle)
    finally:
        world.close()


def down_at(x: float, y: float, z: float) -> np.ndarray:
    """Return a TCP pose at (x, y, z) in base_link with the gripper pointing down."""
    pose = np.diag([1.0, -1.0, -1.0, 1.0])
    pose[:3, 3] = (x, y, z)
    return pose


def sideways_at(x: float, y: float, z: float) -> np.ndarray:
    """Return a TCP pose at (x, y, z) in base_link with the gripper pointing toward -x."""
    pose = np.array([[0.0, 0.0, -1.0, x], [0.0, 1.0, 0.0, y], [1.0, 0.0, 0.0, z],
                     [0.0, 0.0, 0.0, 1.0]])
    return pose


@pytest.mark.parametrize(('target', 'reason'), [
    (down_at(3.0, 0.0, 0.2), 'unreachable'),
    (down_at(0.4, 0.1, -0.2), 'floor'),
    (sideways_at(0.1, 0.0, -0.05), 'pedestal'),
    (np.full((4, 4), np.nan), 'invalid'),
    (np.diag([2.0, 1.0, 1.0, 1.0]), 'invalid'),
    (np.diag([1.0, 1.0, -1.0, 1.0]), 'invalid'),
])
def test_bad_targets_are_refused_with_the_reason(urdf, target, reason):
    model, text = urdf
    arm = ArmKinematics.from_urdf(text, floor_z=-0.12, keep_out=[
        Box((-0.11, -0.11, -0.2), (0.11, 0.11, 0.0))])
    if model == 'ur3' and reason == 'floor':
        target = down_at(0.3, 0.1, -0.2)
    with pytest.raises(KinematicsError) as error:
        arm.solve(target, np.zeros(6))
    assert error.value.reason == reason
    assert str(error.value)


def test_outside_the_joint_limits_and_singular_targets_are_refused(urdf):
    arm = ArmKinematics.from_urdf(urdf[1])
    q = np.array([0.3, -1.2, 1.5, -1.8, -1.57, 0.2])
    narrow = ArmKinematics(arm.dh, arm.base_in_base_link, arm.tcp_in_flange,
                           lower=np.full(6, -0.1), upper=np.full(6, 0.1))
    with pytest.raises(KinematicsError) as error:
        narrow.solve(arm.tcp_pose(q), np.zeros(6))
    assert error.value.reason == 'joint_limits'
    # The elbow fully stretched (as in the zero pose): the edge of the reach.
    stretched = np.array([0.5, -1.0, 0.0, -0.5, 1.2, 0.0])
    with pytest.raises(KinematicsError) as error:
        arm.solve(arm.tcp_pose(stretched), stretched)
    assert error.value.reason == 'singular'
