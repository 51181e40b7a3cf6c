"""The simulator's plain modules, without ROS: URDF, grasping, camera geometry."""

import math

from conftest import move_tcp, simulate
import numpy as np
import pytest
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS, RG2_MAX_OPENING
from ur_rg2_sim.camera import Camera, CameraConfig
from ur_rg2_sim.commands import CommandError, joint_targets
from ur_rg2_sim.simulation import Schedule, SimulationLoop
from ur_rg2_sim.world import SimWorld, WorldConfig


@pytest.mark.parametrize('model', ['ur5', 'ur3'])
def test_models_load_with_real_kinematics(model):
    sim = SimWorld(WorldConfig(robot_model=model))
    try:
        assert sim.joint_names == ARM_JOINTS + GRIPPER_JOINTS
        # UR zero pose: the arm stretched along +x; its reach is the UR5's 0.817 m or the
        # UR3's 0.457 m from the base axis to the wrist.
        flange = sim.link_pose('tool0')[0]
        expected_reach = {'ur5': 0.425 + 0.39225, 'ur3': 0.24365 + 0.21325}[model]
        assert flange[0] == pytest.approx(expected_reach, abs=1e-3)
    finally:
        sim.close()


def test_gripper_opens_to_the_datasheet_stroke(world):
    world.close_gripper()
    simulate(world, 2.5)
    assert world.gripper_opening() == pytest.approx(0.0, abs=1e-3)
    assert not world.gripper_holds_object()
    world.open_gripper()
    simulate(world, 2.5)
    assert world.gripper_opening() == pytest.approx(RG2_MAX_OPENING, abs=1e-3)


def test_grasped_ball_is_lifted_and_held_at_full_speed(world):
    ball = np.array(world.body_position(world.ball))
    move_tcp(world, ball + [0, 0, 0.15])
    move_tcp(world, ball)
    world.close_gripper()
    simulate(world, 1.5)
    assert world.gripper_holds_object()
    assert world.gripper_opening() == pytest.approx(2 * world.config.ball_radius, abs=0.005)

    move_tcp(world, ball + [0, 0, 0.3])
    assert world.body_position(world.ball)[2] > ball[2] + 0.25

    # Swing the shoulder half a turn each way at its velocity limit, then fold the elbow.
    limit = world.limits['shoulder_pan_joint'].velocity
    peak_speed = 0.0
    for pan, elbow in ((math.pi / 2, 0.0), (-math.pi, -0.5)):
        world.jog_arm({'shoulder_pan_joint': pan, 'elbow_joint': elbow})
        for _ in range(round(2.0 / world.dt)):
            world.step()
            peak_speed = max(peak_speed, abs(world.joint_states().velocities[0]))
    assert peak_speed == pytest.approx(limit, rel=0.02)
    tcp = np.array(world.link_pose()[0])
    assert np.linalg.norm(np.array(world.body_position(world.ball)) - tcp) < 0.02


def test_targets_are_clamped_to_joint_limits(world):
    applied = world.set_arm_targets({'elbow_joint': 10.0})
    assert applied['elbow_joint'] == pytest.approx(world.limits['elbow_joint'].upper)


@pytest.mark.parametrize('names, positions, reason', [
    ([], [], 'no joint names'),
    (['elbow_joint'], [0.1, 0.2], '1 joint names but 2 positions'),
    (['elbow'], [0.1], "unknown joint 'elbow'"),
    (['elbow_joint'], [math.nan], 'not a finite number'),
    (['elbow_joint'], [math.inf], 'not a finite number'),
    (['elbow_joint', 'elbow_joint'], [0.1, 0.2], 'more than once'),
])
def test_malformed_commands_are_rejected_with_a_reason(names, positions, reason):
    with pytest.raises(CommandError, match=reason):
        joint_targets(names, positions, ARM_JOINTS)


def test_camera_intrinsics_follow_the_field_of_view(world):
    camera = Camera(world, CameraConfig(width=640, height=480, hfov_deg=57.0))
    fx = camera.k[0, 0]
    assert 2 * math.degrees(math.atan(320 / fx)) == pytest.approx(57.0)
    assert camera.k[1, 1] == fx


@pytest.mark.parametrize('size', [(640, 480), (101, 77)])
def test_bodies_render_where_the_intrinsics_project_them(size):
    sim = SimWorld(WorldConfig(ball_position=(5.0, 5.0, 0.03)))
    try:
        camera = Camera(sim, CameraConfig(width=size[0], height=size[1],
                                          position=(0, 0, 2.0), look_at=(1e-4, 0, 0)))
        for point in [(0, 0, 0.5), (0.3, 0.2, 0.5), (-0.25, 0.3, 0.7)]:
            marker = sim.add_sphere(point, 0.02, (1, 0, 0, 1), mass=0)
            rgb = camera.render().rgb
            sim.remove_bodies([marker])
            v, u = np.nonzero((rgb[:, :, 0] > 150) & (rgb[:, :, 1] < 80))
            assert (u.mean(), v.mean()) == pytest.approx(camera.project(point), abs=0.15)
    finally:
        sim.close()


def test_depth_is_registered_to_color(world):
    camera = Camera(world, CameraConfig())
    frame = camera.render()
    centre = world.body_position(world.ball)
    u, v = (round(c) for c in camera.project(centre))
    assert frame.rgb[v, u, 0] > 150 and frame.rgb[v, u, 1] < 60, 'ball pixel is not red'
    # Expected: where the ray through that pixel meets the ball, along the optical axis.
    ray = np.array([(u - camera.k[0, 2]) / camera.k[0, 0], (v - camera.k[1, 2]) / camera.k[1, 1],
                    1.0])
    c = camera.world_to_optical(centre)
    radius = world.config.ball_radius
    a, b, cc = ray @ ray, -2 * ray @ c, c @ c - radius ** 2
    t = (-b - math.sqrt(b * b - 4 * a * cc)) / (2 * a)
    assert frame.depth[v, u] == pytest.approx(t, abs=0.01)


def test_depth_without_return_is_positive_infinity(world):
    camera = Camera(world, CameraConfig(width=64, height=48, position=(-1.0, 0.0, 0.5),
                                        look_at=(-2.0, 0.0, 0.5)))
    depth = camera.render().depth
    assert np.isposinf(depth[:20]).all(), 'nothing above the horizon: REP 118 +inf'
    assert np.isfinite(depth[-10:]).all(), 'the floor below the horizon'


class _NoOutputs:
    def clock(self, stamp_ns):
        pass

    def joint_states(self, stamp_ns, sample):
        pass

    def frame(self, stamp_ns, camera, frame):
        pass


def test_waiting_gives_up_after_the_simulated_timeout(world):
    loop = SimulationLoop(world, _NoOutputs(), Schedule(real_time_factor=0.0))
    loop.start()
    try:
        never = loop.wait_until(SimWorld.close_gripper, lambda w: False, timeout_s=0.5)
        assert never.result(timeout=30) is False
        assert loop.sim_time_ns >= 0.5e9
        settles = loop.wait_until(SimWorld.open_gripper, SimWorld.gripper_stopped,
                                  timeout_s=5.0, hold_s=0.1)
        assert settles.result(timeout=30) is True
    finally:
        loop.stop()
    with pytest.raises(RuntimeError, match='not running'):
        loop.call(SimWorld.gripper_opening).result(timeout=5)
