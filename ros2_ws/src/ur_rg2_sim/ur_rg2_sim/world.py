"""The pybullet world: floor, pedestal, UR arm with RG2 gripper, ball. Plain Python, no ROS.

:class:`SimWorld` builds it and steps it; what it models lives in modules of its own, mixed in:
:mod:`ur_rg2_sim.scene` (floor, pedestal, ball, test scenery), :mod:`ur_rg2_sim.robot` (arm
and gripper), :mod:`ur_rg2_sim.contacts` (contact settings, contacts, clearance). Everything
here runs on one thread (pybullet clients are not thread-safe); the node feeds it commands
from that thread only.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
import functools
import math
from pathlib import Path
import tempfile
from typing import Optional

import pybullet
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS

from ur_rg2_sim.contacts import SELF_COLLISION_PAIRS, Contact, ContactsMixin
from ur_rg2_sim.robot import ArmMixin, GripperMixin
from ur_rg2_sim.robot_model import TCP_LINK, JointLimit, joint_limits, write_robot_urdf
from ur_rg2_sim.scene import BALL_MASS, DEFAULT_BALL_POSITION, PEDESTAL_HEIGHT, SceneMixin

__all__ = ['BALL_MASS', 'DEFAULT_BALL_POSITION', 'PEDESTAL_HEIGHT', 'SELF_COLLISION_PAIRS',
           'Contact', 'JointStateSample', 'SimWorld', 'WorldConfig']

# Inverse kinematics: the least bend (rad) of elbow and wrist_1 it starts from, and how many
# times at most it restarts pybullet's solver.
_IK_SEED_BEND = 1.0
_IK_ROUNDS = 10


@dataclass
class WorldConfig:
    """Start-up settings of the world."""

    robot_model: str = 'ur5'
    physics_rate: float = 240.0
    ball_position: Sequence[float] = DEFAULT_BALL_POSITION
    ball_radius: float = 0.03
    ball_color: Sequence[float] = (1.0, 0.0, 0.0, 1.0)
    home_position: Sequence[float] = field(default_factory=lambda: [0.0] * len(ARM_JOINTS))
    gui: bool = False


@dataclass(frozen=True)
class JointStateSample:
    """Positions (rad or m), velocities and efforts of the arm and gripper joints, in order."""

    names: tuple[str, ...]
    positions: list[float]
    velocities: list[float]
    efforts: list[float]


class SimWorld(SceneMixin, ArmMixin, GripperMixin, ContactsMixin):
    """A pybullet world with the arm under position control and a force-limited RG2."""

    def __init__(self, config: WorldConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.physics_rate
        self.client = pybullet.connect(pybullet.GUI if config.gui else pybullet.DIRECT)
        self._p = _ClientCalls(self.client)
        # Thousands of calls a second: positional, the cheapest way to call pybullet.
        self._step_simulation = functools.partial(pybullet.stepSimulation, self.client)
        self._p.setPhysicsEngineParameter(fixedTimeStep=self.dt, numSolverIterations=50,
                                          solverResidualThreshold=1e-4)
        self._p.setGravity(0, 0, -9.81)
        self.floor = self._create_floor()
        self.pedestal_height = PEDESTAL_HEIGHT
        self.pedestal = self._create_pedestal()
        self._model_dir = tempfile.TemporaryDirectory(prefix='ur_rg2_sim-')
        self.urdf = write_robot_urdf(config.robot_model, Path(self._model_dir.name))
        self.limits: dict[str, JointLimit] = joint_limits(self.urdf)
        self.robot = self._p.loadURDF(str(self.urdf), [0, 0, self.pedestal_height],
                                      useFixedBase=True,
                                      flags=pybullet.URDF_USE_INERTIA_FROM_FILE
                                      | pybullet.URDF_USE_SELF_COLLISION)
        self._joint_index = {
            self._p.getJointInfo(self.robot, i)[1].decode(): i
            for i in range(self._p.getNumJoints(self.robot))
        }
        self._link_index = {
            self._p.getJointInfo(self.robot, i)[12].decode(): i
            for i in range(self._p.getNumJoints(self.robot))
        }
        self.joint_names = ARM_JOINTS + GRIPPER_JOINTS
        self._indices = [self._joint_index[name] for name in self.joint_names]
        self._arm_indices = self._indices[:len(ARM_JOINTS)]
        self._arm_efforts = [self.limits[name].effort for name in ARM_JOINTS]
        self._arm_speeds = [self.limits[name].velocity for name in ARM_JOINTS]
        self._finger_indices = [self._joint_index[name] for name in GRIPPER_JOINTS]
        self._caps_at_limits = False  # whether every arm motor's speed cap is its limit
        self._link_name = {index: name for name, index in self._link_index.items()}
        self._link_name[-1] = self._p.getBodyInfo(self.robot)[0].decode()
        self._movable = [i for i in range(self._p.getNumJoints(self.robot))
                         if self._p.getJointInfo(self.robot, i)[2] != pybullet.JOINT_FIXED]
        self._obstacle_name = {self.floor: 'floor', self.pedestal: 'pedestal'}
        self._configure_contacts()
        self._steps = 0
        # (step, finger positions) when gripper_stopped last looked, and what it found.
        self._finger_probe: Optional[tuple[int, list[float]]] = None
        self._finger_moving = True
        self.arm_targets = dict.fromkeys(ARM_JOINTS, 0.0)
        self.set_arm_positions(dict(zip(ARM_JOINTS, config.home_position)))
        self.reset_gripper()  # the RG2 starts fully open
        self.ball = self._create_ball()
        self.extra_bodies: list[int] = []
        self._scene_objects: list[int] = []  # set by set_scene_objects

    # -- state --------------------------------------------------------------------------------

    def set_physics_rate(self, rate: float) -> None:
        """Make the physics step 1 / ``rate`` s from now on (the learning environments' choice)."""
        self.dt = 1.0 / rate
        self._p.setPhysicsEngineParameter(fixedTimeStep=self.dt)

    def step(self) -> None:
        """Advance the simulation by one physics step."""
        self._step_simulation()
        self._steps += 1

    @property
    def steps(self) -> int:
        """Return how many physics steps :meth:`step` has taken."""
        return self._steps

    def joint_states(self) -> JointStateSample:
        """Return the current state of the arm and gripper joints."""
        states = self._p.getJointStates(self.robot, self._indices)
        return JointStateSample(
            self.joint_names,
            [s[0] for s in states], [s[1] for s in states], [s[3] for s in states])

    def link_pose(self, link: str = TCP_LINK) -> tuple[tuple, tuple]:
        """Return the world position and xyzw orientation of a robot link."""
        state = self._p.getLinkState(self.robot, self._link_index[link],
                                     computeForwardKinematics=True)
        return state[4], state[5]

    def link_index(self, link: str) -> int:
        """Return pybullet's index of a robot link (for contact and collision queries)."""
        return self._link_index[link]

    def inverse_kinematics(self, position: Sequence[float],
                           orientation: Sequence[float] | None = None) -> dict[str, float]:
        """Return arm joint positions that put the gripper's TCP at a world pose.

        The solution is the posture of a UR working over a table: elbow up, wrist ahead of
        the forearm. The search starts from the current joints with the elbow and wrist_1 bent
        that way (at least ``_IK_SEED_BEND`` rad): from the stretched home pose it would find
        elbow-down solutions, which push the upper arm into the floor, or a folded wrist with
        some 20 cm less reach.
        """
        movable = self._movable
        lower, upper = zip(*[self._p.getJointInfo(self.robot, i)[8:10] for i in movable])
        seed = [self._p.getJointState(self.robot, i)[0] for i in movable]
        elbow = movable.index(self._joint_index['elbow_joint'])
        wrist = movable.index(self._joint_index['wrist_1_joint'])
        seed[elbow] = max(seed[elbow], _IK_SEED_BEND)
        seed[wrist] = min(seed[wrist], -_IK_SEED_BEND)
        # Given the start joints, pybullet takes the target in the base frame.
        base_position, base_orientation = self._p.getBasePositionAndOrientation(self.robot)
        to_base = self._p.invertTransform(base_position, base_orientation)
        local_position, local_orientation = self._p.multiplyTransforms(
            *to_base, list(position), [0, 0, 0, 1] if orientation is None else list(orientation))
        # pybullet's solver stops short far from its start (it limits each iteration's step):
        # restarting it from its own answer converges within a few rounds.
        for _ in range(_IK_ROUNDS):
            solution = self._p.calculateInverseKinematics(
                self.robot, self._link_index[TCP_LINK], local_position,
                targetOrientation=None if orientation is None else local_orientation,
                lowerLimits=list(lower), upperLimits=list(upper),
                jointRanges=[u - lo for lo, u in zip(lower, upper)], restPoses=seed,
                currentPositions=seed, maxNumIterations=200, residualThreshold=1e-5)
            converged = max(abs(a - b) for a, b in zip(solution, seed)) < 1e-6
            seed = list(solution)
            if converged:
                break
        by_index = dict(zip(movable, solution))
        return {name: _wrap(by_index[self._joint_index[name]]) for name in ARM_JOINTS}

    def close(self) -> None:
        """Disconnect from pybullet; the world is unusable afterwards."""
        if self.client is not None and pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)
        self.client = None
        self._model_dir.cleanup()


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


class _ClientCalls:
    """pybullet functions bound to one physics client (``physicsClientId`` on every call)."""

    def __init__(self, client: int) -> None:
        self._client = client

    def __getattr__(self, name: str):
        call = functools.partial(getattr(pybullet, name), physicsClientId=self._client)
        setattr(self, name, call)  # cached: the next lookup skips __getattr__
        return call
