"""The arm and the gripper: joint targets, coordinated moves, the RG2's fingers.

A mixin of :class:`ur_rg2_sim.world.SimWorld` (its pybullet client ``self._p``).
"""

from collections.abc import Mapping, Sequence
import math
from typing import Optional

import pybullet
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS, RG2_MAX_FORCE, RG2_MAX_OPENING

from ur_rg2_sim.contacts import _HOLDING_ERROR
from ur_rg2_sim.robot_model import RG2_MAX_FINGER_SPEED, RG2_MIN_FORCE

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


class ArmMixin:
    """The arm's motors and poses of a SimWorld."""

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

    def place_robot(self, positions: Sequence[float]) -> None:
        """Put the arm and gripper joints (``joint_names`` order) at ``positions``, motors unset.

        For a world that only tries poses (ur_rg2_sim.planning), never stepped.
        """
        for index, position in zip(self._indices, positions):
            self._p.resetJointState(self.robot, index, position, 0.0)

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


class GripperMixin:
    """The RG2's motors and state of a SimWorld."""

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
        # One pybullet call for both fingers (the learning environments ask every step).
        return sum(self._finger_positions())

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
        # The fingers are read only when they are judged: this runs before every step of a
        # gripper action (and of the environments' wait for the fingers).
        if self._finger_probe is None:
            self._finger_probe = (self._steps, self._finger_positions())
            return False
        steps, before = self._finger_probe
        if (self._steps - steps) * self.dt >= _FINGER_SPEED_WINDOW:
            positions = self._finger_positions()
            elapsed = (self._steps - steps) * self.dt
            self._finger_moving = any(abs(a - b) / elapsed >= _FINGER_STOPPED_SPEED
                                      for a, b in zip(positions, before))
            self._finger_probe = (self._steps, positions)
        return not self._finger_moving

    def _finger_positions(self) -> list[float]:
        return [state[0] for state in self._p.getJointStates(self.robot, self._finger_indices)]

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
        positions = self._finger_positions()
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
