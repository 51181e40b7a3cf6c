"""The world's scenery: floor, pedestal, ball and the test scenery (boxes, spheres, discs).

A mixin of :class:`ur_rg2_sim.world.SimWorld` (its pybullet client ``self._p``).
"""

from collections.abc import Iterable, Sequence

import pybullet
from ur_rg2_common.scene_objects import SceneObject

from ur_rg2_sim.contacts import _BALL_FRICTION, _BALL_ROLLING_FRICTION, _BALL_SPINNING_FRICTION

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
BALL_MASS = 0.05  # kg, a light foam ball the RG2's 40 N holds easily


class SceneMixin:
    """Floor, pedestal, ball and other bodies of a SimWorld."""

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

    def set_ball_color(self, rgba: Sequence[float]) -> None:
        """Repaint the ball."""
        self._p.changeVisualShape(self.ball, -1, rgbaColor=list(rgba))

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
