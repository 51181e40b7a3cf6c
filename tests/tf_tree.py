"""Test helpers: compose received transforms as a tf2 listener would, and UR DH kinematics."""

from collections.abc import Iterable, Sequence
import math

import numpy as np

# Universal Robots' published DH parameters (d1, a2, a3, d4, d5, d6), metres.
UR_DH = {
    'ur5': (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    'ur3': (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
}


def matrix(translation: Sequence[float], rotation: Sequence[float]) -> np.ndarray:
    """Return the 4x4 homogeneous matrix of a translation and an xyzw quaternion."""
    x, y, z, w = rotation
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = translation
    return m


class Tree:
    """Latest parent->child transforms by child frame; composes chains between two frames."""

    def __init__(self, transforms: Iterable[tuple[str, str, Sequence, Sequence]] = ()) -> None:
        self.edges: dict[str, tuple[str, np.ndarray]] = {}
        self.add(transforms)

    def add(self, transforms: Iterable[tuple[str, str, Sequence, Sequence]]) -> None:
        for parent, child, translation, rotation in transforms:
            self.edges[child] = (parent, matrix(translation, rotation))

    def add_message(self, msg) -> None:
        """Add every transform of a tf2_msgs/TFMessage."""
        self.add((t.header.frame_id, t.child_frame_id,
                  (t.transform.translation.x, t.transform.translation.y,
                   t.transform.translation.z),
                  (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                   t.transform.rotation.w)) for t in msg.transforms)

    def from_root(self, frame: str) -> tuple[str, np.ndarray]:
        """Return the root of ``frame``'s branch and root->frame."""
        pose = np.eye(4)
        seen = set()
        while frame in self.edges:
            assert frame not in seen, f'a loop through {frame}'
            seen.add(frame)
            parent, edge = self.edges[frame]
            pose = edge @ pose
            frame = parent
        return frame, pose

    def lookup(self, target: str, source: str) -> np.ndarray:
        """Return the pose of ``source`` in ``target`` (tf2's lookupTransform(target, source))."""
        root_t, target_pose = self.from_root(target)
        root_s, source_pose = self.from_root(source)
        assert root_t == root_s, f'{target} ({root_t}) and {source} ({root_s}) are not connected'
        return np.linalg.inv(target_pose) @ source_pose


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


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Return the rotation angle (rad) between the rotation parts of two poses."""
    r = a[:3, :3].T @ b[:3, :3]
    # atan2 of sine and cosine stays accurate near zero, where acos of the trace does not.
    sine = np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2
    return math.atan2(sine, (np.trace(r) - 1) / 2)
