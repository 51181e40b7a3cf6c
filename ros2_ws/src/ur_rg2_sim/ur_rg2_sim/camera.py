"""Kinect-like RGB-D camera: pinhole intrinsics, color + registered depth. Plain Python, no ROS.

Two renderers draw the same camera (docs/design.md, "The camera"):

* ``egl``: OpenGL through moderngl on an EGL context (:mod:`ur_rg2_sim.gl_renderer`), Mesa's
  llvmpipe on a CPU or a GPU where there is one. It draws a snapshot of the shapes' poses, so
  the drawing may run on another thread while the physics goes on.
* ``tiny``: pybullet's TinyRenderer, the fallback where no EGL context loads. It reads the
  world itself, so it draws on the simulation thread.

The floor is the plane z = 0, never rasterised by TinyRenderer (a screen-filling plane costs it
~75 ms): its colour and depth per pixel depend only on the camera pose, so they are computed
once with numpy and composited under the rendered bodies by depth; the OpenGL renderer draws
the same tiles. Whatever lies below the floor plane is hidden as a floor hides it: the arm
cannot get there (floor and pedestal are solid, see world.py), but the floor's own visual speck
sits there, and tests park bodies there out of sight.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import functools
import math
from typing import Optional

import cv2
import numpy as np
import pybullet
from ur_rg2_common.camera_pose import optical_rotation

from ur_rg2_sim.gl_renderer import FloorLook, GlRenderer, create_context, describe, thread_context
from ur_rg2_sim.render_scene import SceneSnapshot, read_snapshot
from ur_rg2_sim.world import SimWorld

# A Kinect v1 sees 0.4-8 m; nearer and farther the renderer clips.
NEAR_CLIP = 0.05
FAR_CLIP = 8.0

# The ``renderer`` parameter's values: the first picks the second where EGL loads.
RENDERERS = ('auto', 'egl', 'tiny')
# What gives the OpenGL renderer its EGL context on Debian and Ubuntu.
EGL_PACKAGES = 'libegl1 libgl1-mesa-dri'


class RendererError(ValueError):
    """The requested renderer is unknown, or cannot run on this machine."""


@dataclass(frozen=True)
class RendererChoice:
    """Which renderer draws (``egl`` or ``tiny``) and why, for the start-up log line."""

    name: str
    reason: str


@functools.lru_cache(maxsize=1)
def _egl_probe() -> tuple[Optional[str], Optional[str]]:
    """Return (the EGL renderer's description, None) or (None, why no context loads)."""
    try:
        context = create_context()
    except Exception as error:  # noqa: BLE001 - any failure means: no EGL here
        return None, f'{type(error).__name__}: {error}'
    try:
        return describe(context), None
    finally:
        context.release()


def choose_renderer(requested: str) -> RendererChoice:
    """Resolve a ``renderer`` parameter value; raise RendererError when it cannot be had."""
    if requested not in RENDERERS:
        raise RendererError(f"renderer must be {', '.join(RENDERERS)}, got {requested!r}")
    if requested == 'tiny':
        return RendererChoice('tiny', "pybullet's TinyRenderer, as asked (renderer: tiny)")
    found, failure = _egl_probe()
    if found is not None:
        return RendererChoice('egl', f'OpenGL on EGL: {found}')
    if requested == 'egl':
        raise RendererError(f'renderer egl: no EGL context loads ({failure}); install '
                            f'{EGL_PACKAGES} (Debian/Ubuntu) or use renderer auto or tiny')
    return RendererChoice('tiny', f"pybullet's TinyRenderer: no EGL context loads ({failure}); "
                          f'for the faster OpenGL renderer install {EGL_PACKAGES}')


@dataclass
class CameraConfig:
    """Image size, field of view, pose and look of the camera."""

    width: int = 640
    height: int = 480
    hfov_deg: float = 57.0
    position: Sequence[float] = (1.3, -1.1, 0.95)
    look_at: Sequence[float] = (0.3, -0.1, 0.1)
    floor_colors: tuple[Sequence[int], Sequence[int]] = ((176, 176, 170), (150, 150, 146))
    floor_tile: float = 0.25  # m
    # Where no surface is in view (beyond the far clip): TinyRenderer's clear colour, white.
    background_color: Sequence[int] = (255, 255, 255)
    light_direction: Sequence[float] = (0.4, -0.6, 1.0)


@dataclass
class Frame:
    """One RGB-D frame: ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 metres."""

    rgb: np.ndarray
    depth: np.ndarray


class Camera:
    """Renders a :class:`SimWorld` from a fixed pose; depth is registered to colour.

    ``renderer`` is the ``renderer`` parameter's value (:data:`RENDERERS`); :attr:`renderer`
    says which one draws. With ``egl`` a camera draws on one thread: the first that draws.
    """

    def __init__(self, world: SimWorld, config: CameraConfig, renderer: str = 'auto') -> None:
        if config.width < 1 or config.height < 1:
            raise ValueError('camera width and height must be positive')
        if not 1.0 <= config.hfov_deg <= 170.0:
            raise ValueError('camera_hfov must be between 1 and 170 degrees')
        self.world = world
        self.config = config
        self.renderer = choose_renderer(renderer)
        w, h = config.width, config.height
        self.fx = (w / 2) / math.tan(math.radians(config.hfov_deg) / 2)
        self.fy = self.fx  # square pixels
        # Where TinyRenderer puts the optical axis, not the frustum's centre: it samples
        # pixel i at i, not i + 0.5, and flips rows with an offset of one (docs/design.md).
        self.cx = w / 2
        self.cy = h / 2 - 1
        self._rotation = optical_rotation(config.position, config.look_at)
        self._position = np.asarray(config.position, dtype=float)
        self._floor_look = floor_look(config)
        self._gl: Optional[GlRenderer] = None
        self._tiny: Optional[tuple] = None  # TinyRenderer's matrices and floor, made when used

    @property
    def k(self) -> np.ndarray:
        """Return the 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]])

    @property
    def draws_off_thread(self) -> bool:
        """Whether :meth:`draw` may run on another thread than the world's (OpenGL)."""
        return self.renderer.name == 'egl'

    def world_to_optical(self, point: Sequence[float]) -> np.ndarray:
        """Return a world point in the optical frame (x right, y down, z forward)."""
        return self._rotation.T @ (np.asarray(point, dtype=float) - self._position)

    def project(self, point: Sequence[float]) -> tuple[float, float]:
        """Return the pixel (u, v) of a world point."""
        x, y, z = self.world_to_optical(point)
        return self.fx * x / z + self.cx, self.fy * y / z + self.cy

    def render(self) -> Frame:
        """Render the world now; depth is metres along the optical axis, +inf: no return.

        A world with a textured body (the data set's patterned balls) is drawn by TinyRenderer
        whichever renderer was chosen: the OpenGL renderer draws colours, not textures.
        """
        if self.renderer.name == 'egl':
            snapshot = self.snapshot()
            if not snapshot.textured:
                return self.draw(snapshot)
        return self._render_tiny()

    def snapshot(self) -> SceneSnapshot:
        """Return what the OpenGL renderer draws, as the world is now (the world's thread)."""
        return read_snapshot(self.world.client)

    def draw(self, snapshot: SceneSnapshot) -> Frame:
        """Draw a snapshot with OpenGL, on the thread that draws for this camera."""
        if self._gl is None:
            view = np.eye(4)
            view[:3, :3] = self._rotation.T
            view[:3, 3] = -self._rotation.T @ self._position
            self._gl = GlRenderer(thread_context(), self.config.width, self.config.height,
                                  self.k, view, self.config.light_direction,
                                  (NEAR_CLIP, FAR_CLIP), self._floor_look)
        rgb, depth = self._gl.render(snapshot)
        return Frame(rgb=rgb, depth=depth)

    def close(self) -> None:
        """Free the OpenGL objects, on the thread that drew (the camera stays usable)."""
        if self.renderer.name == 'egl' and self._gl is not None:
            self._gl.release()
            self._gl = None

    def _render_tiny(self) -> Frame:
        cfg = self.config
        if self._tiny is None:
            vfov = math.degrees(2 * math.atan((cfg.height / 2) / self.fy))
            self._tiny = (
                pybullet.computeViewMatrix(list(cfg.position), list(cfg.look_at),
                                           list(self._rotation @ [0, -1, 0])),
                pybullet.computeProjectionMatrixFOV(vfov, cfg.width / cfg.height, NEAR_CLIP,
                                                    FAR_CLIP),
                *self._render_floor())
        view, projection, floor_rgb, floor_depth = self._tiny
        _, _, rgba, depth_buffer, _ = pybullet.getCameraImage(
            cfg.width, cfg.height, view, projection, shadow=0,
            lightDirection=list(cfg.light_direction), renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK, physicsClientId=self.world.client)
        depth_buffer = np.asarray(depth_buffer, dtype=np.float32).reshape(cfg.height, cfg.width)
        rgb = cv2.cvtColor(np.asarray(rgba, dtype=np.uint8).reshape(cfg.height, cfg.width, 4),
                           cv2.COLOR_RGBA2RGB)
        # In place, for speed (docs/design.md). The buffer's 0-1 maps to NEAR_CLIP-FAR_CLIP.
        depth = depth_buffer * np.float32(-(FAR_CLIP - NEAR_CLIP))
        depth += np.float32(FAR_CLIP)
        np.divide(np.float32(FAR_CLIP * NEAR_CLIP), depth, out=depth)
        np.copyto(depth, np.float32(np.inf), where=depth_buffer >= 1.0)
        floor_in_front = floor_depth < depth
        np.copyto(depth, floor_depth, where=floor_in_front)
        cv2.copyTo(floor_rgb, floor_in_front.view(np.uint8), rgb)
        return Frame(rgb=rgb, depth=depth)

    def _render_floor(self) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        u, v = np.meshgrid(np.arange(cfg.width), np.arange(cfg.height))
        rays = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy,
                         np.ones_like(u, dtype=float)], axis=-1)
        world_rays = rays @ self._rotation.T
        with np.errstate(divide='ignore', invalid='ignore'):
            distance = -self._position[2] / world_rays[..., 2]  # optical z of the floor hit
        hits = (distance > 0) & (distance < FAR_CLIP)
        depth = np.where(hits, distance, np.inf).astype(np.float32)
        points = self._position + world_rays * np.where(hits, distance, 0)[..., None]
        tiles = (np.floor(points[..., 0] / cfg.floor_tile)
                 + np.floor(points[..., 1] / cfg.floor_tile)).astype(int) % 2
        look = self._floor_look
        rgb = np.where(hits[..., None], look.tile_colors[tiles], look.background)
        return rgb.astype(np.uint8), depth


def floor_look(config: CameraConfig) -> FloorLook:
    """Return the floor's two tile colours as lit, and the background, in 8-bit RGB."""
    # Lambert shading of the horizontal floor with the renderer's light, so that floor and
    # bodies brighten and darken together when the light changes.
    light = np.asarray(config.light_direction, dtype=float)
    shade = 0.6 + 0.4 * max(light[2] / (np.linalg.norm(light) or 1.0), 0.0)
    tiles = np.asarray(config.floor_colors, dtype=np.float32) * np.float32(shade)
    return FloorLook(tile_colors=np.clip(tiles, 0, 255).astype(np.uint8),
                     tile_size=float(config.floor_tile),
                     background=np.clip(config.background_color, 0, 255).astype(np.uint8))
