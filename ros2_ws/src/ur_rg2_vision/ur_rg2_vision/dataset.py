"""The labelled data set's logic, without ROS: sphere boxes, placements, files, progress.

A ball's label is the bounding box of the projected sphere. Off the optical axis the outline
of a sphere is an ellipse (the cone of rays tangent to the sphere, cut by the image plane), so
the box is found from the four planes through the optical centre that touch the sphere and
contain an image row or column, not from the projected centre and a radius.

Layout (YOLO): ``images/{train,val}/NAME.png``, ``labels/{train,val}/NAME.txt`` with one line
``0 cx cy w h`` (normalised to the image size) or nothing when the ball is out of view,
``depth/{train,val}/NAME.png`` (16-bit, millimetres, 0 = none) and ``data.yaml``. Names are
six-digit sample numbers that continue from the largest one present, and sample ``i`` goes to
``val`` when ``floor((i + 1) f) > floor(i f)`` for the validation fraction ``f``: a run that
appends continues the same split. Each sample's placement comes from a random generator seeded
with (seed, i), so one seed gives the same placements whatever the run that made sample ``i``.
"""

from collections.abc import Sequence
import colorsys
import dataclasses
from dataclasses import dataclass
import errno
from functools import cached_property
import math
import os
from pathlib import Path
import re
import sys
import time
from typing import TextIO

import cv2
import numpy as np
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.scene_objects import SceneObject

from ur_rg2_vision.frame_store import encode_png, publish_new, remove, write_temporary

SPLITS = ('train', 'val')
CLASS_ID = 0
CLASS_NAME = 'ball'
_NAME = re.compile(r'^(\d{6,})\.(png|txt)$')
# Floor ring the arm reaches around its base axis, m (see ur_rg2_sim.world: the pedestal).
REACH = {'ur5': (0.3, 0.9), 'ur3': (0.3, 0.55)}
# Nearer than this (m, along the optical axis) the sim's renderer clips.
NEAR_CLIP = 0.05


# -- geometry ------------------------------------------------------------------------------------

def sphere_box(center: Sequence[float], radius: float, k: np.ndarray
               ) -> tuple[float, float, float, float] | None:
    """Return the image box (u0, v0, u1, v1) of a sphere, in pixel coordinates, unclipped.

    ``center`` is in the optical frame (x right, y down, z forward), ``k`` the 3x3 camera
    matrix; pixel (u, v) has its centre at integer coordinates (ROS). A plane through the
    optical centre containing the image line x/z = a is tangent to the sphere when its distance
    to the centre equals the radius: (cx - a cz)^2 = r^2 (1 + a^2), a quadratic in a whose two
    roots are the outline's extremes; likewise for y. None when the sphere reaches behind the
    optical centre's plane (z <= r): its outline is then no closed curve.
    """
    cx, cy, cz = (float(c) for c in center)
    r = float(radius)
    if cz <= r:
        return None
    denominator = cz * cz - r * r
    extremes = []
    for c in (cx, cy):
        root = r * math.sqrt(c * c + denominator)
        extremes.append(((c * cz - root) / denominator, (c * cz + root) / denominator))
    (x0, x1), (y0, y1) = extremes
    fx, fy, px, py = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    return fx * x0 + px, fy * y0 + py, fx * x1 + px, fy * y1 + py


def yolo_label(box: tuple[float, float, float, float] | None, width: int, height: int
               ) -> tuple[float, float, float, float] | None:
    """Return a pixel box clipped to the image as normalised (cx, cy, w, h); None if outside.

    Pixel i covers [i - 0.5, i + 0.5] in the box's coordinates and [i, i + 1] in YOLO's.
    """
    if box is None:
        return None
    u0, v0, u1, v1 = box
    u0, u1 = max(u0 + 0.5, 0.0), min(u1 + 0.5, float(width))
    v0, v1 = max(v0 + 0.5, 0.0), min(v1 + 0.5, float(height))
    if u1 <= u0 or v1 <= v0:
        return None
    return ((u0 + u1) / 2 / width, (v0 + v1) / 2 / height, (u1 - u0) / width,
            (v1 - v0) / height)


def depth_png(depth: np.ndarray) -> bytes:
    """Return a depth image (m, inf: no return) as a 16-bit PNG in millimetres (0: none)."""
    millimetres = np.where(np.isfinite(depth), np.round(depth * 1000.0), 0.0)
    return encode_png(np.clip(millimetres, 0, 65535).astype(np.uint16))


