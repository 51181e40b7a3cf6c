"""The camera's orientation from its pose parameters. Plain numpy: no pybullet, no ROS.

Kept apart from the sim's camera.py so that nodes converting between the optical and world
frames (the viewer, the dataset tool) need not load pybullet.
"""

from collections.abc import Sequence

import numpy as np


def optical_rotation(position: Sequence[float], look_at: Sequence[float]) -> np.ndarray:
    """Return the rotation whose columns are the optical x, y, z axes in the world frame.

    The camera looks from ``position`` at ``look_at`` with no roll (image x horizontal).
    """
    forward = np.asarray(look_at, dtype=float) - np.asarray(position, dtype=float)
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise ValueError('camera_position and camera_look_at must differ')
    z = forward / norm
    up = np.array([0.0, 0.0, 1.0])
    if abs(z @ up) > 0.999:  # looking straight down or up: any horizontal x will do
        up = np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])
