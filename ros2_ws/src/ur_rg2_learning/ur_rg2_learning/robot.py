"""The UR arm with its RG2 as the learning environments drive it: the robot of robot, task, env.

The arm moves the way the ``motion`` node moves it: closed-form UR inverse kinematics
(:class:`ur_rg2_motion.kinematics.ArmKinematics`, with its floor and pedestal checks) turns a
TCP target into joint targets. An action moves ``rg2_tcp``'s target by up to ``MAX_STEP``
along each ``base_link`` axis, the gripper pointing straight down; the gripping robot's fourth
component closes (< 0) or opens (>= 0) the RG2.

The functions (:func:`move_target`, :func:`step_duration`, :func:`start_joints`, ...) are the
environments' and the policy node's, which runs them on the live graph: this module needs no
simulator. The robots (:class:`UrRg2Robot`, Reach's; :class:`UrRg2GrippingRobot`, Pick's)
drive a :class:`ur_rg2_sim.world.SimWorld` that the environment makes and hands them.

Speed: one step is one inverse kinematics solution, one joint command with the joint
velocities fed forward (the sim's trajectory controller feeds them forward too, so the arm
tracks within millimetres despite the long physics steps) and ``substeps`` physics steps.
"""

from __future__ import annotations

from collections.abc import Callable
import math
from typing import TYPE_CHECKING

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_motion.kinematics import (
    FLOOR_CLEARANCE,
    ArmKinematics,
    KinematicsError,
    arm_on_pedestal,
)
from ur_rg2_motion.planning import PICK_POSTURE, gripper_down, plan_joint_move

if TYPE_CHECKING:
    from ur_rg2_sim.world import SimWorld

CONTROL_RATE = 10.0  # Hz: one action per 0.1 s of simulation time
MAX_STEP = 0.05  # m of TCP motion per step and axis at |action| = 1 (0.5 m/s)
# Each episode starts with the TCP here (base_link), jittered by up to START_JITTER per axis.
START_TCP = (0.4, -0.15, 0.1)
START_JITTER = 0.05
# TCP targets stay in this box (base_link); below it the fingers would touch the floor.
TARGET_LOW = (-0.8, -0.8, None)
TARGET_HIGH = (0.8, 0.8, 0.4)
GRIPPER_TIMEOUT = 1.5  # s: the RG2 closes its full 110 mm in under 1 s

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


class UrRg2Robot:
    """The arm as Reach drives it: TCP moves with the joints' speed fed forward, the RG2 open.

    It keeps the step's state: the commanded TCP ``target`` and its ``joints``, the measured
    ``tcp`` and ``tcp_velocity`` (base_link, m, m/s). Measured vectors are plain floats: every
    step computes them, and numpy's overhead on 3-vectors would be most of their cost.
    """

    action_size = 3  # the TCP's move along x, y, z
    substeps = 1  # physics steps per action: the world's physics rate is CONTROL_RATE times it

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        height = world.pedestal_height
        self.base = [0.0, 0.0, height]  # base_link in the world frame
        self.arm = arm_on_pedestal(world.urdf.read_text(), height)
        self.joints = np.zeros(len(ARM_JOINTS))
        self.tcp = [0.0, 0.0, 0.0]
        self.target = np.zeros(3)  # the commanded TCP position
        self.tcp_velocity = [0.0, 0.0, 0.0]
        self.closed = False  # the RG2 commanded closed

    def sample_start(self, rng: np.random.Generator) -> np.ndarray:
        """Return an episode's TCP start: START_TCP jittered by up to START_JITTER per axis."""
        return np.add(START_TCP, rng.uniform(-START_JITTER, START_JITTER, 3))

    def reset(self, start: np.ndarray) -> None:
        """Put the TCP at ``start`` (base_link) in the pick posture, at rest, the RG2 open.

        ValueError when no joints put it there.
        """
        try:
            joints = start_joints(self.arm, start)
        except KinematicsError as error:
            raise ValueError(f'tcp_position {start.tolist()} is out of reach: {error}') from None
        self.world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        self.world.reset_gripper()
        self.closed = False
        self.joints = joints
        self.target = start
        self.tcp = self.tcp_position()
        self.tcp_velocity = [0.0, 0.0, 0.0]

    def place(self, tcp: np.ndarray) -> None:
        """Teleport the arm to the TCP at ``tcp`` in the pick posture (KinematicsError)."""
        joints = start_joints(self.arm, tcp)
        self.world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        self.joints, self.target = joints, tcp
        self.tcp = self.tcp_position()

    def step(self, action: list[float], object_near: bool) -> None:
        """Act (clipped ``action``, plain floats) for 1 / CONTROL_RATE s; measure the TCP.

        ``object_near``: the task's object is near the TCP (a gripping robot steps finely).
        """
        previous = self.joints
        self._command(action)
        self._move_arm(previous, self.joints, object_near)
        tcp = self.tcp_position()
        self.tcp_velocity = [(a - b) * CONTROL_RATE for a, b in zip(tcp, self.tcp)]
        self.tcp = tcp

    def tcp_position(self) -> list[float]:
        """Return the TCP's position in base_link (m) now, plain floats."""
        return [p - b for p, b in zip(self.world.link_pose()[0], self.base)]

    def _command(self, action: list[float]) -> None:
        # From the last commanded target, not the measured TCP: a zero action then holds the
        # arm still instead of letting it creep after its own tracking error.
        self.target, self.joints = move_target(self.arm, self.target, self.joints, action)

    def _move_arm(self, previous: np.ndarray, joints: np.ndarray, object_near: bool) -> None:
        """Take the arm from the last step's joint targets to this one's in one control period.

        Here in one physics step: the speed that takes the last target to this one in one step
        is fed forward, as the trajectory controller feeds its path's speed.
        """
        # Inside the joint limits already (the inverse kinematics keeps to them): one call.
        q = joints.tolist()
        self.world.drive_arm(q, [(a - b) * CONTROL_RATE for a, b in zip(q, previous.tolist())])
        for _ in range(self.substeps):
            self.world.step()


