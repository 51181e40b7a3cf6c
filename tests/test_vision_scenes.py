"""Synthetic RGB-D frames with exact ground truth for the vision tests (numpy ray casting).

The scene lives in the camera's optical frame (x right, y down, z forward): a checkered floor
plane below the camera, spheres and boxes with Lambert shading. Depth is the optical z of the
first hit, +inf where a ray hits nothing. The tests in this module check the renderer itself.
"""

from dataclasses import dataclass, field

import numpy as np

WIDTH, HEIGHT = 640, 480
FX = FY = 589.37  # 57 degrees horizontal field of view, as the sim's camera
CX, CY = (WIDTH - 1) / 2, (HEIGHT - 1) / 2
K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
RED = (0.85, 0.0, 0.0)
_U, _V = np.meshgrid(np.arange(WIDTH, dtype=np.float64), np.arange(HEIGHT, dtype=np.float64))
_RAYS = np.stack([(_U - CX) / FX, (_V - CY) / FY, np.ones_like(_U)], axis=-1)  # z = 1


@dataclass
class Sphere:
    """A sphere: centre in the optical frame (m), radius (m), RGB 0-1."""

    centre: tuple[float, float, float]
    radius: float = 0.03
    color: tuple[float, float, float] = RED


@dataclass
class Box:
    """A box: centre (m), half extents (m), yaw about the floor normal (rad), RGB 0-1."""

    centre: tuple[float, float, float]
    half_extents: tuple[float, float, float]
    color: tuple[float, float, float] = RED
    yaw: float = 0.0


@dataclass
class Scene:
    """Camera 1 m above the floor, pitched down 40 degrees, light from above."""

    spheres: list[Sphere] = field(default_factory=list)
    boxes: list[Box] = field(default_factory=list)
    floor_colors: tuple = ((0.62, 0.62, 0.6), (0.5, 0.5, 0.48))
    camera_height: float = 1.0
    pitch: float = np.radians(40.0)
    light: tuple[float, float, float] = (0.3, -1.0, -0.4)  # towards the light
    ambient: float = 0.45
    exposure: float = 1.0

    @property
    def up(self) -> np.ndarray:
        """World up in the optical frame."""
        return np.array([0.0, -np.cos(self.pitch), -np.sin(self.pitch)])

    def on_floor(self, x: float, distance: float, height: float) -> tuple[float, float, float]:
        """Return the optical point ``height`` above the floor, ``distance`` ahead, ``x`` right.

        ``distance`` is measured along the floor from the point below the camera.
        """
        up = self.up
        ahead = np.array([0.0, 0.0, 1.0]) - up * up[2]
        ahead /= np.linalg.norm(ahead)
        point = -up * self.camera_height + ahead * distance + up * height + [x, 0, 0]
        return tuple(point)


