"""Kinect-like RGB-D camera: pinhole intrinsics, color + registered depth. Plain Python, no ROS.

pybullet's CPU TinyRenderer costs per covered pixel, and a floor fills half the image: with the
floor rasterised a 640x480 frame takes ~90 ms, without it ~15 ms. The floor is the plane z = 0,
so its colour and depth per pixel depend only on the camera pose; they are computed once with
numpy and composited under the rendered bodies by depth. Whatever lies below the floor plane is
hidden exactly as a rendered floor would hide it: the arm cannot get there (floor and pedestal
are solid, see world.py), but the floor's own visual speck sits there, and tests park bodies
there out of sight.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import cv2
import numpy as np
import pybullet
from ur_rg2_common.camera_pose import optical_rotation

from ur_rg2_sim.world import SimWorld

# A Kinect v1 sees 0.4-8 m; nearer and farther the renderer clips.
NEAR_CLIP = 0.05
FAR_CLIP = 8.0


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
    background_color: Sequence[int] = (205, 215, 225)
    light_direction: Sequence[float] = (0.4, -0.6, 1.0)


@dataclass
class Frame:
    """One RGB-D frame: ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 metres."""

    rgb: np.ndarray
    depth: np.ndarray


class Camera:
    """Renders a :class:`SimWorld` from a fixed pose; depth is registered to colour."""

    def __init__(self, world: SimWorld, config: CameraConfig) -> None:
        if config.width < 1 or config.height < 1:
            raise ValueError('camera width and height must be positive')
        if not 1.0 <= config.hfov_deg <= 170.0:
            raise ValueError('camera_hfov must be between 1 and 170 degrees')
        self.world = world
        self.config = config
        w, h = config.width, config.height
        self.fx = (w / 2) / math.tan(math.radians(config.hfov_deg) / 2)
        self.fy = self.fx  # square pixels
        # Where TinyRenderer puts the optical axis, not the frustum's centre: it samples
        # pixel i at i, not i + 0.5, and flips rows with an offset of one (docs/design.md).
        self.cx = w / 2
        self.cy = h / 2 - 1
        self._rotation = optical_rotation(config.position, config.look_at)
        self._position = np.asarray(config.position, dtype=float)
        vfov = math.degrees(2 * math.atan((h / 2) / self.fy))
        self._view = pybullet.computeViewMatrix(
            list(config.position), list(config.look_at), list(self._rotation @ [0, -1, 0]))
        self._projection = pybullet.computeProjectionMatrixFOV(vfov, w / h, NEAR_CLIP, FAR_CLIP)
        self._floor_rgb, self._floor_depth = self._render_floor()

    @property
    def k(self) -> np.ndarray:
        """Return the 3x3 intrinsic matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]])

    def world_to_optical(self, point: Sequence[float]) -> np.ndarray:
        """Return a world point in the optical frame (x right, y down, z forward)."""
        return self._rotation.T @ (np.asarray(point, dtype=float) - self._position)

    def project(self, point: Sequence[float]) -> tuple[float, float]:
        """Return the pixel (u, v) of a world point."""
        x, y, z = self.world_to_optical(point)
        return self.fx * x / z + self.cx, self.fy * y / z + self.cy

    def render(self) -> Frame:
        """Render the world now; depth is metres along the optical axis, +inf: no return."""
        cfg = self.config
        _, _, rgba, depth_buffer, _ = pybullet.getCameraImage(
            cfg.width, cfg.height, self._view, self._projection, shadow=0,
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
        floor_in_front = self._floor_depth < depth
        np.copyto(depth, self._floor_depth, where=floor_in_front)
        cv2.copyTo(self._floor_rgb, floor_in_front.view(np.uint8), rgb)
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
        palette = np.array(cfg.floor_colors, dtype=np.float32)
        # Lambert shading of the horizontal floor with the renderer's light, so that floor and
        # bodies brighten and darken together when the light changes.
        light = np.asarray(cfg.light_direction, dtype=float)
        shade = 0.6 + 0.4 * max(light[2] / (np.linalg.norm(light) or 1.0), 0.0)
        floor = palette[tiles] * shade
        background = np.broadcast_to(np.asarray(cfg.background_color, dtype=np.float32),
                                     floor.shape)
        rgb = np.where(hits[..., None], floor, background)
        return np.clip(rgb, 0, 255).astype(np.uint8), depth
