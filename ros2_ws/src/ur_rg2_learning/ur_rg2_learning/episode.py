"""One policy episode on the live graph, without ROS: what the ``policy`` node observes and sends.

:func:`start_episode` checks that the ball is within reach and plans the move to the
environment's start pose. An :class:`Episode` builds each step's observation as the
environment builds it (from the measured joints, the RG2's opening and the ball the camera
sees), decides when the episode ends, and turns the actor's action into the step's joint goal
(``robot.move_target``), its duration (``robot.step_duration``: the controller refuses a goal
too fast rather than slow it down, where the environment's motors only lag) and, for Pick, a
change of the gripper. The node does the messaging around it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time

import numpy as np
from ur_rg2_motion.kinematics import ArmKinematics, KinematicsError
from ur_rg2_motion.planning import Trajectory, plan_joint_move, plan_pick

from ur_rg2_learning import EPISODE_STEPS, PICK_ID, REACH_ID
from ur_rg2_learning.robot import (
    CONTROL_RATE,
    START_TCP,
    move_target,
    start_joints,
    step_duration,
    tcp_pose,
)
from ur_rg2_learning.scripted import APPROACH_HEIGHT
from ur_rg2_learning.tasks import (
    LIFT_GOAL,
    LIFT_SUCCESS,
    PICK_GOAL_TOLERANCE,
    REACH_TOLERANCE,
    pick_goal,
    pick_observation,
    reach_observation,
)

LOST_STEPS = 30  # Pick steps (3 s of simulation time) a ball not held may go unseen
# A closed RG2 holds the ball when its fingers stopped this near the ball's diameter (the
# motion node's grasp check) with the ball this near the TCP.
GRASP_TOLERANCE = 0.02  # m of opening
HELD_DISTANCE = 0.03  # m, ball centre to TCP
START_SPEED_SCALE = 0.4  # share of the joints' velocity limits for the move to the start
START_TIMEOUT = 30.0  # s for the start move beyond its duration


@dataclass(frozen=True)
class Outcome:
    """How an episode ended: the log line's text and whether it reached its goal."""

    text: str
    reached: bool


@dataclass(frozen=True)
class Step:
    """One step to send: the joints due after ``duration`` s, and the gripper's new opening."""

    joints: np.ndarray
    duration: float
    gripper: float | None  # m (0: close, the full opening: open), None: unchanged


