"""Reach and Pick, the tasks of robot, task, env: the ball, the goal, reward and success.

Observations are dicts like Gymnasium-Robotics' Fetch tasks (``observation``,
``achieved_goal``, ``desired_goal``), every position in ``base_link``, metres. A task places
the ball at an episode's start (and, for Pick, may start it held or with the open fingers
over it), observes, rewards and judges each step; the robot (:mod:`ur_rg2_learning.robot`)
moves the arm.

The constants and the observation functions (:func:`reach_observation`,
:func:`pick_observation`, :func:`pick_goal`) are the environments' and the policy node's,
which runs them on the live graph: this module needs no simulator.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any

import numpy as np

from ur_rg2_learning.robot import CONTROL_RATE, UrRg2GrippingRobot, UrRg2Robot

BALL_RADIUS = 0.03  # m, the sim's default ball
REACH_TOLERANCE = 0.02  # m, TCP to the ball's top (the contract's)
LIFT_SUCCESS = 0.10  # m, the ball's bottom above the floor, held (the contract's)
LIFT_GOAL = 0.15  # m: Pick's goal is the ball this far above where it lay
# m, the distance Pick's sparse reward accepts: the ball's bottom is then 12 cm up or more, a
# margin over LIFT_SUCCESS that the camera's estimate of a held ball cannot eat up
PICK_GOAL_TOLERANCE = 0.03
# The ball lies on the floor in this ring sector of base_link (distance from the base axis,
# heading from x): in front of the default camera, in the UR5's reach (the UR3 reaches most).
BALL_DISTANCE = (0.35, 0.55)
BALL_HEADING = (math.radians(-80.0), math.radians(20.0))
# The TCP this far above the ball's centre grasps it low between the pads, as the motion
# node's pick does (the scripted demonstrator's grasp, and the grasped starts').
GRASP_HEIGHT = 0.003  # m
GRASP_GAP = 0.002  # m: a grasped start's fingers close from this far apart round the ball
# An over-ball start puts the open TCP up to this far above the grasp height (and up to
# OVER_BALL_JITTER off the ball's axis): the last part of the demonstrator's approach.
OVER_BALL_HEIGHT = 0.08  # m
OVER_BALL_JITTER = 0.01  # m
NEAR_BALL = 0.15  # m, ball centre to TCP: nearer, Pick steps the physics finely (a grasp)
# Where Pick's observation has the ball: its position, its offset from the TCP, its velocity.
BALL_SLICE, OFFSET_SLICE, BALL_VELOCITY_SLICE = slice(7, 10), slice(10, 13), slice(13, 16)


def reach_observation(tcp: np.ndarray, tcp_velocity: np.ndarray,
                      goal: np.ndarray) -> dict[str, np.ndarray]:
    """Return Reach's observation dict (base_link, m, m/s): the env's and the policy node's.

    The vectors may be arrays or sequences of floats (the environment's, every step).
    """
    return {
        'observation': np.array([*tcp, *tcp_velocity], dtype=np.float32),
        'achieved_goal': np.array(tcp, dtype=np.float32),
        'desired_goal': np.asarray(goal, dtype=np.float32),
    }


def pick_observation(tcp: np.ndarray, tcp_velocity: np.ndarray, opening: float,
                     ball: np.ndarray, ball_velocity: np.ndarray,
                     goal: np.ndarray) -> dict[str, np.ndarray]:
    """Return Pick's observation dict (base_link, m, m/s): the env's and the policy node's.

    The vectors may be arrays or sequences of floats (the environment's, every step).
    """
    offset = [b - t for b, t in zip(ball, tcp)]  # the ball relative to the TCP
    return {
        'observation': np.array([*tcp, *tcp_velocity, opening, *ball, *offset, *ball_velocity],
                                dtype=np.float32),
        'achieved_goal': np.array(ball, dtype=np.float32),
        'desired_goal': np.asarray(goal, dtype=np.float32),
    }


def pick_goal(ball: np.ndarray) -> np.ndarray:
    """Return Pick's goal for a ball lying with its centre at ``ball`` (base_link)."""
    return np.asarray(ball, dtype=float) + (0.0, 0.0, LIFT_GOAL)


def _length(vector: np.ndarray) -> float:
    """Return np.linalg.norm(vector) of a 1-D float array, without its checks (every step)."""
    return math.sqrt(vector.dot(vector))  # the norm's own computation, sqrt of the dot product


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return np.linalg.norm(a - b, axis=-1) computed as it does, without its checks."""
    difference = np.subtract(a, b)
    return np.sqrt(np.add.reduce(difference * difference, axis=-1))


class Task:
    """What a task defines (panda-gym's Task, on a UR with the RG2 and a ball on the floor).

    The environment calls, per episode, :meth:`sample_ball`, :meth:`reset` (after the
    robot's), :meth:`observe` and :meth:`is_success`, then :meth:`alter_start`; per step
    :meth:`object_near` (before the robot's step), :meth:`observe`, :meth:`is_success` and
    :meth:`compute_reward`.
    """

    observation_size = 0  # the length of ``observation``
    goal_size = 3  # the length of ``achieved_goal`` and ``desired_goal``

    def __init__(self, robot: UrRg2Robot) -> None:
        self.robot = robot
        self.world = robot.world
        self.goal = np.zeros(3)

    def sample_ball(self, rng: np.random.Generator,
                    given: Sequence[float] | None = None) -> np.ndarray:
        """Return the centre (base_link) of a ball lying on the floor for an episode.

        Somewhere in BALL_DISTANCE and BALL_HEADING; ``given`` (x, y, or x, y, z) replaces
        that. The draws are made either way: a seed places the rest of the episode alike.
        """
        distance, heading = rng.uniform(*BALL_DISTANCE), rng.uniform(*BALL_HEADING)
        ball = np.array([distance * math.cos(heading), distance * math.sin(heading),
                         BALL_RADIUS - self.robot.base[2]])
        given = np.asarray(ball[:2] if given is None else given, dtype=float)
        ball[:len(given)] = given
        return ball

    def reset(self, ball: np.ndarray) -> None:
        """Put the ball's centre at ``ball`` (base_link), at rest, and set the goal."""
        self.world.set_ball_position((ball + self.robot.base).tolist())

    def alter_start(self, rng: np.random.Generator, options: dict[str, Any]) -> bool:
        """Change the start :meth:`reset` made, or not; return whether it did."""
        return False

    def object_near(self) -> bool:
        """Return whether the task's object is near the TCP (before a step)."""
        return False

    def observe(self) -> dict[str, np.ndarray]:
        """Return the step's observation dict."""
        raise NotImplementedError

    def is_success(self) -> bool:
        """Return whether the task is done now."""
        raise NotImplementedError

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return the reward of goals (..., 3) and their infos; vectorised, for HER."""
        raise NotImplementedError


class Reach(Task):
    """Bring ``rg2_tcp`` to the top of the ball, the gripper pointing down.

    observation: TCP position and velocity (6); achieved goal: the TCP; desired goal: the
    ball's top. Reward: minus the distance (m). The arm passes through the ball (it is the
    target, as Fetch's goal marker is), so the goal stays where the episode put it.
    """

    observation_size = 6

    def reset(self, ball: np.ndarray) -> None:
        """Put the ball at ``ball`` for the arm to pass through; the goal is its top."""
        super().reset(ball)
        self.world.set_robot_collisions(self.world.ball, False)
        self.goal = ball + (0.0, 0.0, BALL_RADIUS)

    def observe(self) -> dict[str, np.ndarray]:
        """Return the TCP, its velocity and the ball's top."""
        return reach_observation(self.robot.tcp, self.robot.tcp_velocity, self.goal)

    def is_success(self) -> bool:
        """Return whether the TCP is within REACH_TOLERANCE of the ball's top."""
        return _length(np.subtract(self.robot.tcp, self.goal)) < REACH_TOLERANCE

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return minus the distance (m) from the TCP to the ball's top."""
        return -_distances(achieved_goal, desired_goal)


class Pick(Task):
    """Grasp the ball and lift it.

    observation: TCP position and velocity, gripper opening, ball position, ball relative to
    the TCP, ball velocity (16); achieved goal: the ball's centre; desired goal: the ball's
    centre LIFT_GOAL above where it lay. Reward: 0 within PICK_GOAL_TOLERANCE of the goal,
    else -1 (sparse, as Fetch's pick). Success: the ball's bottom LIFT_SUCCESS above the
    floor, held between the closed fingers.

    ``grasped_share`` of the episodes (none reset with options) start with the ball between
    the closed fingers, somewhere between the floor and the goal above where it lay (Fetch's
    trick: the lift is then met early in training), and ``over_ball_share`` with the open
    fingers round or over the ball lying on the floor (the grasp is then met early).
    """

    observation_size = 16

    def __init__(self, robot: UrRg2GrippingRobot, grasped_share: float = 0.0,
                 over_ball_share: float = 0.0) -> None:
        super().__init__(robot)
        self.robot: UrRg2GrippingRobot = robot
        self.grasped_share = grasped_share
        self.over_ball_share = over_ball_share
        # The ball's centre (base_link) and velocity at the last observation, plain floats.
        self.ball = [0.0, 0.0, 0.0]
        self.ball_velocity = [0.0, 0.0, 0.0]

    def reset(self, ball: np.ndarray) -> None:
        """Put the ball at ``ball``; the goal is LIFT_GOAL above it."""
        super().reset(ball)
        self.ball = ball.tolist()
        self.goal = pick_goal(ball)

    def alter_start(self, rng: np.random.Generator, options: dict[str, Any]) -> bool:
        """Start grasped or over the ball by the shares (no options), or by options.

        Options ``grasped`` and ``over_ball`` (bool) choose by hand.
        """
        draw = None if options else rng.uniform()
        if options.get('grasped', draw is not None and draw < self.grasped_share):
            self._start_grasped(rng)
            return True
        if options.get('over_ball', draw is not None
                       and draw < self.grasped_share + self.over_ball_share):
            self._start_over_ball(rng)
            return True
        return False

    def _start_over_ball(self, rng: np.random.Generator) -> None:
        """Put the open TCP 0 to OVER_BALL_HEIGHT above the grasp height over the ball."""
        tcp = np.add(self.ball, (0.0, 0.0, GRASP_HEIGHT + rng.uniform(0.0, OVER_BALL_HEIGHT)))
        tcp[:2] += rng.uniform(-OVER_BALL_JITTER, OVER_BALL_JITTER, 2)
        self.robot.place(tcp)

    def _start_grasped(self, rng: np.random.Generator) -> None:
        """Put the ball (and the TCP over its centre) up to LIFT_GOAL up, the RG2 closed on it."""
        ball = self.goal - (0.0, 0.0, LIFT_GOAL)
        ball[2] += rng.uniform(0.0, LIFT_GOAL)
        world_ball = (ball + self.robot.base).tolist()
        self.robot.close_on(ball + (0.0, 0.0, GRASP_HEIGHT), 2 * BALL_RADIUS + GRASP_GAP,
                            lambda: self.world.set_ball_position(world_ball))
        self.ball = self._ball_position()

    def object_near(self) -> bool:
        """Return whether the ball's centre is within NEAR_BALL of the TCP (a grasp may come)."""
        return _length(np.subtract(self.ball, self.robot.tcp)) < NEAR_BALL

    def observe(self) -> dict[str, np.ndarray]:
        """Return the TCP, its velocity, the opening and the ball; measure the ball first."""
        # Once per step (and at the reset, where the ball lies still where it was put).
        ball = self._ball_position()
        self.ball_velocity = [(a - b) * CONTROL_RATE for a, b in zip(ball, self.ball)]
        self.ball = ball
        robot = self.robot
        return pick_observation(robot.tcp, robot.tcp_velocity, self.world.gripper_opening(),
                                self.ball, self.ball_velocity, self.goal)

    def _ball_position(self) -> list[float]:
        """Return the ball's centre in base_link (m) now, plain floats."""
        return [p - b for p, b in zip(self.world.body_position(self.world.ball), self.robot.base)]

    def is_success(self) -> bool:
        """Return whether the ball's bottom is LIFT_SUCCESS above the floor, held."""
        bottom = self.ball[2] - BALL_RADIUS + self.robot.base[2]  # above the floor (z = 0)
        return bool(bottom >= LIFT_SUCCESS and self.world.gripper_holds_object())

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return 0 where the ball is within PICK_GOAL_TOLERANCE of the goal, else -1."""
        return -(_distances(achieved_goal, desired_goal) > PICK_GOAL_TOLERANCE).astype(np.float32)