def label_text(label: tuple[float, float, float, float] | None) -> str:
    """Return a label file's text: one YOLO line, or nothing when the ball is out of view."""
    if label is None:
        return ''
    return f'{CLASS_ID} ' + ' '.join(f'{v:.6f}' for v in label) + '\n'


def hidden_fraction(center: Sequence[float], radius: float, k: np.ndarray, depth: np.ndarray,
                    tolerance: float = 0.01) -> tuple[float, float]:
    """Return the fractions of the ball's inner pixels hidden by something nearer, and empty.

    Inner pixels are those whose ray meets the sphere shrunk to 90 % (the rendered ball is a
    mesh a little inside the true sphere); each should show the true sphere's depth within
    ``tolerance`` m. Nearer: the ball is hidden there (the arm, the pedestal). Farther: no ball
    there, so the frame does not show the ball where it is labelled. (0, 0) when no inner pixel
    is in the image.
    """
    box = sphere_box(center, radius, k)
    if box is None:
        return 0.0, 0.0
    height, width = depth.shape
    u0, v0 = max(int(math.floor(box[0])), 0), max(int(math.floor(box[1])), 0)
    u1, v1 = min(int(math.ceil(box[2])), width - 1), min(int(math.ceil(box[3])), height - 1)
    if u1 < u0 or v1 < v0:
        return 0.0, 0.0
    u, v = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
    rays = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones(u.shape)], -1)
    c = np.asarray(center, dtype=float)
    # |t d - c|^2 = s^2 with d = (x, y, 1): the nearer root t is the optical depth of the hit.
    a = np.einsum('...i,...i', rays, rays)
    b = rays @ c
    cc = c @ c
    inner = b * b - a * (cc - (0.9 * radius) ** 2) > 0
    if not inner.any():
        return 0.0, 0.0
    expected = (b - np.sqrt(np.maximum(b * b - a * (cc - radius * radius), 0.0))) / a
    seen = depth[v0:v1 + 1, u0:u1 + 1][inner]
    expected = expected[inner]
    with np.errstate(invalid='ignore'):
        nearer = np.count_nonzero(seen < expected - tolerance)
        farther = np.count_nonzero(~(seen <= expected + tolerance))  # nan and inf count too
    return nearer / seen.size, farther / seen.size


# -- placements ----------------------------------------------------------------------------------

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


# -- files ---------------------------------------------------------------------------------------

def is_val(index: int, val_fraction: float) -> bool:
    """Return whether sample ``index`` belongs to the validation split."""
    return math.floor((index + 1) * val_fraction) > math.floor(index * val_fraction)


