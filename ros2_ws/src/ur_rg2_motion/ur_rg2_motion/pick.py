"""The ball pick as a sequence of steps, without ROS: plan, open, go above, descend, close, lift.

:func:`run_pick` drives an :class:`Arm` (the motion node's: goals to the trajectory and gripper
controllers, the latest joint states) and judges each step: the arm must come to rest first,
stay where it is while the gripper closes (else another command moved it), the gripper must
stop on the ball (:func:`ur_rg2_motion.planning.grasp_check`) and still hold it after the lift.
Each failure raises :class:`PickError` (or :class:`PickCancelledError`) saying why. Its
``progress`` hears each phase as it starts, with the TCP positions still to go through.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import math
import time
from typing import Protocol

import numpy as np
from ur_rg2_common.contract import RG2_MAX_OPENING

from ur_rg2_motion.kinematics import ArmKinematics, KinematicsError
from ur_rg2_motion.planning import (
    Trajectory,
    grasp_check,
    limit_tcp_speed,
    plan_joint_move,
    plan_move,
    plan_pick,
)

# The shortest move, so a tiny one is still a smooth start and stop.
MIN_MOVE_DURATION = 0.2  # s
# The pick starts once no arm joint moves faster than this (rad/s), waiting at most so long.
REST_SPEED = 0.02
REST_TIMEOUT = 10.0  # s
_REST_POLL = 0.02  # s
STAYED_TOLERANCE = 0.02  # rad: the arm held at the ball sags less than this as it grips
# The opening may change this much during the lift (m) before the ball counts as dropped.
HELD_TOLERANCE = 0.005
# The pick's straight moves must not take more than this share of the joint speed limits.
PICK_SPEED_SCALE = 0.7
# The pick's phases, in order: before the plan (the arm to rest, the ball placed), the swing
# above the ball (the gripper opening meanwhile), the descent, the gripper closing, the lift.
PLANNING, APPROACHING, DESCENDING, GRASPING, LIFTING = (
    'planning', 'approaching', 'descending', 'grasping', 'lifting')
# progress(phase, waypoints): the TCP positions (base_link, m) the phase and those after it go
# through, in order.
Progress = Callable[[str, Sequence[np.ndarray]], None]


class PickCancelledError(Exception):
    """The pick was cancelled by another arm command."""


class PickError(Exception):
    """The pick cannot go on; str() says why."""


@dataclass(frozen=True)
class GripResult:
    """How a gripper goal ended: the opening (m) and whether it stopped on an object."""

    position: float
    stalled: bool


@dataclass(frozen=True)
class PickSettings:
    """The motion node's parameters that shape a pick."""

    approach_height: float
    lift_height: float
    speed_scale: float
    approach_speed: float
    grasp_tolerance: float


class Arm(Protocol):
    """What the pick needs of the robot; every call may raise PickError or PickCancelledError."""

    velocity_limits: np.ndarray

    def joints(self) -> np.ndarray:
        """Return the arm joints now (rad)."""

    def speed(self) -> float:
        """Return the fastest arm joint's speed now (rad/s)."""

    def opening(self) -> float | None:
        """Return the gripper's opening now (m), None when unknown."""

    def check(self) -> None:
        """Raise when the pick is to stop (cancelled, or vision lost while it needs it)."""

    def vision_done(self) -> None:
        """From now on the pick no longer goes by what vision sees."""

    def move(self, trajectory: Trajectory, what: str) -> None:
        """Run ``trajectory`` to its end."""

    def start_grip(self, opening: float) -> object:
        """Send a gripper goal toward ``opening`` (m); return what finish_grip takes."""

    def finish_grip(self, pending: object, what: str) -> GripResult:
        """Wait for the gripper goal sent by start_grip to end."""


def no_progress(_phase: str, _waypoints: Sequence[np.ndarray]) -> None:
    """Hear nothing of the pick's phases (a pick nobody watches)."""


def run_pick(arm: Arm, model: ArmKinematics, ball: np.ndarray, settings: PickSettings,
             progress: Progress = no_progress) -> float:
    """Pick the ball centred at ``ball`` (base_link); return the opening it is held at."""
    progress(PLANNING, ())
    wait_for_rest(arm)
    joints = arm.joints()
    try:
        plan = plan_pick(model, joints, ball, settings.approach_height, settings.lift_height)
    except KinematicsError as error:
        raise PickError(f'out of reach: {error}') from None
    arm.check()
    scale = settings.speed_scale
    straight_scale = min(scale, PICK_SPEED_SCALE)
    above, grasp, lift = (pose[:3, 3] for pose in (plan.above, plan.grasp, plan.lift))
    progress(APPROACHING, (above, grasp, lift))
    # Opening while the arm swings over: the fingers are clear of the ball above it.
    opening = arm.start_grip(RG2_MAX_OPENING)
    arm.move(plan_joint_move(joints, plan.joints_above, arm.velocity_limits, scale,
                             MIN_MOVE_DURATION), 'moving above the ball')
    arm.finish_grip(opening, 'opening the gripper')
    progress(DESCENDING, (grasp, lift))
    _straight(arm, model, plan.grasp, settings.approach_speed, straight_scale,
              'descending to the ball')
    progress(GRASPING, (grasp, lift))
    at_ball = arm.joints()
    closing = arm.start_grip(0.0)
    result = arm.finish_grip(closing, 'closing the gripper')
    arm.vision_done()  # the ball is in the hand or missed: no reading counts
    check_arm_stayed(arm, at_ball, 'closing the gripper')
    missed = grasp_check(result.position, result.stalled, plan.radius,
                         settings.grasp_tolerance)
    if missed:
        raise PickError(missed)
    progress(LIFTING, (lift,))
    _straight(arm, model, plan.lift, settings.approach_speed, straight_scale,
              'lifting the ball')
    held = arm.opening()
    # Slipped out during the lift, the fingers would have closed on after it.
    if held is None or abs(held - result.position) > HELD_TOLERANCE:
        raise PickError(f'dropped: the gripper is at {1000 * (held or 0):.1f} mm after the '
                        f'lift, {1000 * result.position:.1f} mm when it closed')
    return held


def wait_for_rest(arm: Arm, timeout: float = REST_TIMEOUT) -> None:
    """Wait for the arm to stop (a reset or jog under way): moves are planned from rest."""
    deadline = time.monotonic() + timeout
    while True:
        arm.check()
        if arm.speed() < REST_SPEED:
            return
        if time.monotonic() > deadline:
            raise PickError(f'the arm did not come to rest within {timeout:g} s')
        time.sleep(_REST_POLL)


def check_arm_stayed(arm: Arm, joints: np.ndarray, what: str) -> None:
    """Give up when the arm left ``joints`` during a gripper step: something else drives it.

    The sim's ``reset`` service is such a command that the motion node cannot see being sent;
    lifting from where the arm went would override it.
    """
    moved = float(np.abs(arm.joints() - joints).max())
    if moved > STAYED_TOLERANCE or arm.speed() >= REST_SPEED:
        raise PickCancelledError(
            f'cancelled: the arm was moved by another command while {what} '
            f'({math.degrees(moved):.1f} deg away, a reset?)')


def _straight(arm: Arm, model: ArmKinematics, pose: np.ndarray, speed: float, scale: float,
              what: str) -> None:
    joints = arm.joints()
    try:
        trajectory = plan_move(model, joints, pose, arm.velocity_limits, scale,
                               MIN_MOVE_DURATION)
    except KinematicsError as error:
        raise PickError(f'{what}: {error}') from None
    arm.move(limit_tcp_speed(trajectory, model, joints, speed), what)
