"""URDF of a UR arm (from example-robot-data) with an OnRobot RG2 gripper on its tool flange.

The UR kinematics, limits and meshes are the maintained `example-robot-data` ones. Two changes
are made for the simulator:

* Each link's visual is the link's collision mesh (the same real UR shape, far fewer
  triangles than the COLLADA visual) with a flat colour: pybullet's CPU renderer spends its
  time per triangle, and the COLLADA meshes cost ~37 ms per 640x480 frame against ~13 ms.
  The STL files carry zero facet normals, which render black, so they are converted to OBJ
  with computed normals (:func:`convert_meshes`).
* Those OBJ files ship in this package's share directory, ``meshes/MODEL/LINK.obj``
  (``scripts/robot_meshes.py`` writes them; ``meshes/PROVENANCE.md``), so a URDF names them as
  ``package://ur_rg2_sim/meshes/...`` resources (:func:`package_uri`), which outlive the sim.
  The URDF written for pybullet names the installed files by absolute path, which it needs.

The RG2 is modelled from its datasheet: 0-110 mm stroke, 3-40 N grip force, two parallel
fingers. Its linkage is simplified to two prismatic fingers moving symmetrically, each with a
rubber pad, so a finger joint's position is half the opening between the pads.
"""

from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
import xml.etree.ElementTree as ET

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
import numpy as np
from ur_rg2_common.contract import RG2_MAX_FORCE, RG2_MAX_OPENING

ROBOT_MODELS = ('ur5', 'ur3')
PACKAGE = 'ur_rg2_sim'
MESHES = 'meshes'  # the arm's OBJ files in the share directory: meshes/MODEL/LINK.obj

FLANGE_LINK = 'tool0'
TCP_LINK = 'rg2_tcp'

# RG2 datasheet values.
RG2_MIN_FORCE = 3.0  # N
RG2_MAX_FINGER_SPEED = 0.127 / 2  # m/s per finger (datasheet closing speed 38-127 mm/s)
RG2_MASS = 0.78  # kg

# Simplified RG2 geometry in the flange frame (z out of the flange), metres.
_HOUSING_SIZE = (0.05, 0.08, 0.125)
_HOUSING_BASE = 0.012  # flange adapter thickness
_FINGER_SIZE = (0.022, 0.012, 0.065)  # width (x), thickness (y), length (z)
_FINGER_CENTRE_Z = _HOUSING_BASE + _HOUSING_SIZE[2] + _FINGER_SIZE[2] / 2
_TCP_Z = _FINGER_CENTRE_Z + 0.01  # between the pads, a little below their middle

_ARM_COLOUR = '0.78 0.79 0.81 1'
_JOINT_COLOUR = '0.30 0.42 0.58 1'
_GRIPPER_COLOUR = '0.92 0.92 0.92 1'
_PAD_COLOUR = '0.12 0.12 0.12 1'
_JOINT_LINKS = {'base_link', 'shoulder_link', 'wrist_1_link', 'wrist_2_link', 'wrist_3_link'}


class RobotModelError(ValueError):
    """The requested robot model cannot be built."""


@dataclass(frozen=True)
class JointLimit:
    """Position and velocity limits of one joint, from the URDF."""

    lower: float
    upper: float
    velocity: float
    effort: float


def example_robot_data_share() -> Path:
    """Return the ``share/example-robot-data`` directory of the installed wheel."""
    try:
        dist = metadata.distribution('example-robot-data')
    except metadata.PackageNotFoundError as exc:
        raise RobotModelError(
            'the example-robot-data package is not installed (pip install example-robot-data)'
        ) from exc
    marker = 'robots/ur_description/urdf/ur5_robot.urdf'
    for file in dist.files or ():
        if str(file).endswith(marker):
            return Path(dist.locate_file(file)).parents[3]
    raise RobotModelError('example-robot-data is installed but has no ur_description URDFs')


def package_share() -> Path:
    """Return this package's installed share directory (the ament index's), or raise."""
    try:
        return Path(get_package_share_directory(PACKAGE))
    except (PackageNotFoundError, OSError) as exc:
        raise RobotModelError(
            f'{PACKAGE} is not in the ament index, so its meshes are not found: source '
            'scripts/env.sh (or a colcon install/setup.bash) first') from exc


def package_uri(path: Path) -> str:
    """Return the ``package://`` URI of a file of this package's share directory.

    Any other file is named by its absolute ``file://`` URI.
    """
    share = package_share()
    if path.is_relative_to(share):
        return f'package://{PACKAGE}/{path.relative_to(share).as_posix()}'
    return path.resolve().as_uri()