class DatasetWriter:
    """Writes samples into a YOLO data set directory; appends to what is there."""

    def __init__(self, root: str | os.PathLike, val_fraction: float,
                 renderer: str = '') -> None:
        self.root = Path(root).absolute()
        self.val_fraction = val_fraction
        self.renderer = renderer  # who drew the frames, recorded in data.yaml
        for kind in ('images', 'labels'):
            for split in SPLITS:
                (self.root / kind / split).mkdir(parents=True, exist_ok=True)
        self._check_data_yaml()
        self.removed_orphans = self._remove_orphan_labels()
        self.next_index = self._next_index()

    def _check_data_yaml(self) -> None:
        path = self.root / 'data.yaml'
        if path.exists():
            text = path.read_text()
            if not re.search(rf'^names:\s*\{{\s*{CLASS_ID}:\s*{CLASS_NAME}\s*\}}\s*$', text,
                             re.MULTILINE):
                raise ValueError(f'{path} exists and is not a data set of the class '
                                 f'{CLASS_ID}: {CLASS_NAME} alone; choose another --out')
        data = (f'path: {self.root}\ntrain: images/train\nval: images/val\n'
                f'names: {{{CLASS_ID}: {CLASS_NAME}}}\n')
        if self.renderer:
            data += f'renderer: {self.renderer!r}\n'
        temporary = write_temporary(str(self.root), 'data.yaml', data.encode())
        try:
            os.replace(temporary, path)
        finally:
            remove(temporary)

    def _names(self, kind: str, split: str) -> dict[int, Path]:
        names = {}
        for entry in (self.root / kind / split).iterdir():
            match = _NAME.match(entry.name)
            if match:
                names[int(match.group(1))] = entry
        return names

    def _remove_orphan_labels(self) -> int:
        """Delete labels whose image was never written (a run killed between the two)."""
        removed = 0
        for split in SPLITS:
            images = self._names('images', split)
            for index, label in self._names('labels', split).items():
                if index not in images:
                    remove(str(label))
                    removed += 1
        return removed

    def _next_index(self) -> int:
        indices = [i for kind in ('images', 'labels') for split in SPLITS
                   for i in self._names(kind, split)]
        return max(indices, default=-1) + 1

    def count(self) -> int:
        """Return how many samples (images) the data set holds."""
        return sum(len(self._names('images', split)) for split in SPLITS)

    def write(self, rgb: np.ndarray, label: tuple[float, float, float, float] | None,
              extras: dict[str, tuple[str, bytes]] | None = None) -> Path:
        """Write one sample under the next free name: the label (and extras) first, the image.

        All appear whole (written aside, then linked to a name no file has), so an image
        never exists without its label. ``extras``: more files of the sample, a folder beside
        ``images`` -> (file suffix, content), e.g. ``{'depth': ('.png', ...)}``. Returns the
        image's path.
        """
        extras = extras or {}
        while True:
            index = self.next_index
            self.next_index += 1
            split = 'val' if is_val(index, self.val_fraction) else 'train'
            name = f'{index:06d}'
            label_dir, image_dir = self.root / 'labels' / split, self.root / 'images' / split
            temporaries = [write_temporary(str(label_dir), f'{name}.txt',
                                           label_text(label).encode())]
            paths = [str(label_dir / f'{name}.txt')]
            try:
                for kind, (suffix, data) in extras.items():
                    folder = self.root / kind / split
                    folder.mkdir(parents=True, exist_ok=True)
                    temporaries.append(write_temporary(str(folder), name + suffix, data))
                    paths.append(str(folder / (name + suffix)))
                temporaries.append(write_temporary(
                    str(image_dir), f'{name}.png', encode_png(cv2.cvtColor(rgb,
                                                                           cv2.COLOR_RGB2BGR))))
                paths.append(str(image_dir / f'{name}.png'))
                try:
                    publish_new(temporaries, paths)
                except FileExistsError:
                    continue  # another writer took this name
                return Path(paths[-1])
            finally:
                for temporary in temporaries:
                    remove(temporary)


def check_writable(root: str | os.PathLike) -> None:
    """Raise OSError with the reason if a data set cannot be written under ``root``.

    Creates nothing: a file is written and deleted in ``root`` or its nearest existing parent.
    """
    path = Path(root).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    if not path.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, 'not a directory', str(path))
    remove(write_temporary(str(path), 'probe', b''))


# -- progress ------------------------------------------------------------------------------------

def format_duration(seconds: float) -> str:
    """Return ``H:MM:SS`` (or ``--:--`` when unknown)."""
    if not math.isfinite(seconds) or seconds < 0:
        return '--:--'
    seconds = int(round(seconds))
    return f'{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}'


class Progress:
    """A progress bar with rate and ETA on a terminal; a plain line every ``every`` otherwise."""

    def __init__(self, total: int, stream: TextIO = sys.stderr, every: int = 10,
                 tty: bool | None = None, clock=time.monotonic) -> None:
        self.total = total
        self.done = 0
        self.stream = stream
        self.every = max(every, 1)
        self.tty = stream.isatty() if tty is None else tty
        self._clock = clock
        self._start = clock()

    def line(self) -> str:
        """Return the current state as one line."""
        elapsed = self._clock() - self._start
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float('inf')
        share = self.done / self.total if self.total else 1.0
        text = (f'{self.done}/{self.total} {share:4.0%} {rate:.2f} samples/s '
                f'ETA {format_duration(eta)}')
        if self.tty:
            filled = int(round(share * 30))
            text = '[' + '#' * filled + '-' * (30 - filled) + '] ' + text
        return text

    def advance(self) -> None:
        """Count one sample written and show it."""
        self.done += 1
        if self.tty:
            self.stream.write('\r' + self.line())
            if self.done == self.total:
                self.stream.write('\n')
        elif self.done % self.every == 0 or self.done == self.total:
            self.stream.write(self.line() + '\n')
        self.stream.flush()

    def close(self) -> None:
        """End the bar's line on a terminal (after an interruption)."""
        if self.tty and 0 < self.done < self.total:
            self.stream.write('\n')
            self.stream.flush()
