"""Seeded frames rendered by the sim with exact ground truth, for measuring the vision. No ROS.

Balls of many sizes (1.5-8 cm radius, 0.5-2 m from the camera, anywhere in the image, resting
on the floor or held in the air) and things of the ball's colour that are not balls (cubes,
boxes, flat patches on the floor) or balls of other colours. Used by the tests and the
benchmark; the sim's world and camera render them, so they look as the node sees them.
"""

from collections.abc import Iterator, Sequence
import colorsys
from dataclasses import dataclass
import math

import numpy as np
import pybullet
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.scene_objects import SceneObject
from ur_rg2_sim.camera import Camera, CameraConfig
from ur_rg2_sim.world import SimWorld, WorldConfig
from ur_rg2_vision.placement import group_color

RED = (1.0, 0.0, 0.0, 1.0)
OTHER_COLORS = ((0.0, 0.8, 0.0, 1.0), (0.0, 0.2, 1.0, 1.0), (1.0, 0.9, 0.0, 1.0),
                (1.0, 0.5, 0.0, 1.0))
# Looking away from the arm (it stands at the origin), over an open floor.
CAMERA = CameraConfig(position=(0.0, -1.2, 1.0), look_at=(0.0, -2.6, 0.0))
HIDDEN = (0.0, 0.0, -1.0)  # under the floor, which the camera draws over everything below
MIN_VISIBLE = 0.4  # fraction of the ball's disc seen for it to count as visible


@dataclass
class Shot:
    """One rendered frame and its ground truth."""

    name: str
    rgb: np.ndarray
    depth: np.ndarray
    k: np.ndarray
    centre: np.ndarray | None  # the ball's centre, optical frame, m; None: no ball to find
    radius: float = 0.0  # m
    radius_px: float = 0.0  # the outline's radius on the optical axis
    visible: float = 0.0  # fraction of the ball's disc in the image and unoccluded


def ball_truth(camera: Camera, depth: np.ndarray, world_point: Sequence[float],
               radius: float) -> tuple[np.ndarray, float, float]:
    """Return (optical centre, image radius, visible fraction) of a ball at a world point."""
    centre = camera.world_to_optical(world_point)
    distance = np.linalg.norm(centre)
    radius_px = camera.fx * radius / math.sqrt(distance ** 2 - radius ** 2)
    u, v = camera.project(world_point)
    # Pixels well inside the outline (an ellipse off the axis, so 0.9 of the on-axis radius).
    reach = 0.9 * radius_px
    height, width = depth.shape
    top, bottom = max(0, int(v - reach)), min(height, int(v + reach) + 2)
    left, right = max(0, int(u - reach)), min(width, int(u + reach) + 2)
    if top >= bottom or left >= right:
        return centre, radius_px, 0.0
    rows, cols = np.mgrid[top:bottom, left:right]
    disc = np.hypot(cols - u, rows - v) <= reach
    rays = np.stack([(cols[disc] - camera.cx) / camera.fx, (rows[disc] - camera.cy) / camera.fy,
                     np.ones(disc.sum())], axis=1)
    # Where the ball is seen, the depth is its front surface along the pixel's ray.
    b = rays @ centre
    a = (rays ** 2).sum(axis=1)
    with np.errstate(invalid='ignore'):
        surface = (b - np.sqrt(b ** 2 - a * (centre @ centre - radius ** 2))) / a
    seen = np.abs(depth[rows[disc], cols[disc]] - surface) < 0.01
    return centre, radius_px, float(seen.sum() / (math.pi * reach ** 2))


class _Stage:
    """A world whose own ball is hidden, a camera, and a random placer in its view."""

    def __init__(self, seed: int, config: CameraConfig) -> None:
        self.rng = np.random.default_rng(seed)
        self.world = SimWorld(WorldConfig(ball_position=HIDDEN))
        self.camera = Camera(self.world, config)
        self._rotation = optical_rotation(config.position, config.look_at)  # optical -> world
        self._position = np.asarray(config.position, dtype=float)

    def place(self, size: float, distances: tuple[float, float]) -> np.ndarray:
        """Return a world point for an object of ``size`` (m) in view, resting or in the air."""
        cam = self.camera
        for _ in range(1000):
            distance = self.rng.uniform(*distances)
            margin = cam.fx * size / distance + 2  # the whole object in the image
            u = self.rng.uniform(margin, cam.config.width - margin)
            v = self.rng.uniform(margin, cam.config.height - margin)
            ray = np.array([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0])
            point = self._position + self._rotation @ (distance * ray / np.linalg.norm(ray))
            if self.rng.random() < 0.5 or point[2] < size:
                # On the floor: where this pixel's ray meets the plane z = size.
                direction = self._rotation @ ray
                if direction[2] >= 0:
                    continue
                point = self._position + direction * (size - self._position[2]) / direction[2]
            if distances[0] <= np.linalg.norm(point - self._position) <= distances[1]:
                return point
        raise RuntimeError('no place in view for the object')

    def shoot(self, name: str) -> Shot:
        frame = self.camera.render()
        return Shot(name, frame.rgb, frame.depth, self.camera.k, None)


