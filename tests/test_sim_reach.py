"""The arm on its pedestal: home clears a solid floor, the ball on the floor is in reach.

Without ROS, on the plain world: the UR zero pose (home) touches neither floor nor pedestal;
with the gripper pointing down the TCP reaches a ball lying on the floor over the working
region in front of the robot; an arm driven into the floor or the pedestal stops on it.
"""

import math

from conftest import GRIPPER_DOWN, move_tcp, simulate
import numpy as np
import pybullet
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_sim.robot_model import TCP_LINK
from ur_rg2_sim.world import DEFAULT_BALL_POSITION, PEDESTAL_HEIGHT, SimWorld, WorldConfig

BALL_RADIUS = 0.03
HOME = dict.fromkeys(ARM_JOINTS, 0.0)
# Clearance of every arm and gripper link at home, m (the open RG2's lower finger is nearest).
HOME_MARGIN = 0.1
# Deepest contact allowed: a few mm, as the rubber pads give under the arm's full torque.
MAX_PENETRATION = 0.0075
# Floor radii (m, from the base axis) each arm reaches the floor at, at angles -90..90 degrees
# from its x axis (toward the camera and to both sides).
REACH = {'ur5': (0.3, 0.5, 0.7, 0.9), 'ur3': (0.3, 0.425, 0.55)}
ANGLES_DEG = (-90, -45, 0, 45, 90)


@pytest.fixture(params=['ur5', 'ur3'])
def world_config(request) -> WorldConfig:
    return WorldConfig(robot_model=request.param, ball_radius=BALL_RADIUS)


def descend(world: SimWorld, start, end, steps: int = 15) -> None:
    """Move the TCP on the straight line from ``start`` to ``end``, as a Cartesian move does.

    One joint move straight to the end would let the joints arrive at different times and
    swing the fingers into the floor on the way down.
    """
    for fraction in np.linspace(0.0, 1.0, steps + 1)[1:]:
        move_tcp(world, np.add(start, fraction * np.subtract(end, start)), seconds=0.1)
    simulate(world, 1.0)


def nearest(world: SimWorld, body: int, skip_links=()) -> float:
    """Return the smallest distance (m, < 0: penetration) between the arm and ``body``."""
    points = pybullet.getClosestPoints(world.robot, body, 1.0, physicsClientId=world.client)
    return min(p[8] for p in points if p[3] not in skip_links)


def deepest_contact(world: SimWorld) -> float:
    """Return the deepest penetration (m, >= 0) of the arm into the floor or the pedestal."""
    depths = [-p[8] for body in (world.floor, world.pedestal)
              for p in pybullet.getContactPoints(world.robot, body,
                                                 physicsClientId=world.client)]
    return max(depths, default=0.0)


def test_base_stands_on_the_pedestal_and_home_clears_it_and_the_floor(world):
    base_position = pybullet.getBasePositionAndOrientation(
        world.robot, physicsClientId=world.client)[0]
    assert base_position == pytest.approx((0, 0, PEDESTAL_HEIGHT))
    assert world.link_pose('base_link')[0] == pytest.approx((0, 0, PEDESTAL_HEIGHT))
    assert world.gripper_opening() == pytest.approx(0.11, abs=1e-3), 'home with the RG2 open'
    assert nearest(world, world.floor) > HOME_MARGIN
    # The base is bolted onto the pedestal; every link above it stays clear.
    on_plate = {-1, world.link_index('base_link'), world.link_index('base')}
    assert nearest(world, world.pedestal, on_plate) > 0.02
    simulate(world, 1.0)
    assert deepest_contact(world) == 0.0
    assert world.joint_states().positions[:6] == pytest.approx([0.0] * 6, abs=0.01)


