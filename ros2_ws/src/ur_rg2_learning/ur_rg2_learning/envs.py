"""The goal-conditioned Gymnasium environments: a robot doing a task on the sim's world. No ROS.

``UrRg2Reach-v0`` and ``UrRg2Pick-v0`` (registered by the package's ``__init__``) are
panda-gym's split: a :class:`UrRg2Env` runs :class:`ur_rg2_sim.world.SimWorld` (the physics
the ``sim`` node runs, without its camera) with a robot of :mod:`ur_rg2_learning.robot` (the
arm and the RG2, moved as the ``motion`` node moves them) doing a task of
:mod:`ur_rg2_learning.tasks` (the ball, the goal, reward and success). :class:`BallNoise`
observes Pick's ball as a camera sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import gymnasium as gym
from gymnasium import spaces
import numpy as np

from ur_rg2_learning.robot import CONTROL_RATE, UrRg2GrippingRobot, UrRg2Robot
from ur_rg2_learning.tasks import (
    BALL_RADIUS,
    BALL_SLICE,
    BALL_VELOCITY_SLICE,
    OFFSET_SLICE,
    Pick,
    Reach,
    Task,
)

if TYPE_CHECKING:
    from ur_rg2_sim.world import SimWorld

OBSERVATION_BOUND = 10.0  # m, m/s
# m, per axis: the standard deviation of Gaussian noise on the ball's position that matches the
# vision node's 3D error at its tail: p95 2.80 sigma = 3.6 mm (the learned detector's 3.57 mm on
# `python -m bench detector`'s hard set, 3.37 mm on plain balls), median 1.54 sigma = 2.0 mm
# (vision's is 1.03 mm: the noise is at least vision's at both).
VISION_BALL_NOISE = 0.0013


def _vector(size: int) -> spaces.Box:
    # Positions (m) and velocities (m/s) in base_link, well beyond what the arm reaches.
    return spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (size,), dtype=np.float32)


def _world(robot_model: str, substeps: int) -> SimWorld:
    """Return a world for a robot stepping its physics ``substeps`` times per action."""
    # Imported here: pybullet prints its build line on import, which would come before a
    # command's one-line usage error (evaluate_policy, train_policy).
    from ur_rg2_sim.world import SimWorld, WorldConfig

    return SimWorld(WorldConfig(robot_model=robot_model, ball_radius=BALL_RADIUS,
                                physics_rate=CONTROL_RATE * substeps))


class UrRg2Env(gym.Env):
    """A robot doing a task, as panda-gym's RobotTaskEnv: the Gymnasium API round them.

    ``world`` and ``arm`` (its kinematics) are the robot's. Pickling keeps the settings, not
    the state: a copy is a fresh environment (reset it), which is what vectorised and
    distributed trainers need to start one world per process.
    """

    metadata = {'render_modes': []}

    def __init__(self, robot: UrRg2Robot, task: Task, settings: dict[str, Any]) -> None:
        self._settings = settings
        self.robot, self.task = robot, task
        self.world, self.arm = robot.world, robot.arm
        self.observation_space = spaces.Dict({
            'observation': _vector(task.observation_size),
            'achieved_goal': _vector(task.goal_size),
            'desired_goal': _vector(task.goal_size),
        })
        self.action_space = spaces.Box(-1.0, 1.0, (robot.action_size,), dtype=np.float32)

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start an episode: ball somewhere on the floor, TCP near START_TCP, gripper open.

        ``options`` may place them by hand (base_link, m): ``ball_position`` (x, y, or x, y,
        z for the ball's centre) and ``tcp_position`` (x, y, z); the task may then change
        the start (:meth:`ur_rg2_learning.tasks.Pick.alter_start`).
        """
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        ball = self.task.sample_ball(rng, options.get('ball_position'))
        start = self.robot.sample_start(rng)  # drawn with a tcp_position too
        self.robot.reset(np.asarray(options.get('tcp_position', start), dtype=float))
        self.task.reset(ball)
        observation, info = self.task.observe(), {'is_success': self.task.is_success()}
        if self.task.alter_start(rng, options):
            observation, info = self.task.observe(), {'is_success': self.task.is_success()}
        return observation, info

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Move the TCP (and the gripper), run the physics for 1 / CONTROL_RATE s."""
        # Clipped as np.clip does (min of max), in plain floats.
        action = [min(max(a, -1.0), 1.0) for a in np.asarray(action, dtype=float).tolist()]
        self.robot.step(action, self.task.object_near())
        observation = self.task.observe()
        info = {'is_success': self.task.is_success()}
        reward = float(self.task.compute_reward(observation['achieved_goal'],
                                                observation['desired_goal'], info))
        return observation, reward, False, False, info

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return the reward of goals (..., 3) and their infos; vectorised, for HER."""
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    def close(self) -> None:
        """Disconnect the physics world."""
        if self.world.client is not None:
            self.world.close()

    def __getstate__(self) -> dict[str, Any]:
        return dict(self._settings)

    def __setstate__(self, settings: dict[str, Any]) -> None:
        self.__init__(**settings)


