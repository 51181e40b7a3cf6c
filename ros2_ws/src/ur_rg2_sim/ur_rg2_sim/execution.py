"""A planned joint trajectory being run, as joint_trajectory_controller runs it. No ROS here.

:class:`Execution` samples the spline of :func:`ur_rg2_sim.trajectory.plan` each physics step
and decides the outcome from the goal's path and goal tolerances, with a FollowJointTrajectory
error code.
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ur_rg2_sim.trajectory import (
    GOAL_TOLERANCE_VIOLATED,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    Goal,
    Spline,
)


@dataclass(frozen=True)
class Outcome:
    """How a goal ended: a FollowJointTrajectory error code and a sentence."""

    code: int
    message: str


@dataclass
class Sample:
    """What the controller wanted and what the joints did at one time, in the goal's order."""

    time: float
    desired: tuple[np.ndarray, np.ndarray, np.ndarray]  # positions, velocities, accelerations
    actual: tuple[np.ndarray, np.ndarray]  # positions, velocities


class Execution:
    """A planned goal being run: call :meth:`update` every step with the joints' state."""

    def __init__(self, goal: Goal, spline: Spline) -> None:
        self.goal = goal
        self.spline = spline
        self.last: Optional[Sample] = None

    def desired(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the desired positions, velocities and accelerations at ``t``."""
        return self.spline.sample(t)

    def update(self, t: float, positions: np.ndarray, velocities: np.ndarray,
               desired: Optional[tuple] = None) -> Optional[Outcome]:
        """Record the state at ``t``; return the outcome once the goal has one."""
        desired = self.spline.sample(t) if desired is None else desired
        self.last = Sample(t, desired, (positions, velocities))
        goal = self.goal
        position_error = np.abs(desired[0] - positions)
        if t < self.spline.end_time:
            bad = _first_violation(position_error, goal.path_position,
                                   np.abs(desired[1] - velocities), goal.path_velocity)
            if bad is not None:
                return Outcome(PATH_TOLERANCE_VIOLATED,
                               f'{goal.joints[bad[0]]} is {bad[1]} off the trajectory at '
                               f'{t - self.spline.start_time:.3f} s (path_tolerance '
                               f'{bad[2]})')
            return None
        bad = _first_violation(position_error, goal.goal_position, np.abs(velocities),
                               goal.goal_velocity)
        if bad is None:
            return Outcome(SUCCESSFUL, 'reached the last point within goal_tolerance after '
                           f'{t - self.spline.start_time:.3f} s')
        if t > self.spline.end_time + goal.goal_time_tolerance:
            return Outcome(GOAL_TOLERANCE_VIOLATED,
                           f'{goal.joints[bad[0]]} is still {bad[1]} from the last point '
                           f'{goal.goal_time_tolerance:g} s after its time (goal_tolerance '
                           f'{bad[2]})')
        return None


def _first_violation(position_error: np.ndarray, position_tolerance: np.ndarray,
                     velocity_error: np.ndarray, velocity_tolerance: np.ndarray):
    for j in range(len(position_error)):
        if position_error[j] > position_tolerance[j]:
            return j, f'{position_error[j]:.4f} rad', f'{position_tolerance[j]:g} rad'
        if velocity_error[j] > velocity_tolerance[j]:
            return j, f'{velocity_error[j]:.4f} rad/s', f'{velocity_tolerance[j]:g} rad/s'
    return None