def test_pedestal_is_a_rendered_body(world):
    visuals = pybullet.getVisualShapeData(world.pedestal, physicsClientId=world.client)
    assert visuals, 'the pedestal has a visual shape'
    low, high = pybullet.getAABB(world.pedestal, physicsClientId=world.client)
    assert low[2] == pytest.approx(0.0, abs=1e-3) and high[2] == pytest.approx(PEDESTAL_HEIGHT,
                                                                                abs=1e-3)
    base_low, base_high = pybullet.getAABB(world.robot, world.link_index('base_link'),
                                           physicsClientId=world.client)
    assert low[0] < base_low[0] and high[0] > base_high[0], 'wider than the UR base'


def test_tcp_reaches_the_ball_on_the_floor_with_the_gripper_down(world):
    """Over a grid of floor points, as for a pick: above the ball, then down to its centre."""
    world.set_ball_position((5.0, 5.0, BALL_RADIUS))  # out of the way
    points = [(r * math.cos(math.radians(a)), r * math.sin(math.radians(a)))
              for r in REACH[world.config.robot_model] for a in ANGLES_DEG]
    points.append(DEFAULT_BALL_POSITION[:2])
    missed = {}
    for x, y in points:
        world.set_arm_positions(HOME)
        move_tcp(world, (x, y, BALL_RADIUS + 0.15), seconds=2.0)
        descend(world, (x, y, BALL_RADIUS + 0.15), (x, y, BALL_RADIUS))
        error = np.linalg.norm(np.subtract(world.link_pose(TCP_LINK)[0], (x, y, BALL_RADIUS)))
        down = world.link_pose(TCP_LINK)[1]
        tilt = pybullet.getDifferenceQuaternion(down, GRIPPER_DOWN)
        angle = 2 * math.acos(min(1.0, abs(tilt[3])))
        if error > 0.003 or angle > math.radians(1) or deepest_contact(world) > 0.001:
            missed[(x, y)] = (round(error * 1000, 1), round(math.degrees(angle), 1))
    assert not missed, f'TCP off by (mm, deg) at floor points: {missed}'


def test_default_ball_is_grasped_from_the_pedestal(world):
    ball = np.array(world.body_position(world.ball))
    assert ball == pytest.approx(DEFAULT_BALL_POSITION, abs=1e-3)
    move_tcp(world, ball + [0, 0, 0.15], seconds=2.0)
    move_tcp(world, ball, seconds=2.0)
    world.close_gripper()
    simulate(world, 1.5)
    assert world.gripper_holds_object()
    move_tcp(world, ball + [0, 0, 0.2], seconds=2.0)
    assert world.body_position(world.ball)[2] > ball[2] + 0.15


@pytest.mark.parametrize('pose, jog', [
    # The whole arm swung down onto the floor: the open gripper lands first.
    ({}, {'shoulder_lift_joint': 2.0}),
    # Elbow folded (as far as the UR3's wrist clears its upper arm), the upper arm swung down
    # onto the pedestal's edge.
    ({'shoulder_lift_joint': -1.0, 'elbow_joint': -2.6}, {'shoulder_lift_joint': 3.5}),
], ids=['onto the floor', 'onto the pedestal'])
def test_arm_driven_into_floor_or_pedestal_stops_on_it_and_backs_out(world, pose, jog):
    start = dict(HOME, **pose)
    world.set_arm_positions(start)
    world.jog_arm(jog)
    deepest, touched = 0.0, False
    for _ in range(round(3.0 / world.dt)):
        world.step()
        deepest = max(deepest, deepest_contact(world))
        touched = touched or deepest > 0.0
    state = world.joint_states()
    assert touched, 'the arm reached the obstacle'
    assert deepest < MAX_PENETRATION, f'{deepest * 1000:.1f} mm into it'
    assert np.isfinite(state.positions).all() and max(map(abs, state.velocities)) < 0.05
    (name, delta), = jog.items()
    stopped_at = state.positions[ARM_JOINTS.index(name)]
    assert stopped_at < start[name] + delta - 0.5, 'stopped well short of the target'
    world.set_arm_targets(start)
    simulate(world, 3.0)
    assert world.joint_states().positions[:6] == pytest.approx(
        [start[j] for j in ARM_JOINTS], abs=0.01)
    assert deepest_contact(world) == 0.0
