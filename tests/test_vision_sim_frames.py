"""Ball detection on frames rendered by the simulator, with the issue's metrics.

One pybullet world renders a small labelled set (a few dozen frames, ~20-30 ms each): the red
ball at known positions over the image, near and far, partly hidden by the gripper, next to a
red cube or a ball of another colour, under other light and on other floors; and frames with no
ball, with only red cubes, with only a ball of another colour. Every frame goes through the
node's pipeline (detect, then confirm and locate with depth), once measuring the ball's radius
(the node's default) and once given it. Targets: recall >= 98 % where the ball is visible, no
position in frames without the ball, 3D error median <= 5 mm and max <= 15 mm; measured radius
error median <= 2 mm.
"""

from dataclasses import dataclass
import functools
import math

import numpy as np
import pybullet
import pytest
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_detector.scenes import HIDDEN, MIN_VISIBLE, ball_truth
from ur_rg2_sim.camera import Camera, CameraConfig
from ur_rg2_sim.world import SimWorld, WorldConfig
from ur_rg2_vision.detector import BallDetector
from ur_rg2_vision.localize import locate_first

RADIUS = 0.03
DEFAULT = CameraConfig()
NEAR = CameraConfig(position=(0.95, -0.75, 0.45), look_at=(0.45, -0.35, 0.03))
FAR = CameraConfig(position=(2.0, -1.7, 1.1), look_at=(0.2, -0.1, 0.0))
DOWN = pybullet.getQuaternionFromEuler([math.pi, 0.0, 0.0])  # gripper pointing down


@dataclass
class Sample:
    """One rendered frame and its ground truth."""

    name: str
    rgb: np.ndarray
    depth: np.ndarray
    k: np.ndarray
    ball: np.ndarray | None  # optical frame, None: no red ball in view
    radius_px: float = 0.0
    visible: float = 0.0  # fraction of the ball's disc in the image and unoccluded


class Renderer:
    """The world and its cameras, with helpers to stage scenes."""

    def __init__(self) -> None:
        self.world = SimWorld(WorldConfig(ball_radius=RADIUS))
        self.cameras: dict[int, Camera] = {}
        self.samples: list[Sample] = []

    def camera(self, config: CameraConfig) -> Camera:
        key = id(config)
        if key not in self.cameras:
            self.cameras[key] = Camera(self.world, config)
        return self.cameras[key]

    def shoot(self, name: str, ball, config: CameraConfig = DEFAULT, exposure: float = 1.0):
        """Render a frame with the ball at world point ``ball`` (None: hidden)."""
        world = self.world
        world.set_ball_position(ball if ball is not None else HIDDEN)
        camera = self.camera(config)
        frame = camera.render()
        rgb = frame.rgb
        if exposure != 1.0:
            rgb = np.clip(rgb * exposure, 0, 255).astype(np.uint8)
        sample = Sample(name, rgb, frame.depth, camera.k, None)
        if ball is not None:
            sample.ball, sample.radius_px, sample.visible = ball_truth(
                camera, frame.depth, ball, RADIUS)
        self.samples.append(sample)

    def home(self) -> None:
        self.world.set_arm_positions(dict.fromkeys(ARM_JOINTS, 0.0))

    def reach(self, tcp) -> None:
        self.world.set_arm_positions(self.world.inverse_kinematics(tcp, DOWN))


