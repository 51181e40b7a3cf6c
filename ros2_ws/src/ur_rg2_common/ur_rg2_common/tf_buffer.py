"""A small transform buffer: the latest parent->child transforms from /tf and /tf_static.

tf2_ros is not on PyPI. What the nodes need of it is little: keep the latest transform of each
child frame and compose the chain between two frames of the tree. The frames they look up
between (``base_link``, the camera frames, ``world``, ``rg2_tcp``) are fixed relative to each
other or move with the arm, so no interpolation in time is done: a lookup uses the latest
transforms. Plain Python, no ROS imports; messages are read by their fields only, or from
their serialized bytes (``add_serialized``: rclpy builds a Python object for each of a
TFMessage's transforms, some 0.6 ms a message here, where reading the bytes takes 0.03 ms).

Used by the motion, policy, viewer and 3D view nodes, so it lives in the package every node uses;
so do the conversions between xyzw quaternions and matrices (the sim's frames and motion use
them).
"""

from collections.abc import Callable, Iterable, Sequence
import math
import struct
import threading
import time

import numpy as np

# How often a lookup that waits for frames pulls them (TransformBuffer.pull), s.
PULL_PERIOD_S = 0.01
# The encapsulation headers of plain CDR, big and little endian: the struct byte order.
_CDR_BYTE_ORDERS = {b'\x00\x00': '>', b'\x00\x01': '<'}

Transform = tuple[str, str, tuple[float, ...]]  # parent, child, (x, y, z, qx, qy, qz, qw)


def pose_matrix(position: Sequence[float], quaternion: Sequence[float]) -> np.ndarray:
    """Return the 4x4 matrix of a position and an xyzw unit quaternion."""
    x, y, z, w = quaternion
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = position
    return m


def transform_matrix(transform) -> np.ndarray:
    """Return the 4x4 matrix of a geometry_msgs/Transform."""
    t, r = transform.translation, transform.rotation
    return pose_matrix((t.x, t.y, t.z), (r.x, r.y, r.z, r.w))


def set_pose(pose, matrix: np.ndarray) -> None:
    """Write a 4x4 pose matrix into a geometry_msgs/Pose's position and orientation."""
    p, q = pose.position, pose.orientation
    p.x, p.y, p.z = (float(v) for v in matrix[:3, 3])
    q.x, q.y, q.z, q.w = quaternion_from_matrix(matrix)