class UrRg2GrippingRobot(UrRg2Robot):
    """The arm as Pick drives it: TCP moves along cubics ending at rest, the RG2 opens and closes.

    Grasps need shorter physics steps than free arm motion: 80 Hz holds the ball. Where no
    grasp can happen (the RG2 open, no object near the TCP) 40 Hz moves the arm as well, for
    half the physics.
    """

    action_size = 4  # the TCP's move, and the gripper: close (< 0) or open (>= 0)
    substeps = 8
    free_substeps = 4

    def __init__(self, world: SimWorld) -> None:
        super().__init__(world)
        # The cubic's position and speed factors at the ends of a step's substeps (columns).
        fractions = {n: np.arange(1, n + 1) / n for n in (self.substeps, self.free_substeps)}
        self._cubics = {n: ((s * s * (3.0 - 2.0 * s))[:, None],
                            (6.0 * s * (1.0 - s) * CONTROL_RATE)[:, None])
                        for n, s in fractions.items()}
        self._rate_substeps = self.substeps  # the world's physics rate, in substeps per step
        limits = [world.limits[name] for name in ARM_JOINTS]
        self._lower = np.array([limit.lower for limit in limits])
        self._upper = np.array([limit.upper for limit in limits])
        self._gripper_moved = False

    def close_on(self, tcp: np.ndarray, opening: float,
                 place_object: Callable[[], None]) -> None:
        """Teleport the TCP to ``tcp``, the fingers ``opening`` apart, and close them.

        ``place_object`` then puts what they close on between them (the world's calls in this
        order: their order changes the physics' contacts). The physics steps (finely) until
        the fingers stop on it, or for GRIPPER_TIMEOUT. KinematicsError when no joints put the
        TCP at ``tcp``.
        """
        joints = start_joints(self.arm, tcp)
        world = self.world
        self.use_substeps(self.substeps)
        world.set_arm_positions(dict(zip(ARM_JOINTS, joints.tolist())))
        world.set_gripper_opening(opening)
        place_object()
        world.close_gripper()
        self.closed = True
        for _ in range(round(GRIPPER_TIMEOUT * CONTROL_RATE * self.substeps)):
            world.step()
            if world.gripper_stopped():
                break
        self.joints, self.target = joints, tcp
        self.tcp = self.tcp_position()

    def use_substeps(self, substeps: int) -> None:
        """Set the world's physics rate to ``substeps`` physics steps per action."""
        if substeps != self._rate_substeps:
            self.world.set_physics_rate(CONTROL_RATE * substeps)
            self._rate_substeps = substeps

    def _command(self, action: list[float]) -> None:
        closed = action[3] < 0.0
        self._gripper_moved = closed != self.closed
        if self._gripper_moved:
            if closed:
                self.world.close_gripper()
            else:
                self.world.open_gripper()
            self.closed = closed
        super()._command(action)

    def _move_arm(self, previous: np.ndarray, joints: np.ndarray, object_near: bool) -> None:
        """Move along a cubic from rest at the last target to rest at this one, as in the graph.

        The policy node sends each step as a one-point goal, which the trajectory controller
        runs as a cubic ending at rest on the point. Ending every step at rest also keeps the
        TCP where the policy sent it: fed the speed forward and left to run on (Reach's way),
        the arm overshot a fast descent by up to 2 cm, closing the fingers over the ball's top.
        """
        self.use_substeps(self.substeps if self.closed or object_near else self.free_substeps)
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