def render(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Return (rgb uint8 (H, W, 3), depth float32 (H, W) metres) of the scene."""
    rays = _RAYS
    t = np.full((HEIGHT, WIDTH), np.inf)
    normal = np.zeros(rays.shape)
    albedo = np.zeros(rays.shape)

    def take(window, hit_t, hit_normal, hit_color):
        nearer = (hit_t > 0) & (hit_t < t[window])
        t[window][nearer] = hit_t[nearer]
        normal[window][nearer] = hit_normal[nearer] if np.ndim(hit_normal) == 3 else hit_normal
        albedo[window][nearer] = hit_color[nearer] if np.ndim(hit_color) == 3 else hit_color

    everywhere = np.s_[:, :]
    up = scene.up
    with np.errstate(divide='ignore', invalid='ignore'):
        floor_t = -scene.camera_height / (rays @ up)
    floor_t[~np.isfinite(floor_t)] = np.inf
    points = rays * np.where(np.isfinite(floor_t), floor_t, 0)[..., None]
    side = np.cross(up, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    tiles = (np.floor(points @ side / 0.25) + np.floor(points[..., 2] / 0.25)).astype(int) % 2
    take(everywhere, floor_t, up, np.array(scene.floor_colors)[tiles])

    for sphere in scene.spheres:
        c = np.asarray(sphere.centre)
        window = _window(c + sphere.radius * np.array(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]))
        if window is None:
            continue
        sub = rays[window]
        b = sub @ c
        a = (sub ** 2).sum(axis=-1)
        disc = b ** 2 - a * (c @ c - sphere.radius ** 2)
        with np.errstate(invalid='ignore'):
            hit_t = np.where(disc >= 0, (b - np.sqrt(disc)) / a, np.inf)
        hit_normal = (sub * hit_t[..., None] - c) / sphere.radius
        take(window, hit_t, np.nan_to_num(hit_normal), np.asarray(sphere.color))

    for box in scene.boxes:
        # Box axes in the optical frame: yawed about the floor normal.
        ahead = np.cross(side, up)
        cos, sin = np.cos(box.yaw), np.sin(box.yaw)
        axes = np.stack([cos * side + sin * ahead, -sin * side + cos * ahead, up])
        half = np.asarray(box.half_extents)
        corners = np.asarray(box.centre) + np.array(
            [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half @ axes
        window = _window(corners)
        if window is None:
            continue
        local_rays = rays[window] @ axes.T
        origin = -(axes @ np.asarray(box.centre))
        with np.errstate(divide='ignore', invalid='ignore'):
            t1 = (-half - origin) / local_rays
            t2 = (half - origin) / local_rays
        near = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf)
        far = np.nan_to_num(np.maximum(t1, t2), nan=np.inf)
        entry, leave = near.max(axis=-1), far.min(axis=-1)
        hit_t = np.where(entry <= leave, entry, np.inf)
        face = near.argmax(axis=-1)
        sign = -np.sign(np.take_along_axis(local_rays, face[..., None], -1))[..., 0]
        take(window, hit_t, axes[face] * sign[..., None], np.asarray(box.color))

    light = np.asarray(scene.light) / np.linalg.norm(scene.light)
    shade = scene.ambient + (1 - scene.ambient) * np.clip(normal @ light, 0, 1)
    rgb = np.clip(albedo * shade[..., None] * scene.exposure * 255, 0, 255).astype(np.uint8)
    return rgb, t.astype(np.float32)  # rays have z = 1: t is the optical z


def _window(corners: np.ndarray) -> tuple[slice, slice] | None:
    """Return the image rows and columns that can see inside the corners' convex hull."""
    if (corners[:, 2] <= 0).any():
        raise ValueError('objects must be in front of the camera')
    u = FX * corners[:, 0] / corners[:, 2] + CX
    v = FY * corners[:, 1] / corners[:, 2] + CY
    u0, u1 = max(0, int(u.min()) - 1), min(WIDTH, int(u.max()) + 2)
    v0, v1 = max(0, int(v.min()) - 1), min(HEIGHT, int(v.max()) + 2)
    if u0 >= u1 or v0 >= v1:
        return None
    return np.s_[v0:v1, u0:u1]


def project(point: tuple[float, float, float]) -> tuple[float, float]:
    """Return the pixel (u, v) of an optical-frame point."""
    x, y, z = point
    return FX * x / z + CX, FY * y / z + CY


def test_sphere_depth_and_colour_at_its_centre():
    scene = Scene()
    centre = scene.on_floor(0.1, 1.2, 0.03)
    rgb, depth = render(Scene(spheres=[Sphere(centre)]))
    u, v = (round(c) for c in project(centre))
    ray = np.array([(u - CX) / FX, (v - CY) / FY, 1.0])
    distance_along_ray = depth[v, u] * np.linalg.norm(ray)
    assert abs(distance_along_ray - (np.linalg.norm(centre) - 0.03)) < 1e-3
    assert rgb[v, u, 0] > 100 and rgb[v, u, 1] == 0


def test_floor_below_horizon_and_sky_above():
    rgb, depth = render(Scene(pitch=np.radians(10.0)))
    assert np.isinf(depth[0, 0]) and np.isfinite(depth[-1, 0])
    assert (rgb[0, 0] == 0).all()


def test_box_hides_what_is_behind_it():
    scene = Scene()
    ball = scene.on_floor(0.0, 1.5, 0.03)
    box = Box(scene.on_floor(0.0, 1.2, 0.15), (0.1, 0.02, 0.15), color=(0.7, 0.7, 0.7))
    rgb, depth = render(Scene(spheres=[Sphere(ball)], boxes=[box]))
    u, v = (round(c) for c in project(ball))
    assert depth[v, u] < ball[2] - 0.1
    assert rgb[v, u, 0] == rgb[v, u, 1] > 0  # the grey box, not the red ball
