"""Goal-conditioned Gymnasium environments on the sim's world core. No ROS.

``UrRg2Reach-v0`` and ``UrRg2Pick-v0`` run :class:`ur_rg2_sim.world.SimWorld` (the physics the
``sim`` node runs, without its camera) and move the arm the way the ``motion`` node does:
closed-form UR inverse kinematics (:class:`ur_rg2_motion.kinematics.ArmKinematics`, with its
floor and pedestal checks) turns a TCP target into joint targets.

Observations are dicts like Gymnasium-Robotics' Fetch tasks (``observation``,
``achieved_goal``, ``desired_goal``), every position in ``base_link``, metres. An action moves
``rg2_tcp``'s target by up to ``MAX_STEP`` along each ``base_link`` axis, the gripper pointing
straight down; Pick's fourth component closes (< 0) or opens (>= 0) the RG2.

Speed: one step is one inverse kinematics solution, one joint command with the joint
velocities fed forward (the sim's trajectory controller feeds them forward too, so the arm
tracks within millimetres despite the long physics steps) and ``substeps`` physics steps.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
from gymnasium import spaces
import numpy as np
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_motion.kinematics import (
    FLOOR_CLEARANCE,
    ArmKinematics,
    KinematicsError,
    arm_on_pedestal,
)
from ur_rg2_motion.planning import PICK_POSTURE, gripper_down, plan_joint_move

CONTROL_RATE = 10.0  # Hz: one action per 0.1 s of simulation time
MAX_STEP = 0.05  # m of TCP motion per step and axis at |action| = 1 (0.5 m/s)
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
# Each episode starts with the TCP here (base_link), jittered by up to START_JITTER per axis.
START_TCP = (0.4, -0.15, 0.1)
START_JITTER = 0.05
# TCP targets stay in this box (base_link); below it the fingers would touch the floor.
TARGET_LOW = (-0.8, -0.8, None)
TARGET_HIGH = (0.8, 0.8, 0.4)
OBSERVATION_BOUND = 10.0  # m, m/s
GRIPPER_TIMEOUT = 1.5  # s: the RG2 closes its full 110 mm in under 1 s
# The TCP this far above the ball's centre grasps it low between the pads, as the motion
# node's pick does (the scripted demonstrator's grasp, and the grasped starts').
GRASP_HEIGHT = 0.003  # m
GRASP_GAP = 0.002  # m: a grasped start's fingers close from this far apart round the ball
# An over-ball start puts the open TCP up to this far above the grasp height (and up to
# OVER_BALL_JITTER off the ball's axis): the last part of the demonstrator's approach.
OVER_BALL_HEIGHT = 0.08  # m
OVER_BALL_JITTER = 0.01  # m
NEAR_BALL = 0.15  # m, ball centre to TCP: nearer, Pick steps the physics finely (a grasp)
# m, per axis: the standard deviation of Gaussian noise on the ball's position that matches the
# vision node's 3D error at its tail: p95 2.80 sigma = 3.6 mm (the learned detector's 3.57 mm on
# `python -m bench detector`'s hard set, 3.37 mm on plain balls), median 1.54 sigma = 2.0 mm
# (vision's is 1.03 mm: the noise is at least vision's at both).
VISION_BALL_NOISE = 0.0013
# Where Pick's observation has the ball: its position, its offset from the TCP, its velocity.
BALL_SLICE, OFFSET_SLICE, BALL_VELOCITY_SLICE = slice(7, 10), slice(10, 13), slice(13, 16)


_DOWN = gripper_down((0.0, 0.0, 0.0), 0.0)


def target_bounds(arm: ArmKinematics) -> tuple[np.ndarray, np.ndarray]:
    """Return the box (base_link) that TCP targets are clipped to, low and high corners."""
    low, high = _target_box(arm)
    return np.array(low), np.array(high)


def _target_box(arm: ArmKinematics) -> tuple[tuple[float, ...], tuple[float, ...]]:
    lowest = arm.floor_z + arm.finger_length + 2 * FLOOR_CLEARANCE
    return TARGET_LOW[:2] + (lowest,), TARGET_HIGH


def tcp_pose(position: np.ndarray) -> np.ndarray:
    """Return the TCP pose (base_link) at ``position``, pointing down: every step's target."""
    pose = _DOWN.copy()
    pose[:3, 3] = position
    return pose


