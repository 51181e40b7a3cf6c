"""Trajectories for TCP moves and the plan of a ball pick. Plain Python, no ROS.

A TCP move goes along the straight line between the two poses (positions interpolated, the
orientation turned about one axis) when the inverse kinematics follows it without jumping
from one arm posture to another; otherwise (the line leaves the reach, crosses the floor or
the pedestal, or needs a change of posture) the joints go straight to the target's solution.
Either way the timing is a minimum-jerk profile along the path (zero speed and acceleration
at both ends) as fast as ``speed_scale`` times each joint's velocity limit allows.
"""

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
from ur_rg2_common.tf_buffer import pose_matrix, quaternion_from_matrix

from ur_rg2_motion.kinematics import (
    ArmKinematics,
    KinematicsError,
    rotation_angle,
)

# The peak speed of a minimum-jerk profile over its mean speed.
_MIN_JERK_PEAK = 1.875
# Cartesian interpolation steps, and the largest joint change between two steps that is still
# the same posture (a branch switch of the inverse kinematics jumps by far more).
_LINEAR_STEP = 0.01  # m
_ANGULAR_STEP = math.radians(3.0)
_BRANCH_JUMP = 0.35  # rad
_MAX_STEPS = 200


@dataclass(frozen=True)
class Trajectory:
    """Joint positions (N, 6) to reach at ``times`` (N,) s from the start."""

    times: np.ndarray
    positions: np.ndarray
    straight: bool  # whether the TCP follows the straight line

    @property
    def duration(self) -> float:
        """Seconds from the start to the last point."""
        return float(self.times[-1])


def interpolate(start: np.ndarray, end: np.ndarray, fractions: Sequence[float]) -> np.ndarray:
    """Return poses (N, 4, 4) along the straight line and the one-axis turn from start to end."""
    q0 = np.array(quaternion_from_matrix(start))
    q1 = np.array(quaternion_from_matrix(end))
    dot = float(q0 @ q1)
    if dot < 0:  # the shorter way round
        q1, dot = -q1, -dot
    theta = math.acos(min(dot, 1.0))
    poses = []
    for s in fractions:
        if theta < 1e-6:
            q = q0 + s * (q1 - q0)
        else:
            q = (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)
        poses.append(pose_matrix(start[:3, 3] + s * (end[:3, 3] - start[:3, 3]),
                                 q / np.linalg.norm(q)))
    return np.array(poses).reshape(-1, 4, 4)


def plan_move(arm: ArmKinematics, current: Sequence[float], target: np.ndarray,
              velocity_limits: Sequence[float], speed_scale: float,
              min_duration: float) -> Trajectory:
    """Return the trajectory that takes the TCP from where ``current`` puts it to ``target``.

    Raises KinematicsError (from the target's inverse kinematics) when the target is refused.
    """
    current = np.asarray(current, dtype=float)
    goal = arm.solve(target, current)
    start = arm.tcp_pose(current)
    distance = np.linalg.norm(target[:3, 3] - start[:3, 3])
    angle = float(rotation_angle(start, target))
    steps = max(1, math.ceil(max(distance / _LINEAR_STEP, angle / _ANGULAR_STEP)))
    waypoints = _straight_line(arm, current, start, target, goal, steps)
    straight = waypoints is not None
    if not straight:
        waypoints = goal[None]
    return _time_path(current, waypoints, np.asarray(velocity_limits) * speed_scale,
                      min_duration, straight)


def plan_joint_move(current: Sequence[float], goal: Sequence[float],
                    velocity_limits: Sequence[float], speed_scale: float,
                    min_duration: float) -> Trajectory:
    """Return the trajectory that takes the joints straight from ``current`` to ``goal``."""
    return _time_path(np.asarray(current, dtype=float), np.asarray(goal, dtype=float)[None],
                      np.asarray(velocity_limits) * speed_scale, min_duration, False)


def _straight_line(arm: ArmKinematics, current: np.ndarray, start: np.ndarray,
                   target: np.ndarray, goal: np.ndarray, steps: int) -> np.ndarray | None:
    """Return joint waypoints along the straight TCP line, or None where it cannot be kept."""
    if steps > _MAX_STEPS:
        return None
    waypoints = []
    previous = current
    for pose in interpolate(start, target, np.arange(1, steps) / steps):
        try:
            q = arm.solve(pose, previous)
        except KinematicsError:
            return None
        if np.abs(q - previous).max() > _BRANCH_JUMP:
            return None
        waypoints.append(q)
        previous = q
    if np.abs(goal - previous).max() > _BRANCH_JUMP:
        return None
    waypoints.append(goal)
    return np.array(waypoints)


def _time_path(current: np.ndarray, waypoints: np.ndarray, speeds: np.ndarray,
               min_duration: float, straight: bool) -> Trajectory:
    """Time the joint path current -> waypoints with a minimum-jerk profile along it.

    The path is parametrised by its length in "seconds at full speed" (each segment as long
    as its slowest joint needs), so no joint exceeds its speed anywhere along it.
    """
    path = np.vstack([current, waypoints])
    lengths = (np.abs(np.diff(path, axis=0)) / speeds).max(axis=1)
    covered = np.cumsum(lengths)
    total = float(covered[-1])
    duration = max(min_duration, _MIN_JERK_PEAK * total)
    fractions = covered / total if total > 0 else np.ones(len(waypoints))
    times = duration * _min_jerk_inverse(fractions)
    # Waypoints within rounding of each other in time would be refused (times must rise).
    keep = np.diff(np.concatenate([[0.0], times])) > 1e-4
    keep[-1] = True
    return Trajectory(times[keep], waypoints[keep], straight)


