"""The transform tree of the sim: URDF joints, camera frames, world anchors. Plain Python, no ROS.

tf2_ros is not on PyPI, so turning joint positions into parent->child transforms (what
robot_state_publisher does) is done here. A transform is a pair (translation xyz, rotation as
a unit quaternion xyzw), plain tuples: for the 6 + 2 moving joints at 100 Hz, float arithmetic
is several times cheaper than small numpy arrays.

Frames follow the URDF the sim loads, with two differences:

* ``world`` is the sim's world frame. The URDF's own root (also named ``world`` in the UR
  description) is replaced by where pybullet really has the arm: world->``base_link`` comes from
  the physics engine, so a pedestal or any base placement shows up in the tree.
* ``camera_link`` (REP 103 body frame: x forward, y left, z up) sits at ``camera_position``
  with x toward ``camera_look_at``; its child ``camera_color_optical_frame`` (x right, y down,
  z forward) is the frame of the camera images, the rotation of ``camera_pose.optical_rotation``.
"""

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np
import pybullet
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import WORLD_FRAME
from ur_rg2_common.tf_buffer import quaternion_from_matrix

from ur_rg2_sim.robot_model import package_uri

Vector = tuple[float, float, float]
Quaternion = tuple[float, float, float, float]  # x, y, z, w
Transform = tuple[Vector, Quaternion]
# (parent frame, child frame, translation, rotation)
FrameTransform = tuple[str, str, Vector, Quaternion]

CAMERA_FRAME = 'camera_link'
OPTICAL_FRAME = 'camera_color_optical_frame'
IDENTITY: Transform = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
# camera_link -> optical frame: optical x = -link y, optical y = -link z, optical z = link x.
OPTICAL_IN_CAMERA_LINK: Quaternion = (-0.5, 0.5, -0.5, 0.5)

_MOVING = ('revolute', 'continuous', 'prismatic')


class FrameError(ValueError):
    """The URDF cannot be turned into a transform tree."""


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint: the child's frame is ``origin`` from the parent's, then the motion."""

    name: str
    kind: str
    parent: str
    child: str
    origin: Transform
    axis: Vector


def parse_joints(urdf: str) -> list[UrdfJoint]:
    """Return the joints of URDF text ``urdf``, in document order."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as error:
        raise FrameError(f'the URDF does not parse: {error}') from error
    joints = []
    for joint in root.iter('joint'):
        kind = joint.get('type')
        if kind not in (*_MOVING, 'fixed'):
            raise FrameError(f"joint {joint.get('name')}: type {kind!r} is not supported")
        origin = joint.find('origin')
        xyz = _floats(origin, 'xyz', 3)
        rpy = _floats(origin, 'rpy', 3)
        axis = _floats(joint.find('axis'), 'xyz', 3, default=(1.0, 0.0, 0.0))
        norm = math.sqrt(sum(a * a for a in axis))
        if kind != 'fixed' and norm < 1e-12:
            raise FrameError(f"joint {joint.get('name')}: zero axis")
        joints.append(UrdfJoint(
            joint.get('name'), kind, joint.find('parent').get('link'),
            joint.find('child').get('link'), (xyz, quaternion_from_rpy(*rpy)),
            tuple(a / (norm or 1.0) for a in axis)))
    return joints


def root_link(joints: Sequence[UrdfJoint]) -> str:
    """Return the one link of the tree that is no joint's child."""
    children = {joint.child for joint in joints}
    roots = {joint.parent for joint in joints} - children
    if len(roots) != 1:
        raise FrameError(f'the URDF must have one root link, found {sorted(roots)}')
    return roots.pop()


def world_anchors(world, joints: Sequence[UrdfJoint]) -> dict[str, Transform]:
    """Return the pose in the sim's world of each link hung directly from ``world``.

    ``world`` is a :class:`ur_rg2_sim.world.SimWorld`; call this on its thread. When the URDF's
    root is a link named ``world`` (the UR description), its children are placed where pybullet
    has them; otherwise the root link is placed where pybullet has the robot's base.
    """
    root = root_link(joints)
    if root == WORLD_FRAME:
        return {joint.child: tuple(map(tuple, world.link_pose(joint.child)))
                for joint in joints if joint.parent == root}
    # pybullet's base pose is the base's centre of mass; the link frame is offset from it.
    com_position, com_orientation = pybullet.getBasePositionAndOrientation(
        world.robot, physicsClientId=world.client)
    inertial_position, inertial_orientation = pybullet.getDynamicsInfo(
        world.robot, -1, physicsClientId=world.client)[3:5]
    inverse = pybullet.invertTransform(inertial_position, inertial_orientation)
    position, orientation = pybullet.multiplyTransforms(
        com_position, com_orientation, *inverse)
    return {root: (tuple(position), tuple(orientation))}