@functools.cache
def samples() -> tuple[Sample, ...]:
    """Render the labelled set once per test session."""
    r = Renderer()
    world = r.world
    ball = np.array([0.45, -0.35, RADIUS])
    for x in np.linspace(-0.2, 1.0, 5):  # over the image, 1.1-2.3 m away
        for y in np.linspace(-0.8, 0.6, 5):
            r.shoot(f'floor {x:.2f} {y:.2f}', (x, y, RADIUS))
    for x, y in [(0.3, -0.2), (0.7, -0.5), (0.45, -0.35), (0.6, -0.1), (0.25, -0.5)]:
        r.shoot(f'near {x} {y}', (x, y, RADIUS), NEAR)  # large
    r.shoot('in the air near the camera', (0.85, -0.65, 0.35), NEAR)
    for x, y in [(0.0, 0.4), (0.5, 0.2), (-0.3, -0.4), (-0.4, 0.3), (0.3, 0.6)]:
        r.shoot(f'far {x} {y}', (x, y, RADIUS), FAR)  # small
    # Partly hidden by the gripper: the TCP on the line of sight, 0-20 % of the way to the camera.
    camera_position = np.array(DEFAULT.position)
    for fraction, lift in [(0.0, 0.0), (0.0, 0.04), (0.08, 0.03), (0.1, 0.0), (0.12, 0.05),
                           (0.15, 0.0), (0.2, 0.02)]:
        r.reach(ball + fraction * (camera_position - ball) + [0, 0, lift])
        r.shoot(f'gripper in front {fraction} {lift}', ball)
    r.home()
    # Company: a red cube (not a ball) and a green ball near the red ball.
    for offset in [(0.12, 0.1), (-0.1, -0.15), (0.0, 0.15), (0.07, 0.0), (0.0, 0.07),
                   (-0.07, 0.0), (0.0, -0.07), (0.05, 0.05)]:  # the last five touch it
        cube = world.add_box((ball[0] + offset[0], ball[1] + offset[1], 0.03), [0.03] * 3,
                             (1, 0, 0, 1))
        r.shoot(f'red cube nearby {offset}', ball)
        world.remove_bodies([cube])
    green = world.add_sphere((ball[0] - 0.1, ball[1] + 0.1, RADIUS), RADIUS, (0, 0.8, 0, 1))
    r.shoot('green ball nearby', ball)
    world.remove_bodies([green])
    # Other light and exposure, other floors.
    for light in [(1.0, 0.0, 0.1), (-0.5, 0.5, 0.3), (0.0, 0.0, -1.0)]:
        r.shoot(f'light {light}', ball, CameraConfig(light_direction=light))
    r.shoot('dark exposure', ball, exposure=0.45)
    for floor in [((60, 130, 60), (40, 110, 40)), ((50, 60, 150), (40, 50, 120)),
                  ((40, 40, 40), (20, 20, 20)), ((150, 110, 70), (120, 90, 60))]:
        r.shoot(f'floor colours {floor[0]}', ball, CameraConfig(floor_colors=floor))
    # No ball of the ball's colour.
    r.shoot('nothing', None)
    r.shoot('nothing, far camera', None, FAR)
    cubes = [((0.45, -0.35), 0.03, 0.0), ((0.6, -0.2), 0.03, 0.6), ((0.2, 0.3), 0.02, 0.3),
             ((-0.3, 0.5), 0.025, 0.8), ((0.8, -0.6), 0.04, 0.4)]
    for (x, y), half, yaw in cubes:
        cube = world.add_box((x, y, half), [half] * 3, (1, 0, 0, 1))
        world.set_ball_position(HIDDEN)
        pybullet.resetBasePositionAndOrientation(
            cube, (x, y, half), pybullet.getQuaternionFromEuler([0, 0, yaw]),
            physicsClientId=world.client)
        r.shoot(f'red cube only {x} {y} {half}', None)
        r.shoot(f'red cube only {x} {y} {half}, far camera', None, FAR)
        world.remove_bodies([cube])
    for color in [(0, 0.8, 0, 1), (0, 0.2, 1, 1), (1, 0.9, 0, 1)]:
        world.set_ball_color(color)
        world.set_ball_position(ball)
        r.shoot(f'only a ball of colour {color}', None)  # the red ball is repainted
    world.set_ball_color((1, 0, 0, 1))
    world.close()
    return tuple(r.samples)


@functools.cache
def results(ball_radius: float = 0.0) -> tuple:
    """Run the node's pipeline on every sample: (sample, position or None) pairs."""
    detector = BallDetector()
    return tuple((s, locate_first(detector.detect(s.rgb, s.k), s.depth, s.k, ball_radius))
                 for s in samples())


GIVEN = pytest.mark.parametrize('ball_radius', [0.0, RADIUS], ids=['measured', 'given'])


def test_the_set_covers_the_issue_cases():
    visible = [s for s in samples() if s.ball is not None and s.visible >= MIN_VISIBLE]
    assert len(visible) >= 50  # one miss still meets 98 %
    assert sum(s.visible < 0.9 for s in visible) >= 4, 'partly hidden balls'
    assert min(s.radius_px for s in visible) <= 9, 'a small, far ball'
    assert max(s.radius_px for s in visible) >= 30, 'a large, near ball'
    assert sum(s.ball is None for s in samples()) >= 12, 'frames without the ball'


@GIVEN
def test_recall_where_the_ball_is_visible(ball_radius):
    visible = [(s, p) for s, p in results(ball_radius)
               if s.ball is not None and s.visible >= MIN_VISIBLE]
    missed = [f'{s.name} ({s.visible:.0%} visible, r {s.radius_px:.1f} px)'
              for s, p in visible if p is None]
    recall = 1 - len(missed) / len(visible)
    assert recall >= 0.98, f'recall {recall:.1%}, missed: {missed}'


@GIVEN
def test_no_position_without_the_ball(ball_radius):
    wrong = [s.name for s, p in results(ball_radius) if s.ball is None and p is not None]
    assert not wrong, f'a ball found in {wrong}'


@GIVEN
def test_3d_error(ball_radius):
    errors = {s.name: float(np.linalg.norm(np.array([p.x, p.y, p.z]) - s.ball))
              for s, p in results(ball_radius) if s.ball is not None and p is not None}
    median, worst = np.median(list(errors.values())), max(errors.values())
    assert median <= 0.005 and worst <= 0.015, (
        f'median {median * 1000:.1f} mm, max {worst * 1000:.1f} mm '
        f'({max(errors, key=errors.get)})')


def test_radius_is_measured():
    errors = [abs(p.radius - RADIUS) for s, p in results() if s.ball is not None and p]
    median, worst = np.median(errors), max(errors)
    assert median <= 0.002 and worst <= 0.004, (
        f'radius error median {median * 1000:.1f} mm, max {worst * 1000:.1f} mm')


@pytest.mark.parametrize('name', ['gripper in front 0.1 0.0', 'gripper in front 0.15 0.0'])
def test_ball_split_by_the_gripper_fingers(name):
    (sample, position), = [(s, p) for s, p in results() if s.name == name]
    assert sample.visible < 0.9  # staged right: the fingers do cover part of the ball
    assert position is not None