def sized_balls(count: int, seed: int = 0, radii: tuple[float, float] = (0.015, 0.08),
                distances: tuple[float, float] = (0.5, 2.0),
                config: CameraConfig = CAMERA) -> Iterator[Shot]:
    """Yield ``count`` frames, each with one red ball of a random radius and position.

    The first four are the extremes: the smallest ball far and near, the largest near and far.
    """
    (small, large), (near, far) = radii, distances
    extremes = [(small, (0.95 * far, far)), (large, (near, 1.05 * near)),
                (small, (near, 1.05 * near)), (large, (0.95 * far, far))]
    stage = _Stage(seed, config)
    try:
        for index in range(count):
            radius, where = (extremes[index] if index < len(extremes) else (
                float(np.exp(stage.rng.uniform(*np.log(radii)))),  # as many small as large
                distances))
            point = stage.place(radius, where)
            ball = stage.world.add_sphere(point, radius, RED, mass=0.0)
            shot = stage.shoot(f'ball {index}: r {radius * 100:.1f} cm')
            stage.world.remove_bodies([ball])
            shot.radius = radius
            shot.centre, shot.radius_px, shot.visible = ball_truth(
                stage.camera, shot.depth, point, radius)
            yield shot
    finally:
        stage.world.close()


def no_balls(count: int, seed: int = 0, sizes: tuple[float, float] = (0.015, 0.08),
             distances: tuple[float, float] = (0.5, 2.0),
             config: CameraConfig = CAMERA) -> Iterator[Shot]:
    """Yield ``count`` frames without a red ball.

    In turn a red cube, a red box lying flat, a flat red patch on the floor, and a ball of
    another colour, each of a random size and place.
    """
    stage = _Stage(seed, config)
    world = stage.world
    try:
        for index in range(count):
            size = float(np.exp(stage.rng.uniform(*np.log(sizes))))
            kind = ('red cube', 'red box', 'red patch', 'other ball')[index % 4]
            point = stage.place(size, distances)
            half = {'red cube': (size,) * 3, 'red box': (2 * size, size, size / 2),
                    'red patch': (size, size, 0.001)}.get(kind)
            if half is None:
                body = world.add_sphere(point, size, OTHER_COLORS[index // 4 % 4], mass=0.0)
            else:
                point[2] = half[2]  # on the floor
                body = world.add_box(point, half, RED, mass=0.0)
                yaw = stage.rng.uniform(0, math.pi)
                pybullet.resetBasePositionAndOrientation(
                    body, point, pybullet.getQuaternionFromEuler([0, 0, yaw]),
                    physicsClientId=world.client)
            yield stage.shoot(f'{kind} {index}: {size * 100:.1f} cm')
            world.remove_bodies([body])
    finally:
        world.close()


def hard_scenes(count: int, seed: int = 0, ball_share: float = 0.7,
                radii: tuple[float, float] = (0.015, 0.08),
                distances: tuple[float, float] = (0.5, 2.0),
                groups: Sequence[str] = ()) -> Iterator[Shot]:
    """Yield ``count`` frames of scenes the sim never makes by itself (the held-out hard set).

    Each from a random camera pose (0.6-2.2 m from a point on the floor near the arm, 25-65
    degrees down, from any side but not inside the arm),
    on a floor of a random colour under a random light, with 1-4 objects that are not balls
    (cubes, boxes, flat discs of random sizes and colours, a third in the ball's colour) and,
    in ``ball_share`` of them, one ball of a random colour (red among them) and radius, resting
    on the floor in view. ``centre`` is None in the frames without a ball. ``groups``: the
    ball's colour from these colour groups in turn instead (plain ones: pastel, white, grey,
    dark...), its value at least 0.15 above or below the floor's, plain to the eye.
    """
    from ur_rg2_vision.placement import Camera as PlanCamera
    from ur_rg2_vision.placement import plan_distractors
    rng = np.random.default_rng(seed)
    world = SimWorld(WorldConfig(ball_position=HIDDEN))
    try:
        for index in range(count):
            position = np.zeros(3)
            while np.linalg.norm(position[:2]) < 0.7:  # not in the arm
                target = np.array([rng.uniform(-0.3, 0.9), rng.uniform(-0.9, 0.6), 0.0])
                reach, pitch, yaw = (rng.uniform(0.6, 2.2), math.radians(rng.uniform(25, 65)),
                                     rng.uniform(-math.pi, math.pi))
                position = target + reach * np.array([math.cos(pitch) * math.cos(yaw),
                                                      math.cos(pitch) * math.sin(yaw),
                                                      math.sin(pitch)])
            floor = np.array(colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0, 0.7),
                                                 rng.uniform(0.25, 0.95))) * 255
            light = rng.normal(size=3)
            light[2] = abs(light[2]) + 0.3
            if groups:
                color = group_color(rng, groups[index % len(groups)])
                while abs(max(color[:3]) - floor.max() / 255) < 0.15:
                    floor = np.array(colorsys.hsv_to_rgb(
                        rng.uniform(0, 1), rng.uniform(0, 0.7), rng.uniform(0.25, 0.95))) * 255
            config = CameraConfig(position=tuple(position), look_at=tuple(target),
                                  floor_colors=(tuple(floor), tuple(0.85 * floor)),
                                  light_direction=tuple(light))
            camera = Camera(world, config)
            if not groups:
                color = (RED if rng.uniform() < 0.2 else
                         (*colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0.5, 1),
                                               rng.uniform(0.5, 1)), 1.0))
            radius = float(np.exp(rng.uniform(*np.log(radii))))
            point = None
            if rng.uniform() < ball_share:
                point = floor_point(rng, camera, radius, distances)
            ball = point if point is not None else HIDDEN
            plan = PlanCamera(tuple(position), tuple(target), camera.k, config.width,
                              config.height)
            objects = plan_distractors(rng, plan, ball, radius, color, int(rng.integers(1, 5)))
            world.set_scene_objects(SceneObject.parse(objects))
            body = world.add_sphere(ball, radius, color, mass=0.0)
            frame = camera.render()
            world.remove_bodies([body])
            shot = Shot(f'hard {index}: ' + ('no ball' if point is None else
                                             f'ball r {radius * 100:.1f} cm'),
                        frame.rgb, frame.depth, camera.k, None)
            if point is not None:
                shot.radius = radius
                shot.centre, shot.radius_px, shot.visible = ball_truth(
                    camera, frame.depth, point, radius)
            yield shot
    finally:
        world.close()


