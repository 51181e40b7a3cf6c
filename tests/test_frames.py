"""The transform tree (ur_rg2_sim.frames) against pybullet's own link poses, without ROS."""

import math
from pathlib import Path
from types import SimpleNamespace
from urllib.parse import urlparse
import xml.etree.ElementTree as ET

from ament_index_python.packages import get_package_share_directory
import numpy as np
import pybullet
import pytest
from tf_tree import buffer_of, ur_forward_kinematics
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS
from ur_rg2_common.tf_buffer import pose_matrix, quaternion_from_matrix
from ur_rg2_motion.kinematics import rotation_angle
from ur_rg2_sim.camera import Camera, CameraConfig
from ur_rg2_sim.frames import (
    FrameError,
    camera_transforms,
    load_frame_tree,
    parse_joints,
    robot_description,
)
from ur_rg2_sim.robot_model import ROBOT_MODELS, convert_meshes
from ur_rg2_sim.world import SimWorld, WorldConfig
import yaml


@pytest.fixture(params=ROBOT_MODELS)
def world_config(request) -> WorldConfig:
    return WorldConfig(robot_model=request.param)


def set_random_pose(world: SimWorld, rng: np.random.Generator) -> dict[str, float]:
    world.set_arm_positions({name: rng.uniform(-math.pi, math.pi) for name in ARM_JOINTS})
    client = world.client
    for index in range(pybullet.getNumJoints(world.robot, physicsClientId=client)):
        if pybullet.getJointInfo(world.robot, index, physicsClientId=client)[1].decode() in (
                GRIPPER_JOINTS):  # any finger opening
            pybullet.resetJointState(world.robot, index, rng.uniform(0, 0.055),
                                     physicsClientId=client)
    sample = world.joint_states()
    return dict(zip(sample.names, sample.positions))


def test_every_link_where_pybullet_has_it(world):
    tree = load_frame_tree(world, world.urdf)
    links = {link.get('name') for link in ET.parse(world.urdf).getroot().iter('link')}
    assert set(tree.frames) == links, 'the tree has exactly the URDF links'
    rng = np.random.default_rng(9)
    for _ in range(5):
        positions = set_random_pose(world, rng)
        received = buffer_of([*tree.static,
                              *tree.transforms([positions[n] for n in tree.moving_joint_names])])
        for link in links - {'world'}:
            position, orientation = world.link_pose(link)
            expected = pose_matrix(position, orientation)
            pose = received.lookup('world', link)
            assert np.allclose(pose[:3, 3], expected[:3, 3], atol=1e-6), link
            assert rotation_angle(pose, expected) < 1e-6, link


def test_base_to_tool0_is_the_ur_dh_kinematics(world):
    tree = load_frame_tree(world, world.urdf)
    rng = np.random.default_rng(3)
    for _ in range(10):
        positions = set_random_pose(world, rng)
        received = buffer_of([*tree.static,
                              *tree.transforms([positions[n] for n in tree.moving_joint_names])])
        expected = ur_forward_kinematics(world.config.robot_model,
                                         [positions[n] for n in ARM_JOINTS])
        pose = received.lookup('base', 'tool0')
        assert np.allclose(pose[:3, 3], expected[:3, 3], atol=1e-6)
        assert rotation_angle(pose, expected) < 1e-6


def test_world_to_base_link_follows_the_physics_base():
    world = SimWorld(WorldConfig())
    try:
        # Wherever pybullet has the arm, the tree hangs base_link there.
        moved = ((0.2, -0.1, 0.7), pybullet.getQuaternionFromEuler((0, 0, 0.3)))
        pybullet.resetBasePositionAndOrientation(world.robot, *moved,
                                                 physicsClientId=world.client)
        tree = load_frame_tree(world, world.urdf)
        pose = buffer_of(tree.static).lookup('world', 'base_link')
        assert np.allclose(pose, pose_matrix(*moved), atol=1e-9)
    finally:
        world.close()


@pytest.mark.parametrize('position, look_at', [
    ((1.3, -1.1, 0.95), (0.3, -0.1, 0.1)),
    ((0.0, 0.0, 2.0), (0.0, 0.0, 0.0)),  # straight down
    ((-1.0, 0.5, 0.3), (0.4, 0.2, 0.6)),
])
def test_camera_frames_match_the_renderer(position, look_at):
    world = SimWorld(WorldConfig())
    try:
        camera = Camera(world, CameraConfig(position=position, look_at=look_at))
        tree = buffer_of(camera_transforms(position, look_at))
        optical = tree.lookup('world', 'camera_color_optical_frame')
        point = np.array([0.3, -0.2, 0.4])
        in_optical = np.linalg.inv(optical) @ [*point, 1.0]
        assert np.allclose(in_optical[:3], camera.world_to_optical(point), atol=1e-9)
        # camera_link is REP 103: x toward the look-at point, y left, z up (no roll).
        link = tree.lookup('world', 'camera_link')
        forward = np.subtract(look_at, position)
        assert np.allclose(link[:3, 0], forward / np.linalg.norm(forward), atol=1e-9)
        assert abs(link[2, 1]) < 1e-9, 'camera_link y is horizontal'
    finally:
        world.close()


