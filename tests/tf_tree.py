"""Test helpers: a transform buffer from (parent, child, translation, rotation), UR DH kinematics.

The DH kinematics is written out here, apart from ur_rg2_motion.kinematics, as an independent
reference for the frames the sim publishes.
"""

from collections.abc import Iterable, Sequence
import math

import numpy as np
from ur_rg2_common.tf_buffer import TransformBuffer, pose_matrix

# Universal Robots' published DH parameters (d1, a2, a3, d4, d5, d6), metres.
UR_DH = {
    'ur5': (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    'ur3': (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
}


def buffer_of(transforms: Iterable[tuple[str, str, Sequence, Sequence]]) -> TransformBuffer:
    """Return a buffer holding (parent, child, translation, xyzw rotation) transforms."""
    buffer = TransformBuffer()
    for parent, child, translation, rotation in transforms:
        buffer.set_transform(parent, child, pose_matrix(translation, rotation))
    return buffer


def ur_forward_kinematics(model: str, q: Sequence[float]) -> np.ndarray:
    """Return the DH base -> flange transform of a UR arm at joint positions ``q``."""
    d1, a2, a3, d4, d5, d6 = UR_DH[model]
    a = (0.0, a2, a3, 0.0, 0.0, 0.0)
    d = (d1, 0.0, 0.0, d4, d5, d6)
    alpha = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
    pose = np.eye(4)
    for i, theta in enumerate(q):
        ct, st = math.cos(theta), math.sin(theta)
        ca, sa = math.cos(alpha[i]), math.sin(alpha[i])
        pose = pose @ np.array([[ct, -st * ca, st * sa, a[i] * ct],
                                [st, ct * ca, -ct * sa, a[i] * st],
                                [0.0, sa, ca, d[i]],
                                [0.0, 0.0, 0.0, 1.0]])
    return pose