def quaternion_from_matrix(matrix: np.ndarray) -> tuple[float, float, float, float]:
    """Return the xyzw unit quaternion (w >= 0) of a rotation or pose matrix."""
    m = np.asarray(matrix, dtype=float)[:3, :3]
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    # Shepperd's method: divide by the largest of the four candidates, for accuracy.
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    i = int(np.argmax(candidates))
    if i == 0:
        s = 2 * math.sqrt(1 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif i == 1:
        s = 2 * math.sqrt(1 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif i == 2:
        s = 2 * math.sqrt(1 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2 * math.sqrt(1 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    sign = -1.0 if q[3] < 0 else 1.0
    return tuple(float(sign * v) for v in q)


class FrameLookupError(LookupError):
    """A lookup names a frame the buffer has not heard of, or two unconnected frames."""


class TransformBuffer:
    """Latest parent->child transforms by child frame; thread-safe.

    ``pull`` is called, holding no lock, before each lookup and while one waits: a node whose
    /tf waits in an inbox (ur_rg2_common.inbox) adds what came then.
    """

    def __init__(self) -> None:
        self.pull: Callable[[], object] = lambda: None
        # By child: (parent, the child's pose in it), the pose a 4x4 or, until a lookup needs
        # its matrix, its (x, y, z, qx, qy, qz, qw) (most values of /tf are never looked up).
        self._edges: dict[str, tuple[str, np.ndarray | tuple[float, ...]]] = {}
        # Reentrant, and notified on every change: lookups may wait for a frame to arrive.
        self._lock = threading.Condition(threading.RLock())

    def set_transform(self, parent: str, child: str, transform: np.ndarray) -> None:
        """Store ``parent`` -> ``child`` (4x4: the child's pose in the parent)."""
        with self._lock:
            self._edges[child] = (parent, transform)
            self._lock.notify_all()

    def add_message(self, message) -> int:
        """Store every well-formed transform of a tf2_msgs/TFMessage; return how many not.

        A transform without both frame ids, from a frame to itself, with a value that is not
        finite or a rotation that is not a unit quaternion, or that would close a loop in the
        tree, is left out: one would break every lookup through its frames until replaced,
        and a frame nobody publishes again (``world``) never is.
        """
        transforms = []
        for stamped in message.transforms:
            t, r = stamped.transform.translation, stamped.transform.rotation
            transforms.append((stamped.header.frame_id, stamped.child_frame_id,
                               (t.x, t.y, t.z, r.x, r.y, r.z, r.w)))
        return self._add(transforms)

    def add_serialized(self, data: bytes) -> int:
        """Store the transforms of a serialized TFMessage as ``add_message`` does.

        Returns how many are left out; bytes that are no plain CDR TFMessage count as one.
        """
        try:
            transforms = serialized_transforms(data)
        except ValueError:
            return 1
        return self._add(transforms)

    def _add(self, transforms: Iterable[Transform]) -> int:
        rejected = 0
        with self._lock:
            for parent, child, values in transforms:
                parent, child = parent.lstrip('/'), child.lstrip('/')
                qx, qy, qz, qw = values[3:]
                # A new value of an edge already in the tree keeps its shape: no loop to check.
                if (not parent or not child or parent == child
                        or not all(math.isfinite(v) for v in values)
                        or abs(math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) - 1.0) > 1e-3
                        or (self._edges.get(child, ('',))[0] != parent
                            and self._above(child, parent))):
                    rejected += 1
                    continue
                self._edges[child] = (parent, values)
            self._lock.notify_all()
        return rejected

    def _above(self, frame: str, below: str) -> bool:
        """Return whether ``frame`` is ``below`` or one of its ancestors."""
        with self._lock:
            seen = set()
            while below not in seen:
                if below == frame:
                    return True
                seen.add(below)
                if below not in self._edges:
                    return False
                below = self._edges[below][0]
            return False

    def frames(self) -> set[str]:
        """Return every frame heard of, parents and children."""
        with self._lock:
            return set(self._edges) | {parent for parent, _ in self._edges.values()}

    def lookup(self, target: str, source: str, timeout: float = 0.0) -> np.ndarray:
        """Return the pose of frame ``source`` in frame ``target`` (tf2's lookupTransform).

        With a ``timeout`` (s), wait up to that long for the tree to connect the two frames
        (a latched /tf_static may arrive after the first request) before raising
        FrameLookupError.
        """
        deadline = time.monotonic() + timeout
        while True:
            self.pull()
            with self._lock:
                try:
                    return self._lookup(target, source)
                except FrameLookupError:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        raise
                    self._lock.wait(min(remaining, PULL_PERIOD_S))

    def _lookup(self, target: str, source: str) -> np.ndarray:
        target, source = target.lstrip('/'), source.lstrip('/')
        with self._lock:
            known = set(self._edges) | {parent for parent, _ in self._edges.values()}
            for frame in (target, source):
                if frame not in known:
                    raise FrameLookupError(f'unknown frame {frame!r} (not on /tf or /tf_static)')
            target_root, target_pose = self._from_root(target)
            source_root, source_pose = self._from_root(source)
        if target_root != source_root:
            raise FrameLookupError(f'frames {target!r} and {source!r} are not connected')
        return np.linalg.solve(target_pose, source_pose)

    def _from_root(self, frame: str) -> tuple[str, np.ndarray]:
        """Return the root of ``frame``'s tree and root -> ``frame``."""
        pose = np.eye(4)
        seen = set()
        while frame in self._edges:
            if frame in seen:
                raise FrameLookupError(f'the transforms loop through {frame!r}')
            seen.add(frame)
            parent, edge = self._edges[frame]
            if isinstance(edge, tuple):
                edge = pose_matrix(edge[:3], edge[3:])
                self._edges[frame] = (parent, edge)
            pose = edge @ pose
            frame = parent
        return frame, pose


def serialized_transforms(data: bytes) -> list[Transform]:
    """Return the transforms of a tf2_msgs/TFMessage serialized in plain CDR (ValueError)."""
    order = _CDR_BYTE_ORDERS.get(bytes(data[:2]))
    if order is None:
        raise ValueError('not a plain CDR message')
    body = memoryview(data)[4:]  # CDR aligns from the end of the encapsulation header
    u32, values = struct.Struct(order + 'I'), struct.Struct(order + '7d')
    offset = 0

    def string() -> str:
        nonlocal offset
        offset += -offset % 4
        (length,) = u32.unpack_from(body, offset)  # with the terminating NUL
        start, offset = offset + 4, offset + 4 + length
        if offset > len(body):
            raise ValueError('a truncated string')
        return bytes(body[start:max(start, offset - 1)]).decode()

    try:
        (count,) = u32.unpack_from(body, 0)
        offset = 4
        transforms = []
        for _ in range(count):
            offset += -offset % 4 + 8  # header.stamp: int32 sec, uint32 nanosec
            parent = string()
            child = string()
            offset += -offset % 8
            transforms.append((parent, child, values.unpack_from(body, offset)))
            offset += values.size
    except (struct.error, UnicodeDecodeError) as error:
        raise ValueError(f'not a TFMessage: {error}') from None
    return transforms


def transform_point(transform: np.ndarray, point: Iterable[float]) -> np.ndarray:
    """Return ``point`` (x, y, z) mapped by the 4x4 ``transform``."""
    return transform[:3, :3] @ np.asarray(list(point), dtype=float) + transform[:3, 3]
