"""ROS messages of the motion, without a node: the motion and policy nodes both use them.

:func:`trajectory_goal` is the arm's goal for the trajectory controller (the sim's, or a real
UR driver's ``scaled_joint_trajectory_controller``); :func:`ball_in_base_link` places the
latest ``ball/position`` in ``base_link`` through the transform tree.
"""

from collections.abc import Sequence
import time

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import PointStamped
import numpy as np
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer, transform_point

from ur_rg2_motion.kinematics import BASE_LINK


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
        to_base = tree.lookup(BASE_LINK, point.header.frame_id)
    except FrameLookupError as error:
        raise ValueError(f'the ball cannot be placed in {BASE_LINK}: {error}') from None
    centre = transform_point(to_base, (point.point.x, point.point.y, point.point.z))
    if not np.isfinite(centre).all():
        raise ValueError('the ball position is not finite')
    return centre