def move_target(arm: ArmKinematics, target: np.ndarray, joints: np.ndarray,
                action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return one step's TCP target and the joints that reach it: the env's and the node's.

    The target moves by ``MAX_STEP`` times the action's first three components from
    ``target`` (clipped to :func:`target_bounds`); inverse kinematics starts from ``joints``.
    Where no joints reach it (pedestal, reach), ``target`` and ``joints`` are kept: the arm
    holds its target.
    """
    # In plain floats, the operations numpy would do elementwise (np.clip is min of max): on
    # 3-vectors, once every step of the environments, numpy's overhead is most of the cost.
    moved = np.array([min(max(t + MAX_STEP * float(a), lo), hi) for t, a, lo, hi in zip(
        np.asarray(target, dtype=float).tolist(), action[:3], *_target_box(arm))])
    try:
        return moved, arm.solve(tcp_pose(moved), joints)
    except KinematicsError:
        return target, joints


def step_duration(current: np.ndarray, goal: np.ndarray,
                  velocity_limits: np.ndarray) -> float:
    """Return the time (s) from the step's start at which the joints should be at ``goal``.

    One control period, stretched when a joint would need more than its velocity limit to
    get from ``current`` there in it: the trajectory controller refuses such a goal instead
    of slowing it down, and near the edge of the workspace one step of a few centimetres can
    turn the shoulder that fast. (The environment's joint motors cap the speed instead.)
    """
    return plan_joint_move(current, goal, velocity_limits, 1.0, 1.0 / CONTROL_RATE).duration


def start_joints(arm: ArmKinematics, position: np.ndarray) -> np.ndarray:
    """Return the joints with the TCP at ``position`` in the pick posture (KinematicsError)."""
    posture = np.array([math.atan2(position[1], position[0]), *PICK_POSTURE, 0.0])
    return arm.solve(tcp_pose(position), posture)


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


def _vector(size: int) -> spaces.Box:
    # Positions (m) and velocities (m/s) in base_link, well beyond what the arm reaches.
    return spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, (size,), dtype=np.float32)


class UrRg2Env(gym.Env):
    """The common part: world, kinematics, TCP moves, goal-conditioned observations.

    Pickling keeps the settings, not the state: a copy is a fresh environment (reset it), which
    is what vectorised and distributed trainers need to start one world per process.
    """

    metadata = {'render_modes': []}
    substeps = 1  # physics steps per action
    gripper_action = False

    def __init__(self, robot_model: str = 'ur5') -> None:
        # Imported here: the policy node uses this module's task (the constants and functions
        # above) on a live graph, where no simulator need be installed.
        from ur_rg2_sim.world import SimWorld, WorldConfig

        self._settings = {'robot_model': robot_model}
        self.world = SimWorld(WorldConfig(robot_model=robot_model, ball_radius=BALL_RADIUS,
                                          physics_rate=CONTROL_RATE * self.substeps))
        height = self.world.pedestal_height
        self._base = np.array([0.0, 0.0, height])  # base_link in the world frame
        self._base_xyz = self._base.tolist()
        self.arm = arm_on_pedestal(self.world.urdf.read_text(), height)
        observation, goal = self._sizes()
        self.observation_space = spaces.Dict({
            'observation': _vector(observation),
            'achieved_goal': _vector(goal),
            'desired_goal': _vector(goal),
        })
        self.action_space = spaces.Box(-1.0, 1.0, (4 if self.gripper_action else 3,),
                                       dtype=np.float32)
        # The step's state. Measured vectors are plain floats: every step computes them, and
        # numpy's overhead on 3-vectors would be most of their cost.
        self._joints = np.zeros(len(ARM_JOINTS))
        self._tcp = [0.0, 0.0, 0.0]
        self._target = np.zeros(3)  # the commanded TCP position
        self._tcp_velocity = [0.0, 0.0, 0.0]
        self._goal = np.zeros(3)

    # -- what the tasks define ----------------------------------------------------------------

    def _sizes(self) -> tuple[int, int]:
        raise NotImplementedError

    def _observe(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def _is_success(self) -> bool:
        raise NotImplementedError

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return the reward of goals (..., 3) and their infos; vectorised, for HER."""
        raise NotImplementedError

    # -- Gymnasium API ------------------------------------------------------------------------

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start an episode: ball somewhere on the floor, TCP near START_TCP, gripper open.

        ``options`` may place them by hand (base_link, m): ``ball_position`` (x, y, or x, y,
        z for the ball's centre) and ``tcp_position`` (x, y, z).
        """
        super().reset(seed=seed)
        options = options or {}
        rng = self.np_random
        distance, heading = rng.uniform(*BALL_DISTANCE), rng.uniform(*BALL_HEADING)
        start = np.add(START_TCP, rng.uniform(-START_JITTER, START_JITTER, 3))
        ball = np.array([distance * math.cos(heading), distance * math.sin(heading),
                         BALL_RADIUS - self._base[2]])
        given = np.asarray(options.get('ball_position', ball[:2]), dtype=float)
        ball[:len(given)] = given
        start = np.asarray(options.get('tcp_position', start), dtype=float)
        try:
            joints = start_joints(self.arm, start)
        except KinematicsError as error:
            raise ValueError(f'tcp_position {start.tolist()} is out of reach: {error}') from None
        self.world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        self.world.reset_gripper()
        self.world.set_ball_position((ball + self._base).tolist())
        self._joints = joints
        self._target = start
        self._tcp = self._tcp_position()
        self._tcp_velocity = [0.0, 0.0, 0.0]
        self._start_episode(ball)
        return self._observe(), {'is_success': self._is_success()}

    def _start_episode(self, ball: np.ndarray) -> None:
        """Set the task's goal from the ball's starting centre (base_link)."""
        raise NotImplementedError

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        """Move the TCP (and the gripper), run the physics for 1 / CONTROL_RATE s."""
        # Clipped as np.clip does (min of max), in plain floats.
        action = [min(max(a, -1.0), 1.0) for a in np.asarray(action, dtype=float).tolist()]
        previous = self._joints
        self._command(action)
        self._move_arm(previous, self._joints)
        tcp = self._tcp_position()
        self._tcp_velocity = [(a - b) * CONTROL_RATE for a, b in zip(tcp, self._tcp)]
        self._tcp = tcp
        observation = self._observe()
        info = {'is_success': self._is_success()}
        reward = float(self.compute_reward(observation['achieved_goal'],
                                           observation['desired_goal'], info))
        return observation, reward, False, False, info

    def _tcp_position(self) -> list[float]:
        """Return the TCP's position in base_link (m) now, plain floats."""
        return [p - b for p, b in zip(self.world.link_pose()[0], self._base_xyz)]

    def _command(self, action: list[float]) -> None:
        # From the last commanded target, not the measured TCP: a zero action then holds the
        # arm still instead of letting it creep after its own tracking error.
        self._target, self._joints = move_target(self.arm, self._target, self._joints, action)

    def _move_arm(self, previous: np.ndarray, joints: np.ndarray) -> None:
        """Take the arm from the last step's joint targets to this one's in one control period.

        Here in one physics step: the speed that takes the last target to this one in one step
        is fed forward, as the trajectory controller feeds its path's speed.
        """
        # Inside the joint limits already (the inverse kinematics keeps to them): one call.
        q = joints.tolist()
        self.world.drive_arm(q, [(a - b) * CONTROL_RATE for a, b in zip(q, previous.tolist())])
        for _ in range(self.substeps):
            self.world.step()

    def close(self) -> None:
        """Disconnect the physics world."""
        if self.world.client is not None:
            self.world.close()

    def __getstate__(self) -> dict[str, Any]:
        return dict(self._settings)

    def __setstate__(self, settings: dict[str, Any]) -> None:
        self.__init__(**settings)


class ReachEnv(UrRg2Env):
    """Bring ``rg2_tcp`` to the top of the ball, the gripper pointing down.

    observation: TCP position and velocity (6); achieved goal: the TCP; desired goal: the
    ball's top. Reward: minus the distance (m). The arm passes through the ball (it is the
    target, as Fetch's goal marker is), so the goal stays where the episode put it.
    """

    def _sizes(self) -> tuple[int, int]:
        return 6, 3

    def _start_episode(self, ball: np.ndarray) -> None:
        self.world.set_robot_collisions(self.world.ball, False)
        self._goal = ball + (0.0, 0.0, BALL_RADIUS)

    def _observe(self) -> dict[str, np.ndarray]:
        return reach_observation(self._tcp, self._tcp_velocity, self._goal)

    def _is_success(self) -> bool:
        return _length(np.subtract(self._tcp, self._goal)) < REACH_TOLERANCE

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return minus the distance (m) from the TCP to the ball's top."""
        return -_distances(achieved_goal, desired_goal)


class PickEnv(UrRg2Env):
    """Grasp the ball and lift it.

    observation: TCP position and velocity, gripper opening, ball position, ball relative to
    the TCP, ball velocity (16); achieved goal: the ball's centre; desired goal: the ball's
    centre LIFT_GOAL above where it lay. Reward: 0 within PICK_GOAL_TOLERANCE of the goal,
    else -1 (sparse, as Fetch's pick). Success: the ball's bottom LIFT_SUCCESS above the
    floor, held between the closed fingers.
    """

    # Grasps need shorter physics steps than free arm motion: 80 Hz holds the ball. Where no
    # grasp can happen (the RG2 open, the ball further than NEAR_BALL from the TCP) 40 Hz
    # moves the arm as well, for half the physics.
    substeps = 8
    free_substeps = 4
    gripper_action = True

    def _sizes(self) -> tuple[int, int]:
        return 16, 3

    def __init__(self, robot_model: str = 'ur5', grasped_share: float = 0.0,
                 over_ball_share: float = 0.0) -> None:
        super().__init__(robot_model)
        self._settings['grasped_share'] = self.grasped_share = grasped_share
        self._settings['over_ball_share'] = self.over_ball_share = over_ball_share
        # The cubic's position and speed factors at the ends of a step's substeps (columns).
        fractions = {n: np.arange(1, n + 1) / n for n in (self.substeps, self.free_substeps)}
        self._cubics = {n: ((s * s * (3.0 - 2.0 * s))[:, None],
                            (6.0 * s * (1.0 - s) * CONTROL_RATE)[:, None])
                        for n, s in fractions.items()}
        self._rate_substeps = self.substeps  # the world's physics rate, in substeps per step
        limits = [self.world.limits[name] for name in ARM_JOINTS]
        self._lower = np.array([limit.lower for limit in limits])
        self._upper = np.array([limit.upper for limit in limits])

    def _start_episode(self, ball: np.ndarray) -> None:
        self._closed = False
        self._ball = ball.tolist()
        self._goal = pick_goal(ball)

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        """Start an episode (see :meth:`UrRg2Env.reset`); some with the ball already held.

        ``grasped_share`` of the episodes (none with ``options``) start with the ball between
        the closed fingers, somewhere between the floor and the goal above where it lay
        (Fetch's trick: the lift is then met early in training), and ``over_ball_share`` with
        the open fingers round or over the ball lying on the floor (the grasp is then met
        early). Options ``grasped`` and ``over_ball`` (bool) choose by hand.
        """
        observation, info = super().reset(seed=seed, options=options)
        options = options or {}
        draw = None if options else self.np_random.uniform()
        if options.get('grasped', draw is not None and draw < self.grasped_share):
            self._start_grasped()
            observation, info = self._observe(), {'is_success': self._is_success()}
        elif options.get('over_ball', draw is not None
                         and draw < self.grasped_share + self.over_ball_share):
            self._start_over_ball()
            observation, info = self._observe(), {'is_success': self._is_success()}
        return observation, info

    def _start_over_ball(self) -> None:
        """Put the open TCP 0 to OVER_BALL_HEIGHT above the grasp height over the ball."""
        rng = self.np_random
        tcp = np.add(self._ball, (0.0, 0.0, GRASP_HEIGHT + rng.uniform(0.0, OVER_BALL_HEIGHT)))
        tcp[:2] += rng.uniform(-OVER_BALL_JITTER, OVER_BALL_JITTER, 2)
        joints = start_joints(self.arm, tcp)
        self.world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        self._joints, self._target = joints, tcp
        self._tcp = self._tcp_position()

    def _start_grasped(self) -> None:
        """Put the ball (and the TCP over its centre) up to LIFT_GOAL up, the RG2 closed on it."""
        ball = self._goal - (0.0, 0.0, LIFT_GOAL)
        ball[2] += self.np_random.uniform(0.0, LIFT_GOAL)
        tcp = ball + (0.0, 0.0, GRASP_HEIGHT)
        joints = start_joints(self.arm, tcp)
        world = self.world
        self._use_substeps(self.substeps)
        world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        world.set_gripper_opening(2 * BALL_RADIUS + GRASP_GAP)
        world.set_ball_position((ball + self._base).tolist())
        world.close_gripper()
        self._closed = True
        for _ in range(round(GRIPPER_TIMEOUT * CONTROL_RATE * self.substeps)):
            world.step()
            if world.gripper_stopped():
                break
        self._joints, self._target = joints, tcp
        self._tcp = self._tcp_position()
        self._ball = self._ball_position()

    def _command(self, action: list[float]) -> None:
        closed = action[3] < 0.0
        self._gripper_moved = closed != self._closed
        if self._gripper_moved:
            if closed:
                self.world.close_gripper()
            else:
                self.world.open_gripper()
            self._closed = closed
        super()._command(action)

    def _move_arm(self, previous: np.ndarray, joints: np.ndarray) -> None:
        """Move along a cubic from rest at the last target to rest at this one, as in the graph.

        The policy node sends each step as a one-point goal, which the trajectory controller
        runs as a cubic ending at rest on the point. Ending every step at rest also keeps the
        TCP where the policy sent it: fed the speed forward and left to run on (Reach's way),
        the arm overshot a fast descent by up to 2 cm, closing the fingers over the ball's top.
        """
        near = self._closed or _length(np.subtract(self._ball, self._tcp)) < NEAR_BALL
        self._use_substeps(self.substeps if near else self.free_substeps)
        # The whole cubic at once (one NumPy computation, clamped to the joint limits once).
        ramp, speed = self._cubics[self._rate_substeps]
        move = joints - previous
        positions = np.clip(previous + ramp * move, self._lower, self._upper).tolist()
        velocities = (speed * move).tolist()
        world = self.world
        for position, velocity in zip(positions, velocities):
            world.drive_arm(position, velocity)
            world.step()
        if self._gripper_moved and not world.skip_free_finger_travel():
            # A step that opens or closes the RG2 lasts until its fingers stop (on the ball,
            # or at the end of their travel), as a gripper action's result comes then: the
            # policy node waits for it too. So no step's observation is of fingers half-way,
            # and a policy needs no waiting of its own for the grasp. Fingers that nothing can
            # be in the way of get there at once (the same end, without 100 physics steps).
            for _ in range(round(GRIPPER_TIMEOUT / world.dt)):
                world.step()
                if world.gripper_stopped():
                    break

    def _use_substeps(self, substeps: int) -> None:
        if substeps != self._rate_substeps:
            self.world.set_physics_rate(CONTROL_RATE * substeps)
            self._rate_substeps = substeps

    def _observe(self) -> dict[str, np.ndarray]:
        # Once per step (and at the reset, where the ball lies still where it was put).
        ball = self._ball_position()
        self._ball_velocity = [(a - b) * CONTROL_RATE for a, b in zip(ball, self._ball)]
        self._ball = ball
        return pick_observation(self._tcp, self._tcp_velocity, self.world.gripper_opening(),
                                self._ball, self._ball_velocity, self._goal)

    def _ball_position(self) -> list[float]:
        """Return the ball's centre in base_link (m) now, plain floats."""
        return [p - b for p, b in zip(self.world.body_position(self.world.ball), self._base_xyz)]

    def _is_success(self) -> bool:
        bottom = self._ball[2] - BALL_RADIUS + self._base_xyz[2]  # above the floor (z = 0)
        return bool(bottom >= LIFT_SUCCESS and self.world.gripper_holds_object())

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                       info: Any) -> np.ndarray:
        """Return 0 where the ball is within PICK_GOAL_TOLERANCE of the goal, else -1."""
        return -(_distances(achieved_goal, desired_goal) > PICK_GOAL_TOLERANCE).astype(np.float32)


def _length(vector: np.ndarray) -> float:
    """Return np.linalg.norm(vector) of a 1-D float array, without its checks (every step)."""
    return math.sqrt(vector.dot(vector))  # the norm's own computation, sqrt of the dot product


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Return np.linalg.norm(a - b, axis=-1) computed as it does, without its checks."""
    difference = np.subtract(a, b)
    return np.sqrt(np.add.reduce(difference * difference, axis=-1))


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