def write_robot_urdf(robot_model: str, directory: Path) -> Path:
    """Write the URDF of arm ``robot_model`` with the RG2 to ``directory``, for pybullet.

    Its meshes are the installed ones of this package's share directory, by absolute path.
    """
    root, _ = _source_urdf(robot_model)
    meshes = package_share() / MESHES / robot_model
    for link in root.iter('link'):
        _use_collision_mesh_as_visual(link, meshes)
    for element in _rg2_elements():
        root.append(element)
    urdf = directory / f'{robot_model}_rg2.urdf'
    ET.ElementTree(root).write(urdf, encoding='unicode')
    return urdf


def convert_meshes(robot_model: str, directory: Path) -> list[Path]:
    """Write each arm link's collision mesh as ``directory/LINK.obj``; return the files.

    The files this package ships in ``meshes/MODEL/`` (``scripts/robot_meshes.py``).
    """
    root, share = _source_urdf(robot_model)
    written = []
    for link in root.iter('link'):
        mesh = link.find('collision/geometry/mesh')
        if mesh is not None and link.find('visual') is not None:
            written.append(directory / f"{link.get('name')}.obj")
            stl_to_obj(Path(_resolve(mesh.get('filename'), share)), written[-1])
    return written


def joint_limits(urdf: Path) -> dict[str, JointLimit]:
    """Return the limits of every revolute or prismatic joint of the URDF file ``urdf``."""
    limits = {}
    for joint in ET.parse(urdf).getroot().iter('joint'):
        limit = joint.find('limit')
        if joint.get('type') in ('revolute', 'prismatic') and limit is not None:
            limits[joint.get('name')] = JointLimit(
                float(limit.get('lower')), float(limit.get('upper')),
                float(limit.get('velocity')), float(limit.get('effort')))
    return limits


def _source_urdf(robot_model: str) -> tuple[ET.Element, Path]:
    """Return example-robot-data's URDF of ``robot_model``, and that package's share.

    Gazebo plugins and transmissions, which only slow the parser, are left out.
    """
    if robot_model not in ROBOT_MODELS:
        raise RobotModelError(
            f"robot_model must be one of {', '.join(ROBOT_MODELS)}, got {robot_model!r}")
    share = example_robot_data_share()
    source = share / 'robots' / 'ur_description' / 'urdf' / f'{robot_model}_robot.urdf'
    root = ET.parse(source).getroot()
    for element in list(root):
        if element.tag in ('gazebo', 'transmission'):
            root.remove(element)
    return root, share


def _resolve(filename: str, share: Path) -> str:
    prefix = 'package://example-robot-data/'
    if filename.startswith(prefix):
        return str(share / filename[len(prefix):])
    return filename


def _use_collision_mesh_as_visual(link: ET.Element, meshes: Path) -> None:
    collision_mesh = link.find('collision/geometry/mesh')
    visual = link.find('visual')
    if collision_mesh is None or visual is None:
        return
    obj = meshes / f"{link.get('name')}.obj"
    if not obj.is_file():
        raise RobotModelError(f'{obj} is missing: the package is installed without its meshes')
    collision_mesh.set('filename', str(obj))
    visual.find('geometry/mesh').set('filename', str(obj))
    colour = _JOINT_COLOUR if link.get('name') in _JOINT_LINKS else _ARM_COLOUR
    for material in visual.findall('material'):
        visual.remove(material)
    material = ET.SubElement(visual, 'material', name=f"{link.get('name')}_colour")
    ET.SubElement(material, 'color', rgba=colour)


def stl_to_obj(stl: Path, obj: Path) -> None:
    """Convert a binary STL mesh to OBJ with smooth, area-weighted vertex normals."""
    data = stl.read_bytes()
    count = int(np.frombuffer(data, '<u4', count=1, offset=80)[0])
    facet = np.dtype([('normal', '<f4', 3), ('vertices', '<f4', (3, 3)), ('attr', '<u2')])
    triangles = np.frombuffer(data, facet, count=count, offset=84)['vertices'].astype(float)
    vertices, faces = np.unique(triangles.reshape(-1, 3), axis=0, return_inverse=True)
    faces = faces.reshape(-1, 3)
    # Cross products are twice the facet areas: summing them weights normals by area.
    facet_normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], facet_normals)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    lines = [f'v {x:.6f} {y:.6f} {z:.6f}' for x, y, z in vertices]
    lines += [f'vn {x:.4f} {y:.4f} {z:.4f}' for x, y, z in normals]
    lines += [f'f {a}//{a} {b}//{b} {c}//{c}' for a, b, c in faces + 1]
    obj.write_text('\n'.join(lines) + '\n')


