"""ROS messages of the motion, without a node: the motion and policy nodes both use them.

:func:`trajectory_goal` is the arm's goal for the trajectory controller (the sim's, or a real
UR driver's ``scaled_joint_trajectory_controller``), :func:`gripper_goal` the RG2's for the
gripper controller; :func:`ball_in_base_link` places the latest ``ball/position`` in
``base_link`` through the transform tree; :func:`pose_of` checks and converts a
``geometry_msgs/Pose``.
"""

from collections.abc import Sequence
import math
import time

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory, GripperCommand
from geometry_msgs.msg import PointStamped
import numpy as np
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_rg2_common.contract import ARM_JOINTS, RG2_MAX_FORCE
from ur_rg2_common.tf_buffer import (
    FrameLookupError,
    TransformBuffer,
    pose_matrix,
    transform_point,
)

from ur_rg2_motion.urdf import BASE_LINK

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


def gripper_goal(opening: float) -> GripperCommand.Goal:
    """Return the RG2's goal: its fingers ``opening`` m apart, at full force."""
    goal = GripperCommand.Goal()
    goal.command.position = float(opening)
    goal.command.max_effort = RG2_MAX_FORCE
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