def test_quaternion_from_matrix_round_trips():
    rng = np.random.default_rng(1)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        back = quaternion_from_matrix(pose_matrix((0, 0, 0), q)[:3, :3])
        assert np.allclose(back, q * np.sign(q[3]), atol=1e-9)


def test_robot_description_names_the_installed_meshes_pybullet_draws(world):
    description = robot_description(world.urdf)
    meshes = {m.get('filename') for m in ET.fromstring(description).iter('mesh')}
    share = Path(get_package_share_directory('ur_rg2_sim'))
    model = world.config.robot_model
    # package:// URIs of the package's share directory, which outlive the sim, one per link.
    assert meshes == {f'package://ur_rg2_sim/meshes/{model}/{file.name}'
                      for file in (share / 'meshes' / model).glob('*.obj')}
    assert len(meshes) == 7
    for uri in meshes:
        assert (share / urlparse(uri).path.lstrip('/')).is_file(), uri
    # pybullet draws those same files (the camera renderers read the paths it reports).
    drawn = {shape[4].decode() for shape in pybullet.getVisualShapeData(
        world.robot, physicsClientId=world.client) if shape[4]}
    assert {Path(path).relative_to(share).as_posix() for path in drawn} == {
        urlparse(uri).path.lstrip('/') for uri in meshes}


@pytest.mark.parametrize('model', ROBOT_MODELS)
def test_shipped_meshes_are_the_converted_collision_meshes(model, tmp_path):
    """The files ur_rg2_sim ships are what scripts/robot_meshes.py writes (PROVENANCE.md)."""
    written = convert_meshes(model, tmp_path)
    shipped = Path(get_package_share_directory('ur_rg2_sim')) / 'meshes' / model
    assert sorted(file.name for file in shipped.glob('*.obj')) == sorted(
        file.name for file in written)
    for file in written:
        assert (shipped / file.name).read_bytes() == file.read_bytes(), file.name


@pytest.mark.parametrize('urdf, reason', [
    ('<robot', 'does not parse'),
    ('<robot><joint name="j" type="floating"><parent link="a"/><child link="b"/></joint>'
     '</robot>', "type 'floating'"),
    ('<robot><joint name="j" type="fixed"><origin xyz="1 2"/><parent link="a"/>'
     '<child link="b"/></joint></robot>', 'needs 3 numbers'),
])
def test_bad_urdf_is_refused_with_the_reason(urdf, reason):
    with pytest.raises(FrameError, match=reason):
        parse_joints(urdf)


def test_rviz_config_shows_the_contract_topics():
    config = yaml.safe_load((Path(__file__).parents[1] / 'config' / 'ur_rg2.rviz').read_text())
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == 'world'
    displays = {d['Class'].split('/')[-1] + ':' + d['Name']: d for d in manager['Displays']}
    model = displays['RobotModel:RobotModel']
    assert model['Description Source'] == 'Topic'
    assert model['Description Topic']['Value'] == '/robot_description'
    assert model['Description Topic']['Durability Policy'] == 'Transient Local'
    assert 'TF:TF' in displays
    images = {d['Topic']['Value'] for key, d in displays.items() if key.startswith('Image:')}
    assert images == {'/camera/color/image_raw', '/ball/image'}


def test_a_urdf_rooted_at_its_base_link_hangs_where_pybullet_has_the_base(tmp_path):
    world = SimWorld(WorldConfig())
    try:
        root = ET.parse(world.urdf).getroot()
        for element in list(root):
            if element.get('name') in ('world', 'world_joint'):
                root.remove(element)
        # An off-centre, turned inertial frame: pybullet's base pose is its centre of mass.
        inertial = root.find("link[@name='base_link']/inertial/origin")
        inertial.set('xyz', '0.02 -0.01 0.05')
        inertial.set('rpy', '0.1 0.2 0.3')
        urdf = tmp_path / 'no_world.urdf'
        ET.ElementTree(root).write(urdf, encoding='unicode')
        robot = pybullet.loadURDF(str(urdf), [0.3, 0.1, 0.5], [0, 0, 0.6, 0.8],
                                  useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
                                  physicsClientId=world.client)
        body = SimpleNamespace(robot=robot, client=world.client)
        tree = buffer_of(load_frame_tree(body, urdf).static)
        assert np.allclose(tree.lookup('world', 'base_link'),
                           pose_matrix([0.3, 0.1, 0.5], [0, 0, 0.6, 0.8]), atol=1e-6)
    finally:
        world.close()