def _box_link(name: str, mass: float, boxes: list[tuple[tuple, tuple, str]]) -> ET.Element:
    """Return a link made of boxes, each given as (size, centre, rgba)."""
    link = ET.Element('link', name=name)
    inertial = ET.SubElement(link, 'inertial')
    ET.SubElement(inertial, 'mass', value=f'{mass}')
    (sx, sy, sz), centre, _ = boxes[0] if boxes else ((0.01, 0.01, 0.01), (0, 0, 0), '')
    ET.SubElement(inertial, 'origin', xyz=' '.join(f'{v}' for v in centre), rpy='0 0 0')
    ET.SubElement(inertial, 'inertia', ixx=f'{mass * (sy * sy + sz * sz) / 12}', ixy='0',
                  ixz='0', iyy=f'{mass * (sx * sx + sz * sz) / 12}', iyz='0',
                  izz=f'{mass * (sx * sx + sy * sy) / 12}')
    for size, centre, rgba in boxes:
        for tag in ('visual', 'collision'):
            element = ET.SubElement(link, tag)
            ET.SubElement(element, 'origin', xyz=' '.join(f'{v}' for v in centre), rpy='0 0 0')
            geometry = ET.SubElement(element, 'geometry')
            ET.SubElement(geometry, 'box', size=' '.join(f'{v}' for v in size))
            if tag == 'visual':
                material = ET.SubElement(element, 'material', name=f'{name}_{rgba}')
                ET.SubElement(material, 'color', rgba=rgba)
    return link


def _joint(name: str, kind: str, parent: str, child: str, xyz: tuple,
           axis: tuple = (0, 0, 1), limit: dict | None = None) -> ET.Element:
    joint = ET.Element('joint', name=name, type=kind)
    ET.SubElement(joint, 'parent', link=parent)
    ET.SubElement(joint, 'child', link=child)
    ET.SubElement(joint, 'origin', xyz=' '.join(f'{v}' for v in xyz), rpy='0 0 0')
    ET.SubElement(joint, 'axis', xyz=' '.join(f'{v}' for v in axis))
    if limit is not None:
        ET.SubElement(joint, 'limit', **{k: f'{v}' for k, v in limit.items()})
    return joint


def _rg2_elements() -> list[ET.Element]:
    hx, hy, hz = _HOUSING_SIZE
    body = _box_link('rg2_body', RG2_MASS - 0.12, [
        (_HOUSING_SIZE, (0, 0, _HOUSING_BASE + hz / 2), _GRIPPER_COLOUR),
        ((0.07, 0.07, _HOUSING_BASE), (0, 0, _HOUSING_BASE / 2), _PAD_COLOUR),
    ])
    fx, fy, fz = _FINGER_SIZE
    pad = 0.004
    finger_limit = {'lower': 0.0, 'upper': RG2_MAX_OPENING / 2, 'effort': RG2_MAX_FORCE,
                    'velocity': RG2_MAX_FINGER_SPEED}
    elements = [body, _joint('rg2_mount_joint', 'fixed', FLANGE_LINK, 'rg2_body', (0, 0, 0))]
    for side, sign in (('left', 1), ('right', -1)):
        # The finger frame sits on the closed inner pad face, so the joint position is the
        # pad's travel from the centre line: half the opening.
        link = f'rg2_{side}_finger'
        elements.append(_box_link(link, 0.06, [
            ((fx, fy - pad, fz), (0, sign * (pad + (fy - pad) / 2), 0), _GRIPPER_COLOUR),
            ((fx, pad, fz * 0.8), (0, sign * pad / 2, fz * 0.1), _PAD_COLOUR),
        ]))
        elements.append(_joint(f'rg2_{side}_finger_joint', 'prismatic', 'rg2_body', link,
                               (0, 0, _FINGER_CENTRE_Z), axis=(0, sign, 0),
                               limit=finger_limit))
    # A massless frame would be given 1 kg by pybullet; a gram keeps the dynamics honest.
    tcp = _box_link(TCP_LINK, 0.001, [])
    elements += [tcp, _joint('rg2_tcp_joint', 'fixed', 'rg2_body', TCP_LINK, (0, 0, _TCP_Z))]
    return elements