def _min_jerk_inverse(fractions: np.ndarray) -> np.ndarray:
    """Return the times in [0, 1] at which the minimum-jerk profile covers ``fractions``."""
    grid = np.linspace(0.0, 1.0, 2001)
    covered = grid ** 3 * (10 - 15 * grid + 6 * grid ** 2)
    return np.interp(fractions, covered, grid)


# -- the pick ---------------------------------------------------------------------------------

# Shoulder lift, elbow, wrist 1 and wrist 2 of the posture a pick works in: upper arm up,
# elbow above and ahead of the shoulder, gripper pointing down (the UR's usual table posture).
PICK_POSTURE = (-math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2)

def gripper_down(position: Sequence[float], yaw: float) -> np.ndarray:
    """Return the TCP pose at ``position`` (base_link) pointing down, turned ``yaw`` about z."""
    c, s = math.cos(yaw), math.sin(yaw)
    pose = np.eye(4)
    # x along yaw, z straight down, y completing the right-handed frame.
    pose[:3, :3] = [[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]]
    pose[:3, 3] = position
    return pose


@dataclass(frozen=True)
class PickPlan:
    """TCP poses in base_link of a pick, all pointing down."""

    ball: np.ndarray  # the ball's centre
    radius: float  # the ball's radius, from its centre's height above the floor
    joints_above: np.ndarray  # the arm's joints at ``above``, in the pick posture
    above: np.ndarray  # approach_height above the grasp
    grasp: np.ndarray  # the pads around the ball's equator (or as low as the floor allows)
    lift: np.ndarray  # lift_height above the grasp


def plan_pick(arm: ArmKinematics, current: Sequence[float], ball: Sequence[float],
              approach_height: float, lift_height: float,
              floor_margin: float = 0.005) -> PickPlan:
    """Return the pick poses for a ball centred at ``ball`` (base_link, on the floor).

    Above the ball the arm takes the solution nearest the pick posture (PICK_POSTURE, the
    shoulder turned toward the ball, wrist 3 where it is); descent and lift stay in it. The
    gripper turns about the vertical to whichever of four headings (along and across the line
    from the base to the ball) is nearest that. Raises KinematicsError with the reason when
    one of the three poses cannot be reached.
    """
    ball = np.asarray(ball, dtype=float)
    current = np.asarray(current, dtype=float)
    radius = float(ball[2] - arm.floor_z) if math.isfinite(arm.floor_z) else 0.0
    lowest = arm.floor_z + arm.finger_length + floor_margin
    grasp_z = max(float(ball[2]), lowest) if math.isfinite(lowest) else float(ball[2])
    heading = math.atan2(ball[1], ball[0])
    posture = np.array([heading, *PICK_POSTURE, current[5]])
    best, best_cost, error = None, math.inf, None
    for yaw in heading + np.array([0.0, 0.5, -0.5, 1.0]) * math.pi:
        poses = [gripper_down((ball[0], ball[1], grasp_z + height), yaw)
                 for height in (approach_height, 0.0, lift_height)]
        try:
            q_above = arm.solve(poses[0], posture)
            q_grasp = arm.solve(poses[1], q_above)
            q_lift = arm.solve(poses[2], q_grasp)
        except KinematicsError as refused:
            error = error or refused
            continue
        cost = (np.sum((q_above - posture) ** 2) + np.sum((q_grasp - q_above) ** 2)
                + np.sum((q_lift - q_grasp) ** 2))
        if cost < best_cost:
            best, best_cost = (q_above, *poses), cost
    if best is None:
        raise error
    return PickPlan(ball, radius, *best)


def grasp_check(opening: float, stalled: bool, radius: float, tolerance: float) -> str | None:
    """Return why a closed gripper does not hold the ball, or None when it does.

    ``opening`` is the distance between the pads (m) after closing, ``radius`` the ball's.
    """
    diameter = 2 * radius
    if opening < 0.002:
        return f'missed: the gripper closed on nothing (opening {opening * 1000:.1f} mm)'
    if not stalled:
        return (f'missed: the gripper did not stop on the ball (opening '
                f'{opening * 1000:.1f} mm)')
    if radius > 0 and abs(opening - diameter) > tolerance:
        return (f"missed: the gripper stopped at {opening * 1000:.1f} mm, not about the ball's "
                f'{diameter * 1000:.0f} mm diameter')
    return None


def limit_tcp_speed(trajectory: Trajectory, arm: ArmKinematics, start: np.ndarray,
                    speed: float) -> Trajectory:
    """Return the trajectory slowed so that a straight move's TCP peaks at ``speed`` m/s."""
    if not trajectory.straight:
        return trajectory
    distance = np.linalg.norm(arm.tcp_pose(trajectory.positions[-1])[:3, 3]
                              - arm.tcp_pose(start)[:3, 3])
    needed = _MIN_JERK_PEAK * distance / speed
    if needed <= trajectory.duration:
        return trajectory
    return Trajectory(trajectory.times * (needed / trajectory.duration), trajectory.positions,
                      trajectory.straight)


def jog_target(start: np.ndarray, frame: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Return the TCP pose ``start`` moved by ``step`` (4x4) given in the axes of ``frame``.

    The translation is along the frame's axes, the rotation about the TCP, about the frame's
    axes (all poses in base_link).
    """
    axes = frame[:3, :3]
    target = start.copy()
    target[:3, 3] = start[:3, 3] + axes @ step[:3, 3]
    target[:3, :3] = axes @ step[:3, :3] @ axes.T @ start[:3, :3]
    return target
