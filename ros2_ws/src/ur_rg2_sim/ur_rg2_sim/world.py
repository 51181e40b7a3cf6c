"""The pybullet world: floor, pedestal, UR arm with RG2 gripper, ball. Plain Python, no ROS.

Everything here runs on one thread (pybullet clients are not thread-safe); the node feeds it
commands from that thread only.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
import functools
import math
from pathlib import Path
import tempfile
from typing import Optional

import pybullet
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS, RG2_MAX_FORCE, RG2_MAX_OPENING
from ur_rg2_common.scene_objects import SceneObject

from ur_rg2_sim.robot_model import (
    RG2_MAX_FINGER_SPEED,
    RG2_MIN_FORCE,
    TCP_LINK,
    JointLimit,
    joint_limits,
    write_robot_urdf,
)

# In front of the robot, in the reach of the UR3 as well as the UR5, 0.5 m from the base axis.
DEFAULT_BALL_POSITION = (0.4, -0.3, 0.03)

# The arm stands on a pedestal, as in a real cell: the UR zero pose (the default home) holds
# the arm out level with the shoulder, which puts the wrist and the open RG2's lower finger up
# to 73 mm (UR5) below the base plane. On this riser home clears the floor by 127 mm, room for
# the first jogs down before the gripper meets the floor. base_link sits on top, PEDESTAL_HEIGHT
# above the world origin. One height for both models: with the gripper pointing down, the
# floor stays in reach from 0.3 to 0.9 m from the base axis (UR5), 0.3 to 0.55 m (UR3); the
# elbow's +-180 degrees end it nearer in (tests/test_sim_reach.py).
PEDESTAL_HEIGHT = 0.2  # m, floor to base_link
_PEDESTAL_WIDTH = 0.20  # m, a square steel column a little wider than the UR5's 149 mm base
_PLATE_WIDTH = 0.22  # m, the mounting plate the UR base is bolted to
_PLATE_THICKNESS = 0.015  # m
_PEDESTAL_COLOUR = (0.27, 0.29, 0.32, 1.0)  # painted steel
_PLATE_COLOUR = (0.55, 0.57, 0.6, 1.0)  # bare aluminium
# Inverse kinematics: the least bend (rad) of elbow and wrist_1 it starts from, and how many
# times at most it restarts pybullet's solver.
_IK_SEED_BEND = 1.0
_IK_ROUNDS = 10
BALL_MASS = 0.05  # kg, a light foam ball the RG2's 40 N holds easily

# Contact settings that make a friction grasp hold: rubber pads, a ball that neither spins nor
# rolls out between them, and a little compliance so the two single-point contacts stay stable.
_PAD_FRICTION = 1.5
_BALL_FRICTION = 1.2
_BALL_ROLLING_FRICTION = 1e-4
_BALL_SPINNING_FRICTION = 1e-3
_CONTACT_STIFFNESS = 3e4
_CONTACT_DAMPING = 1e2

# Self-collision is on only between links that can really meet: the forearm's far end (the
# wrist) and the gripper folded onto the upper arm or the shoulder, the forearm, wrist and
# gripper onto the base. Neighbouring links' meshes (convex hulls in pybullet) overlap at
# their joint in every pose. The forearm's hull is much fatter than the forearm (it spans
# both joint housings): it comes within 13 mm of wrist_2 at home and met the open fingers in
# ordinary tool moves, so the gripper folded back onto the forearm is left out.
_WRIST_AND_GRIPPER = ('wrist_1_link', 'wrist_2_link', 'wrist_3_link', 'rg2_body',
                      'rg2_left_finger', 'rg2_right_finger')
SELF_COLLISION_PAIRS = tuple(
    [('upper_arm_link', link) for link in _WRIST_AND_GRIPPER]
    + [('shoulder_link', link) for link in ('forearm_link', *_WRIST_AND_GRIPPER)]
    + [('base_link', link) for link in ('forearm_link', *_WRIST_AND_GRIPPER)])

# A position motor holding its joint keeps it this close to the target (rad), also against a
# contact; a joint further off is on its way somewhere (or pressed back from there).
_HOLDING_ERROR = 2e-3

# In a coordinated move (SimWorld.move_arm) no joint is slowed below this share of its
# velocity limit: one pushed off its target (by a contact) still gets back briskly.
_MIN_SPEED_SHARE = 0.05

# A finger that moves slower than this is stopped (m/s).
_FINGER_STOPPED_SPEED = 1e-3
# The fingers' speed is measured over this long (s): the solver's jitter of a finger resting
# at the end of its travel averages out.
_FINGER_SPEED_WINDOW = 0.05
# A body slower than this is at rest (m/s): free finger travel may be skipped past it.
_BODY_AT_REST_SPEED = 0.005
# Fingers stopped this far short of closed hold something (m of opening).
_GRASP_MIN_OPENING = 0.002


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
class Contact:
    """A robot link pressing on an obstacle: the floor, the pedestal or another robot link."""

    link: str
    obstacle: str  # 'floor', 'pedestal' or the other link's name
    force: float  # N, along the normal
    approach: float  # m the joints' targets would take the link into the obstacle (<0: away)
    incidence: float  # sine of the angle of that motion into the surface: 1 head-on, 0 along


@dataclass(frozen=True)
class JointStateSample:
    """Positions (rad or m), velocities and efforts of the arm and gripper joints, in order."""

    names: tuple[str, ...]
    positions: list[float]
    velocities: list[float]
    efforts: list[float]


class SimWorld:
    """A pybullet world with the arm under position control and a force-limited RG2."""

    def __init__(self, config: WorldConfig) -> None:
        self.config = config
        self.dt = 1.0 / config.physics_rate
        self.client = pybullet.connect(pybullet.GUI if config.gui else pybullet.DIRECT)
        self._p = _ClientCalls(self.client)
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

    # -- construction -------------------------------------------------------------------------

    def _create_floor(self) -> int:
        # Collision only: the camera draws the floor analytically, which is far cheaper than
        # rasterising a screen-filling plane (see camera.py).
        # A body without a visual shape is drawn from its collision shape; a speck of a visual
        # below the floor (hidden there by the camera) keeps the plane out of the renderer.
        speck = self._p.createVisualShape(pybullet.GEOM_SPHERE, radius=1e-4,
                                          visualFramePosition=[0, 0, -1])
        floor = self._p.createMultiBody(0, self._p.createCollisionShape(pybullet.GEOM_PLANE),
                                        speck)
        self._p.changeDynamics(floor, -1, lateralFriction=1.0)
        return floor

    def _create_pedestal(self) -> int:
        height = self.pedestal_height
        column = (_PEDESTAL_WIDTH / 2, _PEDESTAL_WIDTH / 2, (height - _PLATE_THICKNESS) / 2)
        plate = (_PLATE_WIDTH / 2, _PLATE_WIDTH / 2, _PLATE_THICKNESS / 2)
        centres = [[0, 0, column[2]], [0, 0, height - plate[2]]]
        collision = self._p.createCollisionShapeArray(
            [pybullet.GEOM_BOX] * 2, halfExtents=[column, plate], collisionFramePositions=centres)
        visual = self._p.createVisualShapeArray(
            [pybullet.GEOM_BOX] * 2, halfExtents=[column, plate], visualFramePositions=centres,
            rgbaColors=[_PEDESTAL_COLOUR, _PLATE_COLOUR])
        return self._p.createMultiBody(0, collision, visual)

    def _configure_contacts(self) -> None:
        # The floor and the pedestal are solid for the whole arm and gripper, except where the
        # base sits on the plate by design (its mesh reaches a few mm into it).
        self._on_pedestal = (-1, self._link_index['base_link'], self._link_index['base'])
        for link in self._on_pedestal:
            self._p.setCollisionFilterPair(self.robot, self.pedestal, link, -1, 0)
        # Self-collision only for SELF_COLLISION_PAIRS (see there).
        self._self_collision_links = [tuple(self._link_index[name] for name in pair)
                                      for pair in SELF_COLLISION_PAIRS]
        allowed = {frozenset(pair) for pair in self._self_collision_links}
        links = range(-1, self._p.getNumJoints(self.robot))
        for a in links:
            for b in links:
                if a < b and frozenset((a, b)) not in allowed:
                    self._p.setCollisionFilterPair(self.robot, self.robot, a, b, 0)
        # The RG2's linkage moves both fingers together: a gear constraint keeps them
        # symmetric, so a grasped object is centred between them instead of pushed aside.
        gear = self._p.createConstraint(
            self.robot, self._link_index['rg2_left_finger'], self.robot,
            self._link_index['rg2_right_finger'], pybullet.JOINT_GEAR, [0, 1, 0], [0, 0, 0],
            [0, 0, 0])
        self._p.changeConstraint(gear, gearRatio=-1, erp=0.2, maxForce=2 * RG2_MAX_FORCE)
        for name in ('rg2_left_finger', 'rg2_right_finger'):
            self._p.changeDynamics(
                self.robot, self._link_index[name], lateralFriction=_PAD_FRICTION,
                spinningFriction=_BALL_SPINNING_FRICTION,
                rollingFriction=_BALL_ROLLING_FRICTION,
                contactStiffness=_CONTACT_STIFFNESS, contactDamping=_CONTACT_DAMPING)

    def _create_ball(self) -> int:
        radius = self.config.ball_radius
        ball = self._p.createMultiBody(
            BALL_MASS,
            self._p.createCollisionShape(pybullet.GEOM_SPHERE, radius=radius),
            self._p.createVisualShape(pybullet.GEOM_SPHERE, radius=radius,
                                      rgbaColor=list(self.config.ball_color)),
            basePosition=list(self.config.ball_position))
        self._p.changeDynamics(ball, -1, lateralFriction=_BALL_FRICTION,
                               rollingFriction=_BALL_ROLLING_FRICTION,
                               spinningFriction=_BALL_SPINNING_FRICTION, restitution=0.0)
        return ball

    # -- arm ----------------------------------------------------------------------------------

    def clamp(self, name: str, position: float) -> float:
        """Clamp ``position`` to the joint limits of ``name``."""
        limit = self.limits[name]
        return min(max(position, limit.lower), limit.upper)

    def set_arm_targets(self, targets: Mapping[str, float],
                        velocities: Optional[Mapping[str, float]] = None) -> dict[str, float]:
        """Move the named arm joints toward new targets (clamped); return the targets set.

        ``velocities`` (rad/s), given by a trajectory, are fed forward so that the joints
        follow a moving target without lagging behind it.
        """
        applied = {name: self.clamp(name, value) for name, value in targets.items()}
        self.arm_targets.update(applied)
        self._caps_at_limits = len(applied) == len(ARM_JOINTS) or self._caps_at_limits
        for name, target in applied.items():
            limit = self.limits[name]
            self._p.setJointMotorControl2(
                self.robot, self._joint_index[name], pybullet.POSITION_CONTROL,
                targetPosition=target, force=limit.effort, maxVelocity=limit.velocity,
                targetVelocity=velocities[name] if velocities else 0.0)
        return applied

    def drive_arm(self, positions: Sequence[float], velocities: Sequence[float]) -> None:
        """Set every arm joint's target and fed-forward speed, ``ARM_JOINTS`` order, unclamped.

        For callers that clamp once for many physics steps (the learning environments, each
        substep of a step): one pybullet call. Its motors keep the speed caps set last
        (setJointMotorControlArray takes none): the velocity limits, set again here first if
        :meth:`move_arm` lowered them.
        """
        if not self._caps_at_limits:
            self.set_arm_targets(dict(zip(ARM_JOINTS, positions)),
                                 dict(zip(ARM_JOINTS, velocities)))
            return
        self._p.setJointMotorControlArray(
            self.robot, self._arm_indices, pybullet.POSITION_CONTROL, targetPositions=positions,
            targetVelocities=velocities, forces=self._arm_efforts)
        self.arm_targets.update(zip(ARM_JOINTS, positions))

    def move_arm(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Move the named arm joints to new targets (clamped) together; return the targets set.

        As a UR's movej: every joint still on its way goes at the speed that brings it to its
        target when the slowest one arrives, so the arm moves along a straight line in joint
        space. Joints moving on their own, each at its limit, reach their targets at
        different times, and the short moves come first: from a folded pose, a reset brought
        the shoulder down before the elbow had opened and pressed the wrist into the floor.
        """
        applied = {name: self.clamp(name, value) for name, value in targets.items()}
        self.arm_targets.update(applied)
        positions = self.joint_states().positions
        times = {name: abs(self.arm_targets[name] - position) / self.limits[name].velocity
                 for name, position in zip(ARM_JOINTS, positions)}
        slowest = max(times.values())
        self._caps_at_limits = False
        for name in ARM_JOINTS:
            limit = self.limits[name]
            share = times[name] / slowest if slowest > 0 else 1.0
            self._p.setJointMotorControl2(
                self.robot, self._joint_index[name], pybullet.POSITION_CONTROL,
                targetPosition=self.arm_targets[name], force=limit.effort,
                maxVelocity=limit.velocity * max(share, _MIN_SPEED_SHARE))
        return applied

    def jog_arm(self, deltas: Mapping[str, float]) -> dict[str, float]:
        """Add ``deltas`` to the named joints' current targets, moving together (move_arm)."""
        return self.move_arm(
            {name: self.arm_targets[name] + delta for name, delta in deltas.items()})

    def set_arm_positions(self, positions: Mapping[str, float]) -> None:
        """Teleport the named joints (at rest) and hold them there."""
        for name, position in positions.items():
            self._p.resetJointState(self.robot, self._joint_index[name],
                                    self.clamp(name, position), 0.0)
        self.set_arm_targets(positions)

    # -- gripper ------------------------------------------------------------------------------

    def reset_gripper(self) -> None:
        """Teleport the fingers fully open, at rest, and hold them there."""
        for name in GRIPPER_JOINTS:
            self._p.resetJointState(self.robot, self._joint_index[name], RG2_MAX_OPENING / 2,
                                    0.0)
        self.command_gripper(RG2_MAX_OPENING)

    def set_gripper_opening(self, opening: float) -> None:
        """Teleport the fingers ``opening`` (m, clamped) apart, at rest, and hold them there."""
        opening = min(max(opening, 0.0), RG2_MAX_OPENING)
        for index in self._finger_indices:
            self._p.resetJointState(self.robot, index, opening / 2, 0.0)
        self.command_gripper(opening)

    def open_gripper(self) -> None:
        """Drive the fingers to the full 110 mm opening."""
        self.command_gripper(RG2_MAX_OPENING)

    def close_gripper(self) -> None:
        """Drive the fingers closed with the RG2's maximum force; an object stops them."""
        self.command_gripper(0.0)

    def command_gripper(self, opening: float, force: float = RG2_MAX_FORCE) -> tuple[float, float]:
        """Drive the fingers to ``opening`` (m) pushing with at most ``force`` (N).

        Both are clamped to the RG2's range (0-110 mm, 3-40 N); returns the values used.
        """
        self.gripper_target = min(max(opening, 0.0), RG2_MAX_OPENING)
        self.gripper_force = min(max(force, RG2_MIN_FORCE), RG2_MAX_FORCE)
        self._finger_probe = None  # moving from now on, until seen stopped
        self._finger_moving = True
        for name in GRIPPER_JOINTS:
            self._p.setJointMotorControl2(
                self.robot, self._joint_index[name], pybullet.POSITION_CONTROL,
                targetPosition=self.gripper_target / 2, force=self.gripper_force,
                maxVelocity=RG2_MAX_FINGER_SPEED)
        return self.gripper_target, self.gripper_force

    def gripper_opening(self) -> float:
        """Return the distance between the finger pads, metres."""
        return sum(self._p.getJointState(self.robot, self._joint_index[name])[0]
                   for name in GRIPPER_JOINTS)

    def gripper_effort(self) -> float:
        """Return the force the finger motors push with, N (the grip force on an object)."""
        return sum(abs(self._p.getJointState(self.robot, self._joint_index[name])[3])
                   for name in GRIPPER_JOINTS) / len(GRIPPER_JOINTS)

    def gripper_stopped(self) -> bool:
        """Return whether both fingers have stopped moving (at the target or blocked).

        Judged by how far the fingers moved over the last ``_FINGER_SPEED_WINDOW`` (or more)
        at which this was asked, not by the speed the solver reports: with the gripper on its
        side or upside down (the arm folded), or a finger pressed on the floor, the fingers
        rest at the end of their travel and the reported speed jitters by several mm/s
        without any motion.
        """
        positions = [self._p.getJointState(self.robot, self._joint_index[name])[0]
                     for name in GRIPPER_JOINTS]
        if self._finger_probe is None:
            self._finger_probe = (self._steps, positions)
            return False
        steps, before = self._finger_probe
        if (self._steps - steps) * self.dt >= _FINGER_SPEED_WINDOW:
            elapsed = (self._steps - steps) * self.dt
            self._finger_moving = any(abs(a - b) / elapsed >= _FINGER_STOPPED_SPEED
                                      for a, b in zip(positions, before))
            self._finger_probe = (self._steps, positions)
        return not self._finger_moving

    def skip_free_finger_travel(self, margin: float = 0.005,
                                still: float = _BODY_AT_REST_SPEED) -> bool:
        """Put the fingers at their target at once if nothing can be in their way; say if so.

        Nothing can be when every other body is at rest (slower than ``still``, m/s) and no
        body, nor a robot link the fingers may touch, comes within ``margin`` of a finger
        sliding its remaining travel. Convex shapes' distance shrinks at most by the travel
        times the cosine between the slide and their closest points' normal: a floor under
        fingers sliding level stays as far. Their travel is then the motors' free run to the
        target: stepping through it (the RG2's full stroke takes some 100 steps at 80 Hz)
        changes nothing else. The learning environments wait for the fingers this way; a grasp
        (the ball between the pads) is always stepped.
        """
        p = self._p
        fingers = self._finger_indices
        positions = [state[0] for state in p.getJointStates(self.robot, fingers)]
        travel = max(abs(self.gripper_target / 2 - x) for x in positions)
        (left, _), (right, _) = [state[:2] for state in p.getLinkStates(self.robot, fingers)]
        slide = [a - b for a, b in zip(left, right)]
        length = math.sqrt(sum(x * x for x in slide)) or 1.0
        slide = [x / length for x in slide]

        def clear(points) -> bool:
            return all(point[8] - travel * abs(sum(n * d for n, d in zip(point[7], slide)))
                       > margin for point in points)

        reach = travel + margin
        for i in range(p.getNumBodies()):
            body = p.getBodyUniqueId(i)
            if body == self.robot:
                continue
            speed = p.getBaseVelocity(body)[0]
            if speed[0] ** 2 + speed[1] ** 2 + speed[2] ** 2 > still * still:
                return False
            for finger in fingers:
                if not clear(p.getClosestPoints(self.robot, body, reach, linkIndexA=finger)):
                    return False
        for a, b in self._self_collision_links:
            if (a in fingers or b in fingers) and not clear(
                    p.getClosestPoints(self.robot, self.robot, reach, a, b)):
                return False
        for index in fingers:
            p.resetJointState(self.robot, index, self.gripper_target / 2, 0.0)
        self._finger_probe = (self._steps, [self.gripper_target / 2] * len(positions))
        self._finger_moving = False
        return True

    def gripper_holds_object(self) -> bool:
        """Return whether the closed fingers are held apart by something between them."""
        if self.gripper_target > 0.0:
            return False
        return self.gripper_opening() > _GRASP_MIN_OPENING and all(
            self._p.getContactPoints(self.robot, linkIndexA=self._link_index[link])
            for link in ('rg2_left_finger', 'rg2_right_finger'))

    # -- state --------------------------------------------------------------------------------

    def set_physics_rate(self, rate: float) -> None:
        """Make the physics step 1 / ``rate`` s from now on (the learning environments' choice)."""
        self.dt = 1.0 / rate
        self._p.setPhysicsEngineParameter(fixedTimeStep=self.dt)

    def step(self) -> None:
        """Advance the simulation by one physics step."""
        self._p.stepSimulation()
        self._steps += 1

    def joint_states(self) -> JointStateSample:
        """Return the current state of the arm and gripper joints."""
        states = self._p.getJointStates(self.robot, self._indices)
        return JointStateSample(
            self.joint_names,
            [s[0] for s in states], [s[1] for s in states], [s[3] for s in states])

    def obstacle_contacts(self) -> list[Contact]:
        """Return the links pressing on the floor, the pedestal or the arm (last step).

        One Contact per link and obstacle: ``force`` is the sum over its contact points,
        ``approach`` how far the most loaded point would move into the obstacle if every arm
        joint went from where it is to its target (the Jacobian there times the joints'
        remaining travel): positive while a command drives the link into it; ``incidence``
        the sine of the angle between that motion and the obstacle's surface. A joint within
        ``_HOLDING_ERROR`` of its target counts as holding, not moving.
        """
        pairs: dict[tuple[int, int, int], list] = {}
        for c in self._p.getContactPoints(self.robot):
            if c[9] > 0.0 and (c[2] == self.robot or c[2] in self._obstacle_name):
                pairs.setdefault((c[2], c[3], c[4]), []).append(c)
        if not pairs:
            return []
        states = self._p.getJointStates(self.robot, self._movable)
        positions = [s[0] for s in states]
        travel = dict.fromkeys(self._movable, 0.0)
        for name, index in zip(ARM_JOINTS, self._indices):
            remaining = self.arm_targets[name] - states[self._movable.index(index)][0]
            travel[index] = remaining if abs(remaining) > _HOLDING_ERROR else 0.0
        travel = [travel[i] for i in self._movable]
        moving = any(travel)
        zeros = [0.0] * len(self._movable)
        found = []
        for (body, link_a, link_b), points in pairs.items():
            c = max(points, key=lambda point: point[9])
            approach = incidence = 0.0
            if moving:
                motion = self._point_motion(link_a, c[5], positions, travel, zeros)
                if body == self.robot:
                    other = self._point_motion(link_b, c[6], positions, travel, zeros)
                    motion = [m - o for m, o in zip(motion, other)]
                # The normal points from the obstacle (B) toward the robot link (A).
                approach = -sum(m * n for m, n in zip(motion, c[7]))
                incidence = approach / max(math.sqrt(sum(m * m for m in motion)), 1e-12)
            # Of two links, the one further down the chain (the wrist, not the upper arm) is
            # the one that touched; the approach is the same either way round.
            link, other_link = ((link_a, link_b) if body != self.robot or link_a > link_b
                                else (link_b, link_a))
            found.append(Contact(self._link_name[link],
                                 self._obstacle_name.get(body) or self._link_name[other_link],
                                 sum(point[9] for point in points), approach, incidence))
        return found

    def clearance(self, within: float) -> float:
        """Return the robot's least gap to the floor, the pedestal and itself, up to ``within``.

        In m, negative where a link is in an obstacle. From the links' poses now, stepped or
        placed (``place_robot``); the pairs are those the simulation lets touch.
        """
        points = list(self._p.getClosestPoints(self.robot, self.floor, within))
        points += [point for point in self._p.getClosestPoints(self.robot, self.pedestal, within)
                   if point[3] not in self._on_pedestal]
        for a, b in self._self_collision_links:
            points += self._p.getClosestPoints(self.robot, self.robot, within, a, b)
        return min((point[8] for point in points), default=within)

    def place_robot(self, positions: Sequence[float]) -> None:
        """Put the arm and gripper joints (``joint_names`` order) at ``positions``, motors unset.

        For a world that only tries poses (ur_rg2_sim.planning), never stepped.
        """
        for index, position in zip(self._indices, positions):
            self._p.resetJointState(self.robot, index, position, 0.0)

    def _point_motion(self, link: int, point, positions, travel, zeros) -> list[float]:
        """Return how far ``point`` (world) on ``link`` moves for the joint ``travel``."""
        # calculateJacobian takes the point in the link's URDF frame (as pybullet's own
        # jacobian example passes the centre of mass's offset in it), not about the centre of
        # mass: the upper arm's is 0.28 m from its frame, and a point there came out moving
        # up where it moved down.
        frame_position, frame_orientation = self._p.getLinkState(self.robot, link)[4:6]
        local, _ = self._p.multiplyTransforms(
            *self._p.invertTransform(frame_position, frame_orientation), point, [0, 0, 0, 1])
        linear, _ = self._p.calculateJacobian(self.robot, link, local, positions, zeros, zeros)
        return [sum(row[i] * travel[i] for i in range(len(travel))) for row in linear]

    def arm_on_its_way(self) -> bool:
        """Return whether an arm joint is further from its target than a motor holding it."""
        positions = self.joint_states().positions
        return any(abs(self.arm_targets[name] - position) > _HOLDING_ERROR
                   for name, position in zip(ARM_JOINTS, positions))

    def hold_arm(self, back_off: float = 0.0) -> dict[str, float]:
        """Hold the arm where it is, or ``back_off`` rad back the way it was going; return it.

        Backing off takes the load off a contact the arm was driven into: held exactly where
        it pressed, each motor would go on pushing with its full torque against the contact.
        The way back is the reverse of the joints' remaining travel to their targets, scaled
        so that the joint with the most travel moves ``back_off``.
        """
        positions = self.joint_states().positions[:len(ARM_JOINTS)]
        travel = [self.arm_targets[name] - position
                  for name, position in zip(ARM_JOINTS, positions)]
        largest = max(abs(t) for t in travel)
        scale = back_off / largest if largest > _HOLDING_ERROR else 0.0
        return self.set_arm_targets({name: position - scale * t for name, position, t
                                     in zip(ARM_JOINTS, positions, travel)})

    def link_pose(self, link: str = TCP_LINK) -> tuple[tuple, tuple]:
        """Return the world position and xyzw orientation of a robot link."""
        state = self._p.getLinkState(self.robot, self._link_index[link],
                                     computeForwardKinematics=True)
        return state[4], state[5]

    def link_index(self, link: str) -> int:
        """Return pybullet's index of a robot link (for contact and collision queries)."""
        return self._link_index[link]

    def body_position(self, body: int) -> tuple[float, float, float]:
        """Return the world position of a body's base (e.g. ``world.ball``)."""
        return self._p.getBasePositionAndOrientation(body)[0]

    def body_pose(self, body: int) -> tuple[tuple, tuple]:
        """Return the world position and xyzw orientation of a body's base."""
        return self._p.getBasePositionAndOrientation(body)

    def set_ball_position(self, position: Sequence[float]) -> None:
        """Move the ball to ``position`` at rest."""
        self._p.resetBasePositionAndOrientation(self.ball, list(position), [0, 0, 0, 1])
        self._p.resetBaseVelocity(self.ball, [0, 0, 0], [0, 0, 0])

    def set_robot_collisions(self, body: int, enabled: bool) -> None:
        """Let the arm and gripper touch ``body`` (e.g. ``world.ball``), or pass through it."""
        for link in range(-1, self._p.getNumJoints(self.robot)):
            self._p.setCollisionFilterPair(self.robot, body, link, -1, int(enabled))

    def set_ball_color(self, rgba: Sequence[float]) -> None:
        """Repaint the ball."""
        self._p.changeVisualShape(self.ball, -1, rgbaColor=list(rgba))

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

    # -- test scenery -------------------------------------------------------------------------

    def add_box(self, position: Sequence[float], half_extents: Sequence[float],
                rgba: Sequence[float], mass: float = 0.1) -> int:
        """Add a box (e.g. a red cube that is not a ball) and return its body id."""
        body = self._p.createMultiBody(
            mass, self._p.createCollisionShape(pybullet.GEOM_BOX, halfExtents=list(half_extents)),
            self._p.createVisualShape(pybullet.GEOM_BOX, halfExtents=list(half_extents),
                                      rgbaColor=list(rgba)),
            basePosition=list(position))
        self.extra_bodies.append(body)
        return body

    def add_sphere(self, position: Sequence[float], radius: float, rgba: Sequence[float],
                   mass: float = BALL_MASS) -> int:
        """Add another sphere (e.g. a ball of another colour) and return its body id."""
        body = self._p.createMultiBody(
            mass, self._p.createCollisionShape(pybullet.GEOM_SPHERE, radius=radius),
            self._p.createVisualShape(pybullet.GEOM_SPHERE, radius=radius, rgbaColor=list(rgba)),
            basePosition=list(position))
        self.extra_bodies.append(body)
        return body

    def add_disc(self, position: Sequence[float], radius: float, height: float,
                 rgba: Sequence[float], mass: float = 0.0) -> int:
        """Add an upright cylinder (a flat disc when low) and return its body id."""
        body = self._p.createMultiBody(
            mass, self._p.createCollisionShape(pybullet.GEOM_CYLINDER, radius=radius,
                                               height=height),
            self._p.createVisualShape(pybullet.GEOM_CYLINDER, radius=radius, length=height,
                                      rgbaColor=list(rgba)),
            basePosition=list(position))
        self.extra_bodies.append(body)
        return body

    def set_scene_objects(self, objects: Sequence[SceneObject]) -> None:
        """Replace the static scenery set last time (not the ball) with ``objects``."""
        self.remove_bodies(self._scene_objects)
        self._scene_objects = []
        for item in objects:
            rgba = (*item.color, 1.0)
            position = (item.x, item.y, item.size[2])
            if item.shape == 'disc':
                body = self.add_disc(position, item.size[0], 2 * item.size[2], rgba)
            else:
                body = self.add_box(position, item.size, rgba, mass=0.0)
            self._p.resetBasePositionAndOrientation(
                body, position, pybullet.getQuaternionFromEuler([0, 0, item.yaw]))
            self._scene_objects.append(body)

    def remove_bodies(self, bodies: Iterable[int]) -> None:
        """Remove bodies added with :meth:`add_box` or :meth:`add_sphere`."""
        for body in list(bodies):
            self._p.removeBody(body)
            self.extra_bodies.remove(body)

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
