"""What touches what: contact settings, the robot's self-collision pairs, contacts, clearance.

A mixin of :class:`ur_rg2_sim.world.SimWorld` (its pybullet client ``self._p``).
"""

from dataclasses import dataclass
import functools
import math

import pybullet
from ur_rg2_common.contract import ARM_JOINTS, RG2_MAX_FORCE

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


@dataclass(frozen=True)
class Contact:
    """A robot link pressing on an obstacle: the floor, the pedestal or another robot link."""

    link: str
    obstacle: str  # 'floor', 'pedestal' or the other link's name
    force: float  # N, along the normal
    approach: float  # m the joints' targets would take the link into the obstacle (<0: away)
    incidence: float  # sine of the angle of that motion into the surface: 1 head-on, 0 along




class ContactsMixin:
    """Contact settings and queries of a SimWorld."""

    def _configure_contacts(self) -> None:
        # The robot's contact points of the last step, as pybullet gives them: asked before
        # every step, so bound once, with positional arguments (the cheapest call).
        self.robot_contact_points = functools.partial(
            pybullet.getContactPoints, self.robot, -1, -2, -2, self.client)
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

    def obstacle_contacts(self, points: tuple | None = None) -> list[Contact]:
        """Return the links pressing on the floor, the pedestal or the arm (last step).

        One Contact per link and obstacle: ``force`` is the sum over its contact points,
        ``approach`` how far the most loaded point would move into the obstacle if every arm
        joint went from where it is to its target (the Jacobian there times the joints'
        remaining travel): positive while a command drives the link into it; ``incidence``
        the sine of the angle between that motion and the obstacle's surface. A joint within
        ``_HOLDING_ERROR`` of its target counts as holding, not moving. ``points``: those of
        :attr:`robot_contact_points` when the caller has them already.
        """
        if points is None:
            points = self.robot_contact_points()
        if not points:
            return []
        pairs: dict[tuple[int, int, int], list] = {}
        for c in points:
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

    def set_robot_collisions(self, body: int, enabled: bool) -> None:
        """Let the arm and gripper touch ``body`` (e.g. ``world.ball``), or pass through it."""
        for link in range(-1, self._p.getNumJoints(self.robot)):
            self._p.setCollisionFilterPair(self.robot, body, link, -1, int(enabled))