def floor_point(rng: np.random.Generator, camera: Camera, radius: float,
                 distances: tuple[float, float], cut: bool = False) -> np.ndarray | None:
    """Return a point where a ball of ``radius`` rests on the floor, wholly in view.

    ``cut``: its centre near the image border instead, so that the border cuts the ball.
    """
    rotation = optical_rotation(camera.config.position, camera.config.look_at)
    position = np.asarray(camera.config.position, dtype=float)
    for _ in range(400 if cut else 200):
        u = rng.uniform(-40, camera.config.width + 40) if cut else rng.uniform(
            0, camera.config.width)
        v = rng.uniform(-40, camera.config.height + 40) if cut else rng.uniform(
            0, camera.config.height)
        ray = rotation @ np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1])
        if ray[2] >= -1e-3:
            continue
        point = position + ray * (radius - position[2]) / ray[2]
        if not distances[0] <= np.linalg.norm(point - position) <= distances[1]:
            continue
        x, y, z = camera.world_to_optical(point)
        margin = camera.fx * radius / z + 2
        pu, pv = camera.project(point)
        width, height = camera.config.width, camera.config.height
        if cut and (min(pu, width - pu, pv, height - pv) < 0.6 * margin
                    and -0.4 * margin <= pu <= width + 0.4 * margin
                    and -0.4 * margin <= pv <= height + 0.4 * margin):
            return point
        if not cut and margin <= pu <= width - margin and margin <= pv <= height - margin:
            return point
    return None
