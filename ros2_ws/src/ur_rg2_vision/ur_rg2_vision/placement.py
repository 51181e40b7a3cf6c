"""Where the ``dataset`` command puts the ball, the camera and the objects for each sample.

Each sample's placement comes from a random generator seeded with (seed, i), so one seed gives
the same placements whatever the run that made sample ``i``. No ROS: the command's driver
(:mod:`ur_rg2_vision.dataset_run`) sets them on the sim, and the rendered scenes of
:mod:`ur_rg2_detector.scenes` use the same camera poses, colours and objects.
"""

from collections.abc import Sequence
import colorsys
import dataclasses
from dataclasses import dataclass
from functools import cached_property
import math

import numpy as np
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.scene_objects import SceneObject

from ur_rg2_vision.dataset import yolo_label
from ur_rg2_vision.sphere import sphere_box

# Floor ring the arm reaches around its base axis, m (see ur_rg2_sim.world: the pedestal).
REACH = {'ur5': (0.3, 0.9), 'ur3': (0.3, 0.55)}
# Nearer than this (m, along the optical axis) the sim's renderer clips.
NEAR_CLIP = 0.05


@dataclass(frozen=True)
class Camera:
    """A camera pose (world frame, m) and its intrinsics, as the sim renders it."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    k: np.ndarray
    width: int
    height: int

    @cached_property
    def rotation(self) -> np.ndarray:
        """Return the optical axes in the world frame (columns), as the sim computes them."""
        return optical_rotation(self.position, self.look_at)

    def to_optical(self, point: Sequence[float]) -> np.ndarray:
        """Return a world point in the optical frame."""
        return self.rotation.T @ (np.asarray(point, dtype=float) - np.asarray(self.position))


@dataclass(frozen=True)
class Placement:
    """What one sample asks of the sim; ``camera`` and ``color`` None: leave them as they are."""

    ball: tuple[float, float, float]
    in_view: bool
    camera: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    color: tuple[float, float, float, float] | None = None
    # The sim's scene_objects, floor_color, light_direction.
    objects: str | None = None
    floor: tuple[float, float, float] | None = None
    light: tuple[float, float, float] | None = None


class PlacementError(RuntimeError):
    """No placement of the wanted kind exists (the camera sees no floor in the arm's reach)."""


def plan_placement(seed: int, index: int, attempt: int, camera: Camera, radius: float,
                   reach: tuple[float, float], out_of_view_fraction: float,
                   jitter_camera: bool, jitter_color: bool, tries: int = 2000,
                   distractors: int = 0, jitter_scene: bool = False,
                   ball_color: Sequence[float] = (1.0, 0.0, 0.0, 1.0),
                   any_camera: bool = False) -> Placement:
    """Return the placement of sample ``index`` (``attempt`` > 0: a redraw), seeded.

    The ball lies on the floor in the ring the arm reaches. In view means the whole sphere is
    in front of the camera and its centre projects into the image; out of view, its box lies
    wholly outside the image (about ``out_of_view_fraction`` of the samples), or when the
    camera sees the whole ring, it lies behind the camera. With ``distractors``, up to that
    many objects that are not balls stand on the floor in view (see :func:`plan_distractors`);
    with ``jitter_scene``, the floor's colour and the light change too; with ``any_camera``,
    the camera looks from a random pose (:func:`any_camera_pose`) instead of its own.
    """
    rng = np.random.default_rng([seed, index, attempt])
    if any_camera:
        camera = Camera(*any_camera_pose(rng, reach), camera.k, camera.width, camera.height)
    placement = _place_ball(rng, camera, radius, reach, out_of_view_fraction, jitter_camera,
                            jitter_color, tries)
    if any_camera and placement.camera is None:
        placement = dataclasses.replace(placement, camera=(camera.position, camera.look_at))
    extra: dict[str, object] = {}
    if distractors:
        view = camera if placement.camera is None else Camera(
            *placement.camera, camera.k, camera.width, camera.height)
        color = ball_color if placement.color is None else placement.color
        extra['objects'] = plan_distractors(rng, view, placement.ball, radius, color,
                                            int(rng.integers(0, distractors + 1)))
    if jitter_scene:
        extra['floor'] = tuple(float(c) for c in colorsys.hsv_to_rgb(
            rng.uniform(0, 1), rng.uniform(0, 0.7), rng.uniform(0.25, 0.95)))
        light = rng.normal(size=3)
        light[2] = abs(light[2]) + 0.3  # from above
        extra['light'] = tuple(float(c) for c in light / np.linalg.norm(light))
    return dataclasses.replace(placement, **extra) if extra else placement


def any_camera_pose(rng: np.random.Generator, reach: tuple[float, float]
                    ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """Return a random camera pose (position, look-at) that sees the floor the arm reaches.

    It looks at a point of that floor from any side, 0.6-2.2 m away, 25-65 degrees down, and
    stands clear of the arm (at least 0.7 m from its base): the variety of camera poses a
    user's set-up may have, of which the sim's default is one.
    """
    while True:
        distance = math.sqrt(rng.uniform(reach[0] ** 2, reach[1] ** 2))
        angle = rng.uniform(-math.pi, math.pi)
        target = np.array([distance * math.cos(angle), distance * math.sin(angle), 0.0])
        away, pitch = rng.uniform(0.6, 2.2), math.radians(rng.uniform(25, 65))
        yaw = rng.uniform(-math.pi, math.pi)
        position = target + away * np.array([math.cos(pitch) * math.cos(yaw),
                                              math.cos(pitch) * math.sin(yaw), math.sin(pitch)])
        if np.linalg.norm(position[:2]) >= 0.7:
            return (tuple(float(v) for v in position), tuple(float(v) for v in target))


# The colour groups of balls (and the data set's and evaluation's groups): plain colours, then
# balls of two colours in a pattern (rendered scenes only: the sim's ball has one colour).
COLOR_GROUPS = ('saturated', 'pastel', 'white', 'grey', 'dark', 'patterned')
PLAIN_GROUPS = COLOR_GROUPS[:-1]


def group_color(rng: np.random.Generator, group: str) -> tuple[float, float, float, float]:
    """Return a random plain colour (rgba 0-1) of one of :data:`PLAIN_GROUPS`."""
    hue = rng.uniform(0, 1)
    saturation, value = {
        'saturated': (rng.uniform(0.6, 1), rng.uniform(0.5, 1)),
        'pastel': (rng.uniform(0.15, 0.45), rng.uniform(0.8, 1)),
        'white': (rng.uniform(0, 0.06), rng.uniform(0.9, 1)),
        'grey': (rng.uniform(0, 0.08), rng.uniform(0.3, 0.75)),
        'dark': (rng.uniform(0, 1), rng.uniform(0.06, 0.28)),
    }[group]
    return (*(float(c) for c in colorsys.hsv_to_rgb(hue, saturation, value)), 1.0)


def _random_color(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """Return a colour of any plain group: saturated, pastel, white, grey or dark."""
    return group_color(rng, PLAIN_GROUPS[int(rng.integers(len(PLAIN_GROUPS)))])


def plan_distractors(rng: np.random.Generator, camera: Camera, ball: Sequence[float],
                     radius: float, ball_color: Sequence[float], count: int,
                     tries: int = 50) -> str:
    """Return up to ``count`` objects that are not balls, as the sim's ``scene_objects``.

    Cubes, boxes and flat discs, 1.5-8 cm (half size, log-uniform), each on the floor where
    the camera sees it, clear of the ball, of each other and of the robot's pedestal; a third
    of them in the ball's colour, the others in random colours.
    """
    objects: list[SceneObject] = []
    taken: list[tuple[float, float, float]] = [(ball[0], ball[1], radius), (0.0, 0.0, 0.25)]
    for _ in range(count):
        size = float(np.exp(rng.uniform(math.log(0.015), math.log(0.08))))
        shape = rng.choice(3)  # cube, box, disc
        if shape == 0:
            half = (size, size, size)
        elif shape == 1:
            half = (size, size * rng.uniform(0.3, 1), size * rng.uniform(0.2, 1))
        else:
            half = (size, size, max(0.001, size * rng.uniform(0.03, 0.25)))
        footprint = math.hypot(half[0], half[1])
        color = ball_color if rng.uniform() < 1 / 3 else _random_color(rng)
        for _ in range(tries):
            u, v = rng.uniform(0, camera.width), rng.uniform(0, camera.height)
            ray = camera.rotation @ np.linalg.solve(camera.k, [u, v, 1.0])
            if ray[2] >= -1e-3:
                continue  # above the horizon
            point = np.asarray(camera.position) - ray * camera.position[2] / ray[2]
            if np.linalg.norm(point - camera.position) > 4.0:
                continue
            if all(math.hypot(point[0] - x, point[1] - y) > footprint + r + 0.02
                   for x, y, r in taken):
                taken.append((float(point[0]), float(point[1]), footprint))
                objects.append(SceneObject('disc' if shape == 2 else 'box', float(point[0]),
                                           float(point[1]), float(rng.uniform(0, math.pi)),
                                           tuple(float(h) for h in half),
                                           tuple(float(c) for c in color[:3])))
                break
    return '; '.join(item.text() for item in objects)


def _place_ball(rng: np.random.Generator, camera: Camera, radius: float,
                reach: tuple[float, float], out_of_view_fraction: float, jitter_camera: bool,
                jitter_color: bool, tries: int) -> Placement:
    pose = None
    if jitter_camera:
        position = np.asarray(camera.position) + rng.uniform(-0.15, 0.15, 3)
        position[2] = max(position[2], 0.3)
        look_at = np.asarray(camera.look_at) + np.append(rng.uniform(-0.15, 0.15, 2), 0.0)
        pose = (tuple(float(v) for v in position), tuple(float(v) for v in look_at))
        camera = Camera(pose[0], pose[1], camera.k, camera.width, camera.height)
    color = _random_color(rng) if jitter_color else None
    in_view = bool(rng.uniform() >= out_of_view_fraction)
    for _ in range(tries):
        distance = math.sqrt(rng.uniform(reach[0] ** 2, reach[1] ** 2))  # uniform in area
        angle = rng.uniform(-math.pi, math.pi)
        ball = (distance * math.cos(angle), distance * math.sin(angle), radius)
        center = camera.to_optical(ball)
        if center[2] <= radius + NEAR_CLIP:
            if not in_view:
                return Placement(ball, False, pose, color)
            continue
        box = sphere_box(center, radius, camera.k)
        if in_view:
            u = camera.k[0, 0] * center[0] / center[2] + camera.k[0, 2]
            v = camera.k[1, 1] * center[1] / center[2] + camera.k[1, 2]
            if 0 <= u <= camera.width - 1 and 0 <= v <= camera.height - 1:
                return Placement(ball, True, pose, color)
        elif yolo_label((box[0] - 2, box[1] - 2, box[2] + 2, box[3] + 2), camera.width,
                        camera.height) is None:
            return Placement(ball, False, pose, color)
    forward = camera.rotation[:2, 2]
    if not in_view and np.linalg.norm(forward) > 1e-3:
        # The camera sees the whole ring: out of reach then, on the floor 1 m behind it.
        back = np.asarray(camera.position[:2]) - forward / np.linalg.norm(forward)
        return Placement((float(back[0]), float(back[1]), radius), False, pose, color)
    where = 'in view' if in_view else 'out of view'
    raise PlacementError(f"no floor position {where} within the arm's reach ({reach[0]:g}-"
                         f'{reach[1]:g} m from its base) found in {tries} tries: is the camera '
                         f'looking at the workspace?')