class Episode:
    """The state of one running episode (Reach or Pick) between its steps."""

    def __init__(self, picks: bool, target: np.ndarray, joints: np.ndarray, goal: np.ndarray,
                 radius: float, deadline: float) -> None:
        self.picks = picks
        self.target, self.joints = target, joints  # the commanded TCP target and its joints
        self.goal = goal  # Pick's goal (base_link); Reach's follows the ball each step
        self.radius = radius
        self.step = 0
        self.closed = False
        self.held_back = False  # the arm did not go to the last target
        self.pending = 0  # goals of the current step not yet finished
        self.started = time.monotonic()
        self.deadline = deadline  # monotonic time by which the pending goals must be done
        self._previous: np.ndarray | None = None  # the TCP at the last step
        self._ball: np.ndarray | None = None  # the ball at the last step
        self._held_at: np.ndarray | None = None  # ball - TCP while held
        self.unseen = 0  # steps since the camera last saw the ball

    def observe(self, arm: ArmKinematics, joints: np.ndarray, opening: float | None,
                ball: Callable[[], np.ndarray]) -> dict | Outcome:
        """Return the step's observation, or the Outcome when the episode ends here.

        ``ball`` returns the ball's centre in base_link from the latest sighting, or raises
        ValueError saying why there is none; ValueError also ends the episode (the caller
        reports it).
        """
        tcp = arm.tcp_pose(joints)[:3, 3]
        if self.held_back:  # on from where the arm is
            self.target, self.joints = tcp, joints
            self.held_back = False
        velocity = np.zeros(3) if self._previous is None else (tcp - self._previous) * CONTROL_RATE
        self._previous = tcp
        if self.picks:
            return self._pick(arm, tcp, velocity, opening, ball)
        return self._reach(tcp, velocity, ball() + (0.0, 0.0, self.radius))

    def act(self, action: np.ndarray, arm: ArmKinematics, joints: np.ndarray,
            velocity_limits: np.ndarray, open_width: float) -> Step:
        """Return the step the (clipped) ``action`` makes from the measured ``joints``."""
        action = np.clip(action, -1.0, 1.0)
        self.target, self.joints = move_target(arm, self.target, self.joints, action)
        self.step += 1
        gripper = None
        closed = self.picks and bool(action[3] < 0.0)
        if closed != self.closed:
            self.closed = closed
            gripper = 0.0 if closed else open_width
        return Step(self.joints, step_duration(joints, self.joints, velocity_limits), gripper)

    def _reach(self, tcp: np.ndarray, velocity: np.ndarray, goal: np.ndarray) -> dict | Outcome:
        distance = float(np.linalg.norm(tcp - goal))
        if distance < REACH_TOLERANCE:
            return Outcome(f'reached the ball: TCP {distance * 1000:.0f} mm from its top after '
                           f'{self.step} steps', True)
        if self.step >= EPISODE_STEPS[REACH_ID]:
            return Outcome(f'not reached after {self.step} steps: TCP {distance * 1000:.0f} mm '
                           'from the ball top', False)
        return reach_observation(tcp, velocity, goal)

    def _pick(self, arm: ArmKinematics, tcp: np.ndarray, velocity: np.ndarray,
              opening: float | None, sighting: Callable[[], np.ndarray]) -> dict | Outcome:
        if opening is None:
            raise ValueError('no RG2 finger joints in joint_states')
        gripping = self.closed and abs(opening - 2 * self.radius) < GRASP_TOLERANCE
        if not gripping:
            self._held_at = None
        if self._held_at is not None:
            # Held, the ball moves with the TCP; the fingers hide much of it from the camera,
            # whose estimate of what is left of it is worse than this.
            ball = tcp + self._held_at
        else:
            try:
                ball = sighting()
                self.unseen = 0
            except ValueError as error:
                self.unseen += 1
                if self._ball is None:
                    raise
                if self.unseen > LOST_STEPS:
                    raise ValueError(f'the ball is no longer seen: {self.unseen} steps without '
                                     f'it ({error})') from None
                ball = self._ball  # hidden by the arm: it lies where it was last seen
            if gripping and np.linalg.norm(ball - tcp) < HELD_DISTANCE:
                self._held_at = ball - tcp
        ball_velocity = (np.zeros(3) if self._ball is None
                         else (ball - self._ball) * CONTROL_RATE)
        self._ball = ball
        held = self._held_at is not None
        height = float(ball[2] - self.radius - arm.floor_z)  # its bottom above the floor
        lifted = held and height >= LIFT_SUCCESS
        at_goal = np.linalg.norm(ball - self.goal) < PICK_GOAL_TOLERANCE
        if (lifted and at_goal) or self.step >= EPISODE_STEPS[PICK_ID]:
            state = (f'held {height * 100:.1f} cm above the floor' if held else
                     f'not held, {height * 100:.1f} cm above the floor, gripper '
                     f'{opening * 1000:.0f} mm')
            return Outcome(f"{'picked' if lifted else 'missed'} the ball: {state} after "
                           f'{self.step} steps', lifted)
        return pick_observation(tcp, velocity, opening, ball, ball_velocity, self.goal)


def start_episode(picks: bool, arm: ArmKinematics, joints: np.ndarray, centre: np.ndarray,
                  radius: float, velocity_limits: np.ndarray) -> tuple[Episode, Trajectory]:
    """Return a new episode for the ball at ``centre`` (base_link) and the move to its start.

    The arm goes from ``joints`` to the environment's start pose (START_TCP in the pick
    posture). ValueError when the ball is out of reach from there: for Pick, when no grasp and
    lift can be planned; for Reach, when the TCP cannot be put on the ball's top.
    """
    start = np.array(START_TCP)
    start_q = start_joints(arm, start)
    try:
        if picks:
            plan_pick(arm, start_q, centre, APPROACH_HEIGHT, LIFT_GOAL)
        else:
            arm.solve(tcp_pose(centre + (0.0, 0.0, radius)), start_q)
    except KinematicsError as error:
        raise ValueError(f'the ball is out of reach: {error}') from None
    trajectory = plan_joint_move(joints, start_q, velocity_limits, START_SPEED_SCALE,
                                 1.0 / CONTROL_RATE)
    episode = Episode(picks, start, start_q, pick_goal(centre), radius,
                      time.monotonic() + trajectory.duration + START_TIMEOUT)
    return episode, trajectory
