"""Labelled frames for the ball detector: balls of every colour and pattern, any camera. No ROS.

The training and held-out scenes of the learned detector (``scripts/detector-data``,
:mod:`ur_rg2_detector.scene_dataset`), rendered by the sim's own world and camera as
:mod:`ur_rg2_detector.scenes` renders the vision's measurement scenes.
"""

from collections.abc import Iterator, Sequence
import colorsys
from dataclasses import dataclass
import math

import numpy as np
import pybullet
from ur_rg2_common.scene_objects import SceneObject
from ur_rg2_sim.camera import Camera, CameraConfig
from ur_rg2_sim.world import SimWorld, WorldConfig
from ur_rg2_vision.placement import COLOR_GROUPS, PLAIN_GROUPS, group_color

from ur_rg2_detector.scenes import HIDDEN, Shot, ball_truth, floor_point

PATTERNS = ('two-tone', 'stripes', 'rings', 'checker', 'dots')
_TEXTURE_SIZE = (64, 128)  # rows, columns of a ball's texture (longitude along the columns)


def pattern_texture(rng: np.random.Generator, kind: str) -> np.ndarray:
    """Return a ball's surface texture (RGB uint8): two colours of any groups in a pattern."""
    first, second = (np.array(group_color(rng, PLAIN_GROUPS[int(rng.integers(
        len(PLAIN_GROUPS)))])[:3]) * 255 for _ in range(2))
    rows, cols = _TEXTURE_SIZE
    v, u = np.mgrid[0:rows, 0:cols]
    if kind == 'two-tone':
        mask = u < cols // 2
    elif kind == 'stripes':  # along the meridians
        mask = (u // max(2, cols // int(rng.integers(4, 13)))) % 2 == 0
    elif kind == 'rings':  # along the parallels
        mask = (v // max(2, rows // int(rng.integers(3, 9)))) % 2 == 0
    elif kind == 'checker':
        step = int(rng.integers(6, 22))
        mask = (u // step + v // step) % 2 == 0
    else:  # dots
        mask = np.zeros((rows, cols), bool)
        for _ in range(int(rng.integers(4, 14))):
            cu, cv_, r = rng.uniform(0, cols), rng.uniform(0, rows), rng.uniform(3, 9)
            mask |= (u - cu) ** 2 + (v - cv_) ** 2 <= r * r
    return np.where(mask[..., None], first, second).astype(np.uint8)


CONTRAST = 0.15  # a ball's value (HSV) at least this far from its floor's: plain to the eye


def plain_to_the_eye(ball: Sequence[float], floor: Sequence[float]) -> bool:
    """Return whether one of a ball's colour values (0-1) is :data:`CONTRAST` off each floor's."""
    return any(all(abs(b - f) >= CONTRAST for f in floor) for b in ball)


@dataclass
class LabelledShot:
    """A :class:`Shot` with its colour group and label box (u0, v0, u1, v1; None: no ball)."""

    shot: Shot
    group: str
    box: tuple[float, float, float, float] | None


class _Textures:
    """Textures loaded into a world from PNG files written to a scratch directory."""

    def __init__(self, world: SimWorld) -> None:
        import tempfile
        self._dir = tempfile.TemporaryDirectory(prefix='scenes-')
        self._world = world
        self._count = 0

    def load(self, rgb: np.ndarray) -> int:
        import cv2
        path = f'{self._dir.name}/{self._count}.png'
        self._count += 1
        cv2.imwrite(path, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        return pybullet.loadTexture(path, physicsClientId=self._world.client)

    def close(self) -> None:
        self._dir.cleanup()


def detector_scenes(count: int, seed: int = 0, ball_share: float = 0.88,
                    radii: tuple[float, float] = (0.015, 0.08)) -> Iterator[LabelledShot]:
    """Yield ``count`` labelled frames for the ball detector: a ball of any colour or surface.

    The colour groups in turn (saturated, pastel, white, grey, dark, patterned: two-tone,
    striped, ringed, checked or dotted in two colours of any groups). Each frame from a random
    camera pose (as ``dataset --any-camera``; a fifth near the sim's own camera), a floor of
    two random colours and tile size under a random light, the arm in a random pose half of
    the time, 0-6 objects that are not balls (cubes, boxes, flat discs; a third in the ball's
    colour or pattern), and in ``ball_share`` of them one ball of a random radius on the floor,
    plain to the eye on both floor colours (:func:`plain_to_the_eye`):
    mostly wholly in view, some cut by the image border, some partly hidden behind a box. The
    label is the box of the projected sphere clipped to the image (None: no ball in view).
    """
    from ur_rg2_vision.placement import Camera as PlanCamera
    from ur_rg2_vision.placement import any_camera_pose, plan_distractors
    rng = np.random.default_rng(seed)
    world = SimWorld(WorldConfig(ball_position=HIDDEN))
    textures = _Textures(world)
    default = CameraConfig()
    try:
        for index in range(count):
            group = COLOR_GROUPS[index % len(COLOR_GROUPS)]
            if rng.uniform() < 0.2:
                position = np.asarray(default.position) + rng.uniform(-0.2, 0.2, 3)
                target = np.asarray(default.look_at) + np.append(rng.uniform(-0.2, 0.2, 2), 0)
            else:
                position, target = (np.asarray(p) for p in any_camera_pose(rng, (0.3, 0.9)))
            # The ball first: the floor is drawn again until the ball is plain to the eye on
            # both its colours (a dark ball on a dark floor was a label no one could see).
            color, values, texture = _ball_surface(rng, group, textures)
            floor, other = _floor_colors(rng, values)
            light = rng.normal(size=3)
            light[2] = abs(light[2]) + 0.3
            config = CameraConfig(position=tuple(position), look_at=tuple(target),
                                  floor_colors=(tuple(floor), tuple(other)),
                                  floor_tile=float(rng.uniform(0.1, 0.6)),
                                  light_direction=tuple(light))
            camera = Camera(world, config)
            if rng.uniform() < 0.5:
                world.place_robot(rng.uniform([-3.1, -2.2, -2.5, -3.1, -3.1, -3.1],
                                              [3.1, -0.3, 2.5, 3.1, 3.1, 3.1]))
            else:
                world.place_robot([0.0] * 6)
            radius = float(np.exp(rng.uniform(*np.log(radii))))
            point = None
            if rng.uniform() < ball_share:
                cut = rng.uniform() < 0.12
                point = floor_point(rng, camera, radius, (0.4, 2.4), cut)
            plan = PlanCamera(tuple(position), tuple(target), camera.k, config.width,
                              config.height)
            ball = point if point is not None else HIDDEN
            objects = SceneObject.parse(plan_distractors(
                rng, plan, ball, radius, color, int(rng.integers(0, 7))))
            world.set_scene_objects(objects)
            bodies = [world.add_sphere(ball, radius, color, mass=0.0)]
            if texture is not None:
                for body in [bodies[0], *world._scene_objects]:
                    if body == bodies[0] or rng.uniform() < 1 / 3:
                        pybullet.changeVisualShape(body, -1, textureUniqueId=texture,
                                                   physicsClientId=world.client)
            if point is not None and rng.uniform() < 0.15:
                bodies.append(_occluder(rng, world, camera, point, radius))
            frame = camera.render()
            world.remove_bodies(bodies)
            shot = Shot(f'{group} {index}', frame.rgb, frame.depth, camera.k, None)
            yield LabelledShot(shot, group, _label(shot, camera, point, radius))
    finally:
        textures.close()
        world.close()


def _ball_surface(rng: np.random.Generator, group: str, textures: _Textures
                  ) -> tuple[tuple[float, float, float, float], np.ndarray, int | None]:
    """Return a ball's colour, the values (0-1) of its colours and its texture (or None)."""
    if group == 'patterned':
        surface = pattern_texture(rng, PATTERNS[int(rng.integers(len(PATTERNS)))])
        values = np.unique(surface.reshape(-1, 3), axis=0).max(axis=1) / 255
        return (1.0, 1.0, 1.0, 1.0), values, textures.load(surface)
    color = group_color(rng, group)
    return color, np.array([max(color[:3])]), None


def _floor_colors(rng: np.random.Generator, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return a floor's two colours (RGB 0-255) on both of which the ball is plain to the eye."""
    while True:
        floor = np.array(colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 0.8),
                                             rng.uniform(0.15, 0.97))) * 255
        other = (floor * rng.uniform(0.75, 0.95) if rng.uniform() < 0.7 else
                 np.array(colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 0.8),
                                              rng.uniform(0.15, 0.97))) * 255)
        if plain_to_the_eye(values, (floor.max() / 255, other.max() / 255)):
            return floor, other


def _label(shot: Shot, camera: Camera, point: np.ndarray | None, radius: float
           ) -> tuple[float, float, float, float] | None:
    """Fill in ``shot``'s ball truth; return its label box, None when no ball is in view."""
    from ur_rg2_vision.sphere import sphere_box

    if point is None:
        return None
    shot.radius = radius
    shot.centre, shot.radius_px, shot.visible = ball_truth(camera, shot.depth, point, radius)
    u0, v0, u1, v1 = sphere_box(shot.centre, radius, camera.k)
    box = (max(u0 + 0.5, 0.0), max(v0 + 0.5, 0.0),
           min(u1 + 0.5, float(camera.config.width)), min(v1 + 0.5, float(camera.config.height)))
    if box[2] <= box[0] or box[3] <= box[1] or shot.visible < 0.05:
        shot.centre = None  # not in view after all, or wholly hidden
        return None
    return box


def _occluder(rng: np.random.Generator, world: SimWorld, camera: Camera, point: np.ndarray,
              radius: float) -> int:
    """Add a box on the floor between the camera and the ball, hiding part of it."""
    position = np.asarray(camera.config.position, dtype=float)
    toward = point - position
    spot = point - toward * rng.uniform(0.08, 0.3)
    side = np.cross(toward, (0, 0, 1))
    side /= np.linalg.norm(side) or 1.0
    spot = spot + side * rng.uniform(-1.5, 1.5) * radius
    half = (rng.uniform(0.6, 1.5) * radius, rng.uniform(0.6, 1.5) * radius,
            rng.uniform(0.5, 1.6) * radius)
    body = world.add_box((spot[0], spot[1], half[2]), half, _random_rgba(rng), mass=0.0)
    pybullet.resetBasePositionAndOrientation(
        body, (spot[0], spot[1], half[2]),
        pybullet.getQuaternionFromEuler([0, 0, rng.uniform(0, math.pi)]),
        physicsClientId=world.client)
    return body


def _random_rgba(rng: np.random.Generator) -> tuple[float, float, float, float]:
    return (*(float(c) for c in colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 1),
                                                      rng.uniform(0.1, 1))), 1.0)
