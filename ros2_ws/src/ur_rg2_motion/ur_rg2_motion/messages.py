"""ROS messages of the motion, without a node: the motion and policy nodes both use them.

:func:`trajectory_goal` is the arm's goal for the trajectory controller (the sim's, or a real
UR driver's ``scaled_joint_trajectory_controller``); :func:`ball_in_base_link` places the
latest ``ball/position`` in ``base_link`` through the transform tree; :func:`pose_of` checks
and converts a ``geometry_msgs/Pose``.
"""

from collections.abc import Sequence
import math
import threading
import time

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import PointStamped
import numpy as np
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS
from ur_rg2_common.tf_buffer import (
    FrameLookupError,
    TransformBuffer,
    pose_matrix,
    transform_point,
)

from ur_rg2_motion.kinematics import BASE_LINK

# A quaternion this close to unit length is a client's rounding: normalised without a word.
QUATERNION_NORM_TOLERANCE = 1e-3


def trajectory_goal(times: Sequence[float], positions: Sequence[Sequence[float]]
                    ) -> FollowJointTrajectory.Goal:
    """Return the goal of the six arm joints at ``positions`` (rad) ``times`` s from now."""
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = list(ARM_JOINTS)
    for t, point in zip(times, positions):
        ns = round(float(t) * 1e9)
        goal.trajectory.points.append(JointTrajectoryPoint(
            positions=[float(p) for p in point],
            time_from_start=Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)))
    return goal


# How long a request waits for the latched transforms it needs before it is refused, s.
FRAME_WAIT_S = 5.0


def ball_in_base_link(tree: TransformBuffer, ball: tuple[float, PointStamped] | None,
                      timeout: float) -> np.ndarray:
    """Return the ball's centre in base_link from the latest ``ball/position``.

    ``ball`` is (time.monotonic() when it came, the message), or None before the first.
    Raises ValueError saying why when it is older than ``timeout`` s, missing, not finite or
    in a frame the tree cannot place.
    """
    if ball is None or time.monotonic() - ball[0] > timeout:
        raise ValueError(f"no ball seen in the last {timeout:g} s (is it in the camera's "
                         'view, and is the vision node running?)')
    point = ball[1]
    try:
        to_base = tree.lookup(BASE_LINK, point.header.frame_id, timeout=FRAME_WAIT_S)
    except FrameLookupError as error:
        raise ValueError(f'the ball cannot be placed in {BASE_LINK}: {error}') from None
    centre = transform_point(to_base, (point.point.x, point.point.y, point.point.z))
    if not np.isfinite(centre).all():
        raise ValueError('the ball position is not finite')
    return centre


def finite(what: str, values) -> tuple[float, ...]:
    """Return ``values`` as floats; raise ValueError naming ``what`` unless all are finite."""
    values = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f'{what} {values} is not finite')
    return values


def unit_quaternion(values) -> tuple[float, ...]:
    """Return the quaternion normalised when its length is 1 within rounding, else raise."""
    values = finite('orientation', values)
    norm = math.sqrt(sum(v * v for v in values))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f'orientation quaternion {values} has length {norm:.4f}, not 1 '
                         f'(within {QUATERNION_NORM_TOLERANCE:g}): not normalised, rejected')
    return tuple(v / norm for v in values)


def pose_of(pose) -> np.ndarray:
    """Return the 4x4 of a geometry_msgs/Pose; ValueError when it is not finite or not unit."""
    p, q = pose.position, pose.orientation
    return pose_matrix(finite('position', (p.x, p.y, p.z)),
                       unit_quaternion((q.x, q.y, q.z, q.w)))


class JointStateCache:
    """The latest arm joints, their fastest speed and the RG2's opening, from ``joint_states``.

    The arm and the RG2 may come in separate messages (a real cell: the UR driver, and
    ur_rg2_hardware's ``rg2_adapter`` for OnRobot's driver); each message updates what it has.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._joints: np.ndarray | None = None
        self._speed = 0.0
        self._opening: float | None = None

    def add(self, message: JointState) -> None:
        """Take what ``message`` says of the six arm joints and of the RG2's fingers."""
        positions = dict(zip(message.name, message.position))
        speeds = dict(zip(message.name, message.velocity))
        with self._lock:
            if all(name in positions for name in ARM_JOINTS):
                self._joints = np.array([positions[name] for name in ARM_JOINTS])
                self._speed = max(abs(speeds.get(name, 0.0)) for name in ARM_JOINTS)
            if all(name in positions for name in GRIPPER_JOINTS):
                self._opening = sum(positions[name] for name in GRIPPER_JOINTS)

    def joints(self) -> np.ndarray | None:
        """Return the arm joints (rad), None before the first."""
        with self._lock:
            return self._joints

    def speed(self) -> float:
        """Return the fastest arm joint's speed (rad/s)."""
        with self._lock:
            return self._speed

    def opening(self) -> float | None:
        """Return the RG2's opening (m, the sum of its finger joints), None before the first."""
        with self._lock:
            return self._opening
