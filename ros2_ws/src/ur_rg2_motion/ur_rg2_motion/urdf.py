"""The robot description (URDF text) as the kinematics reads it: joints, chain, limits.

ur_rg2_sim.frames parses the whole tree for the sim, but imports pybullet; this module needs
only the fixed joints and the arm's limits, without it. Plain Python.
"""

from collections.abc import Sequence
import math
import xml.etree.ElementTree as ET

import numpy as np
from ur_rg2_common.contract import ARM_JOINTS

from ur_rg2_motion.closed_form import KinematicsError

BASE_LINK = 'base_link'
FLANGE = 'tool0'


def urdf_joints(urdf: str) -> dict[str, tuple]:
    """Return each joint by its child link: (name, type, parent, origin at zero, axis)."""
    try:
        root = ET.fromstring(urdf)
    except ET.ParseError as error:
        raise KinematicsError(
            'invalid', f'the robot description does not parse: {error}') from None
    joints = {}
    for joint in root.iter('joint'):
        origin = joint.find('origin')
        roll, pitch, yaw = _floats(origin, 'rpy')
        axis = joint.find('axis')
        joints[joint.find('child').get('link')] = (
            joint.get('name'), joint.get('type'), joint.find('parent').get('link'),
            _rpy_matrix(_floats(origin, 'xyz'), roll, pitch, yaw),
            np.array(_floats(axis, 'xyz') if axis is not None else (1.0, 0.0, 0.0)))
    return joints


def urdf_chain(urdf: str) -> dict[tuple[str, str], np.ndarray]:
    """Return each joint's origin (parent -> child at zero motion) by (parent, child)."""
    return {(parent, child): origin
            for child, (_, _, parent, origin, _) in urdf_joints(urdf).items()}


def _arm_path(joints: dict[str, tuple]) -> list[tuple]:
    """Return the joints from base_link to tool0, checking that the six arm joints are on it."""
    missing = [frame for frame in (BASE_LINK, FLANGE)
               if frame not in joints and not any(j[2] == frame for j in joints.values())]
    if missing:
        raise KinematicsError('invalid', f"the robot description has no {' or '.join(missing)} "
                              'frame')
    path, link = [], FLANGE
    while link != BASE_LINK:
        if link not in joints:
            raise KinematicsError('invalid', f'the robot description has no chain from '
                                  f'{BASE_LINK} to {FLANGE} (it stops at {link})')
        path.append(joints[link])
        link = joints[link][2]
    path.reverse()
    names = [joint[0] for joint in path if joint[1] != 'fixed']
    absent = [name for name in ARM_JOINTS if name not in names]
    if absent or names != list(ARM_JOINTS):
        raise KinematicsError(
            'invalid', f"the robot description's chain from {BASE_LINK} to {FLANGE} "
            + (f"lacks {', '.join(absent)}" if absent else f"moves {', '.join(names)}, not the "
               'six UR arm joints in order'))
    return path


def _chain_pose(path: list[tuple], q: Sequence[float]) -> np.ndarray:
    """Return base_link -> tool0 along the description's joints at arm joints ``q``."""
    pose = np.eye(4)
    angles = iter(q)
    for _, kind, _, origin, axis in path:
        pose = pose @ origin
        if kind != 'fixed':
            pose = pose @ _axis_rotation(axis, next(angles))
    return pose


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis / np.linalg.norm(axis)
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    m = np.eye(4)
    m[:3, :3] = [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
                 [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
                 [t * x * z - s * y, t * y * z + s * x, t * z * z + c]]
    return m


def _finite_offset(offset: Sequence[float]) -> tuple[float, float, float]:
    values = tuple(float(v) for v in offset)
    if len(values) != 3 or not all(map(math.isfinite, values)):
        raise KinematicsError('invalid', f'the TCP offset {list(values)} is not [x, y, z] in m')
    return values


def fixed_transform(chain: dict[tuple[str, str], np.ndarray], ancestor: str,
                    frame: str) -> np.ndarray:
    """Return ``ancestor`` -> ``frame`` through the joints of ``chain`` (at zero motion)."""
    parents = {child: (parent, pose) for (parent, child), pose in chain.items()}
    pose = np.eye(4)
    link = frame
    while link != ancestor:
        if link not in parents:
            raise KinematicsError(
                'invalid', f'the robot description has no chain from {ancestor} to {frame}')
        parent, edge = parents[link]
        pose = edge @ pose
        link = parent
    return pose


def urdf_joint_limits(urdf: str) -> dict[str, tuple[float, float]]:
    """Return (lower, upper) of each revolute joint of robot description text ``urdf``."""
    limits = {}
    for joint in ET.fromstring(urdf).iter('joint'):
        limit = joint.find('limit')
        if joint.get('type') == 'revolute' and limit is not None:
            limits[joint.get('name')] = (float(limit.get('lower')), float(limit.get('upper')))
        elif joint.get('type') == 'continuous':
            limits[joint.get('name')] = (-math.inf, math.inf)
    return limits


def _finger_half(urdf: str) -> float:
    # The finger links' boxes are centred on the finger frame: half the longest box is how far
    # the pads reach past it along the gripper's z.
    halves = [0.0]
    for link in ET.fromstring(urdf).iter('link'):
        if link.get('name', '').endswith('_finger'):
            for box in link.iter('box'):
                halves.append(float(box.get('size').split()[2]) / 2)
    return max(halves)


def _floats(element, attribute: str) -> tuple[float, float, float]:
    if element is None or element.get(attribute) is None:
        return (0.0, 0.0, 0.0)
    x, y, z = (float(v) for v in element.get(attribute).split())
    return (x, y, z)


def _rpy_matrix(xyz: Sequence[float], roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    m[:3, 3] = xyz
    return m