class ReachEnv(UrRg2Env):
    """``UrRg2Reach-v0``: the arm brings ``rg2_tcp`` to the ball's top (:class:`Reach`)."""

    def __init__(self, robot_model: str = 'ur5') -> None:
        robot = UrRg2Robot(_world(robot_model, UrRg2Robot.substeps))
        super().__init__(robot, Reach(robot), {'robot_model': robot_model})


class PickEnv(UrRg2Env):
    """``UrRg2Pick-v0``: the arm and the RG2 grasp the ball and lift it (:class:`Pick`).

    ``grasped_share`` and ``over_ball_share`` of the episodes start with the ball held or
    the open fingers over it (see :class:`Pick`).
    """

    def __init__(self, robot_model: str = 'ur5', grasped_share: float = 0.0,
                 over_ball_share: float = 0.0) -> None:
        robot = UrRg2GrippingRobot(_world(robot_model, UrRg2GrippingRobot.substeps))
        super().__init__(robot, Pick(robot, grasped_share, over_ball_share),
                         {'robot_model': robot_model, 'grasped_share': grasped_share,
                          'over_ball_share': over_ball_share})


class BallNoise(gym.Wrapper):
    """Pick with the ball observed as a camera sees it: its true position plus Gaussian noise.

    Each step draws fresh noise of ``std`` (m) per axis, independent of the last (the camera
    sees each frame anew), and everything the policy reads of the ball comes from that noisy
    position, as the policy node builds it from vision's estimate: the ball's position, its
    offset from the TCP, its velocity (the difference of the last two noisy positions) and
    ``achieved_goal``; ``desired_goal`` is offset by the reset's noise (the node sets the goal
    from its first sighting). Rewards and success stay the true ones. The noise repeats under
    a reset's seed and draws nothing from the environment's own generator, so a seed places
    the ball and the TCP as without noise.
    """

    def __init__(self, env: gym.Env, std: float) -> None:
        super().__init__(env)
        if std < 0:
            raise ValueError(f'the noise must not be negative, not {std}')
        self.std = std
        self._rng = np.random.default_rng()
        self._seen = np.zeros(3)
        self._goal_offset = np.zeros(3)

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Reset the environment, then observe its ball with noise (seeded by ``seed``)."""
        observation, info = self.env.reset(seed=seed, options=options)
        if seed is not None:
            self._rng = np.random.default_rng([seed, 0xBA11])
        self._goal_offset = self._rng.normal(0.0, self.std, 3)
        self._seen = observation['achieved_goal'] + self._goal_offset
        return self._noisy(observation, self._seen, np.zeros(3)), info

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Step the environment; its observation with the ball seen with fresh noise."""
        observation, reward, terminated, truncated, info = self.env.step(action)
        seen = observation['achieved_goal'] + self._rng.normal(0.0, self.std, 3)
        velocity = (seen - self._seen) * CONTROL_RATE
        self._seen = seen
        return self._noisy(observation, seen, velocity), reward, terminated, truncated, info

    def _noisy(self, observation: dict, seen: np.ndarray, velocity: np.ndarray) -> dict:
        state = observation['observation'].astype(np.float64)
        state[BALL_SLICE] = seen
        state[OFFSET_SLICE] = seen - state[:3]
        state[BALL_VELOCITY_SLICE] = velocity
        return {'observation': state.astype(np.float32),
                'achieved_goal': seen.astype(np.float32),
                'desired_goal': (observation['desired_goal'] + self._goal_offset)
                .astype(np.float32)}


def make(env_id: str, ball_noise: float = 0.0, **kwargs: Any) -> gym.Env:
    """Return ``gym.make(env_id, **kwargs)``, with :class:`BallNoise` when ``ball_noise`` > 0."""
    env = gym.make(env_id, **kwargs)
    if not ball_noise:
        return env
    if not isinstance(env.unwrapped, PickEnv):
        raise ValueError(f'ball noise is for Pick, not {env_id}')
    return BallNoise(env, ball_noise)