def camera_transforms(position: Sequence[float], look_at: Sequence[float]) -> list[FrameTransform]:
    """Return world->camera_link and camera_link->camera_color_optical_frame."""
    optical = optical_rotation(position, look_at)
    # Body axes from the optical ones: forward = optical z, left = -optical x, up = -optical y.
    body = np.column_stack([optical[:, 2], -optical[:, 0], -optical[:, 1]])
    return [
        (WORLD_FRAME, CAMERA_FRAME, tuple(float(v) for v in position),
         quaternion_from_matrix(body)),
        (CAMERA_FRAME, OPTICAL_FRAME, (0.0, 0.0, 0.0), OPTICAL_IN_CAMERA_LINK),
    ]


class FrameTree:
    """Static and moving transforms of the URDF's joints, hung from the sim's ``world``."""

    def __init__(self, joints: Sequence[UrdfJoint], anchors: Mapping[str, Transform]) -> None:
        root = root_link(joints)
        # The URDF's own world link is the sim's world; its joints give way to the anchors.
        kept = [j for j in joints if not (root == WORLD_FRAME and j.parent == root)]
        self.static: list[FrameTransform] = [
            (WORLD_FRAME, link, *pose) for link, pose in anchors.items()]
        self.static += [(j.parent, j.child, *j.origin) for j in kept if j.kind == 'fixed']
        self.moving = [j for j in kept if j.kind != 'fixed']
        self.moving_joint_names = tuple(j.name for j in self.moving)
        # Precomputed per moving joint (see transforms()): a revolute joint's rotation is
        # q_origin * (axis sin(a/2), cos(a/2)) = cos(a/2) q_origin + sin(a/2) (q_origin * axis),
        # a prismatic joint's translation is t_origin + d (R_origin axis).
        self._terms = []
        for joint in self.moving:
            (t, q) = joint.origin
            if joint.kind == 'prismatic':
                self._terms.append((True, t, q, rotate(q, joint.axis)))
            else:
                self._terms.append((False, t, q, quaternion_multiply(q, (*joint.axis, 0.0))))
        frames = [WORLD_FRAME] + [child for _, child, _, _ in self.static]
        frames += [j.child for j in self.moving]
        if len(set(frames)) != len(frames):
            raise FrameError('a frame appears twice in the tree')
        self.frames = tuple(frames)

    def transforms(self, positions: Sequence[float]) -> list[FrameTransform]:
        """Return parent->child of each moving joint (``positions`` as ``moving_joint_names``)."""
        result = []
        for joint, (prismatic, t, q, term), position in zip(self.moving, self._terms, positions):
            if prismatic:
                translation = (t[0] + position * term[0], t[1] + position * term[1],
                               t[2] + position * term[2])
                result.append((joint.parent, joint.child, translation, q))
            else:
                c, s = math.cos(position / 2), math.sin(position / 2)
                result.append((joint.parent, joint.child, t, (
                    c * q[0] + s * term[0], c * q[1] + s * term[1], c * q[2] + s * term[2],
                    c * q[3] + s * term[3])))
        return result


def load_frame_tree(world, urdf: Path) -> FrameTree:
    """Return the tree of the URDF file ``urdf`` that ``world`` (a SimWorld) simulates."""
    joints = parse_joints(urdf.read_text())
    return FrameTree(joints, world_anchors(world, joints))


def robot_description(urdf: Path) -> str:
    """Return the URDF text with every mesh filename a URI, as ROS tools read them.

    The sim's shipped meshes become ``package://ur_rg2_sim/...`` URIs (found through the ament
    index wherever the package is installed, after the sim has stopped); any other file its
    absolute ``file://`` URI.
    """
    root = ET.parse(urdf).getroot()
    for mesh in root.iter('mesh'):
        filename = mesh.get('filename', '')
        if '://' not in filename:
            mesh.set('filename', package_uri(urdf.parent / filename))
    return ET.tostring(root, encoding='unicode')


# -- small rigid-transform algebra -------------------------------------------------------------

def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> Quaternion:
    """Return the xyzw quaternion of URDF's fixed-axis roll, pitch, yaw (Rz Ry Rx)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def quaternion_multiply(a: Sequence[float], b: Sequence[float]) -> Quaternion:
    """Return the Hamilton product ``a * b`` of two xyzw quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def rotate(q: Sequence[float], v: Sequence[float]) -> Vector:
    """Return vector ``v`` rotated by the unit quaternion ``q``."""
    x, y, z, _ = quaternion_multiply(quaternion_multiply(q, (*v, 0.0)),
                                     (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def _floats(element, attribute: str, count: int,
            default: Sequence[float] = (0.0, 0.0, 0.0)) -> tuple[float, ...]:
    if element is None or element.get(attribute) is None:
        return tuple(default)
    values = tuple(float(v) for v in element.get(attribute).split())
    if len(values) != count:
        raise FrameError(f'{attribute}="{element.get(attribute)}" needs {count} numbers')
    return values
