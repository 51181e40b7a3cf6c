"""The sim's frames through the contract: /tf, /tf_static, robot_description, ball/true_pose."""

import math
from pathlib import Path
import signal
from urllib.parse import urlparse
import xml.etree.ElementTree as ET

from ament_index_python.packages import get_package_share_directory
from conftest import start_sim, wait_for
from geometry_msgs.msg import PoseStamped
import numpy as np
from std_msgs.msg import String
from test_sim_node import FAST, Probe, image_array, latest_frame, run_sim, stamp_ns
from test_sim_reach import nearest
from tf2_msgs.msg import TFMessage
from tf_tree import ur_forward_kinematics
from ur_rg2_common.contract import ARM_JOINTS, LATCHED_QOS, TF_QOS
from ur_rg2_common.tf_buffer import TransformBuffer
from ur_rg2_motion.kinematics import rotation_angle
from ur_rg2_sim.world import SimWorld, WorldConfig

MM = 1e-3
DEG = math.radians(1.0)
# At FAST, the probe's executor keeps up with three topics at this rate, not at 100 Hz.
SLOW_STATES = 25.0


class FrameProbe(Probe):
    """A probe that also records the transform tree, robot_description and ball/true_pose."""

    def __init__(self, graph) -> None:
        super().__init__(graph)
        for topic, kind, qos in (
                ('/tf', TFMessage, TF_QOS), ('/tf_static', TFMessage, LATCHED_QOS),
                ('robot_description', String, LATCHED_QOS), ('ball/true_pose', PoseStamped, 100)):
            self.node.create_subscription(kind, topic, self._recorder(topic), qos)

    def static_tree(self, timeout: float = 30.0) -> TransformBuffer:
        tree = TransformBuffer()
        tree.add_message(self.latest('/tf_static', timeout))
        return tree

    def tree_at(self, joint_states) -> TransformBuffer:
        """Return /tf_static plus the /tf message stamped like ``joint_states``."""
        stamp = stamp_ns(joint_states)
        tf = wait_for(lambda: [m for m in self.messages('/tf')
                               if stamp_ns(m.transforms[0]) == stamp], 20,
                      f'the /tf message stamped {stamp}')[0]
        tree = self.static_tree()
        tree.add_message(tf)
        return tree


def settle(probe: FrameProbe, targets: dict[str, float]):
    """Command ``targets``; return a joint_states message once the arm is still there."""
    probe.send(probe.command, targets.keys(), targets.values())
    probe.wait_positions(targets, tolerance=math.radians(0.5))

    def still():
        msg = probe.latest('joint_states')
        return max(abs(v) for v in msg.velocity[:len(ARM_JOINTS)]) < 1e-3 and msg
    return wait_for(still, 30, 'the arm to stop')


def clear_configurations(model: str, count: int, seed: int = 17) -> list[dict[str, float]]:
    """Return random arm configurations the arm reaches 2 cm clear of floor and pedestal.

    Each is reached from the one before (home first); the sim drives every joint at its own
    velocity limit, so the path is checked as it moves.
    """
    rng = np.random.default_rng(seed)
    world = SimWorld(WorldConfig(robot_model=model))
    base_link = world.link_index('base_link')

    def clear(positions: dict[str, float]) -> bool:
        world.set_arm_positions(positions)
        return min(nearest(world, world.floor),
                   nearest(world, world.pedestal, (base_link,))) > 0.02

    def path_clear(start: dict[str, float], end: dict[str, float]) -> bool:
        duration = max(abs(end[n] - start[n]) / world.limits[n].velocity for n in ARM_JOINTS)
        for t in np.linspace(0.0, duration, 25):
            if not clear({n: start[n] + np.clip(end[n] - start[n],
                                                 -world.limits[n].velocity * t,
                                                 world.limits[n].velocity * t)
                          for n in ARM_JOINTS}):
                return False
        return True

    try:
        found, start = [], dict.fromkeys(ARM_JOINTS, 0.0)
        while len(found) < count:
            targets = {name: float(rng.uniform(-3.0, 3.0)) for name in ARM_JOINTS}
            if path_clear(start, targets):
                found.append(targets)
                start = targets
        return found
    finally:
        world.close()


def assert_dh_kinematics(probe: FrameProbe, model: str, configurations: int = 3) -> None:
    for targets in clear_configurations(model, configurations):
        joint_states = settle(probe, targets)
        positions = dict(zip(joint_states.name, joint_states.position))
        expected = ur_forward_kinematics(model, [positions[name] for name in ARM_JOINTS])
        pose = probe.tree_at(joint_states).lookup('base', 'tool0')
        assert np.linalg.norm(pose[:3, 3] - expected[:3, 3]) < 1 * MM, (targets, pose, expected)
        assert rotation_angle(pose, expected) < 0.1 * DEG, (targets, pose, expected)


def test_tf_base_to_tool0_is_ur5_dh_kinematics(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST, joint_state_rate=SLOW_STATES)
    assert_dh_kinematics(FrameProbe(ros_graph), 'ur5')


def test_across_processes_ur3_tree_and_robot_description(ros_graph):
    """The sim as its own process: UR3 kinematics, one tree from world, the description."""
    process = run_sim('robot_model:=ur3', 'camera_rate:=0.0', f'real_time_factor:={FAST}',
                      f'joint_state_rate:={SLOW_STATES}', domain_id=ros_graph.domain_id)
    try:
        probe = FrameProbe(ros_graph)
        probe.latest('joint_states', timeout=60)
        description = probe.latest('robot_description').data
        links = {link.get('name') for link in ET.fromstring(description).iter('link')}
        assert {'world', 'base_link', 'base', 'tool0', 'rg2_tcp', 'wrist_3_link'} <= links
        meshes = [mesh.get('filename') for mesh in ET.fromstring(description).iter('mesh')]
        assert meshes
        share = Path(get_package_share_directory('ur_rg2_sim'))
        for uri in meshes:  # the installed package's files, found through the ament index
            assert uri.startswith('package://ur_rg2_sim/meshes/ur3/'), uri
            assert (share / urlparse(uri).path.lstrip('/')).is_file(), uri
        tree = probe.tree_at(probe.latest('joint_states'))
        frames = tree.frames()
        assert frames == links | {'camera_link', 'camera_color_optical_frame'}
        for frame in frames:
            tree.lookup('world', frame)  # raises if the frame is not connected to world
        assert_dh_kinematics(probe, 'ur3', configurations=2)
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=10)
    assert process.returncode == 0


def test_tf_stamps_are_the_joint_states_stamps(ros_graph):
    start_sim(ros_graph, camera_rate=0.0)
    probe = FrameProbe(ros_graph)
    first = stamp_ns(probe.latest('/tf').transforms[0])
    wait_for(lambda: stamp_ns(probe.latest('joint_states')) > first + 0.6e9, 30, '0.6 s of sim')
    joint_stamps = [stamp_ns(m) for m in probe.messages('joint_states')]
    tf = probe.messages('/tf')
    poses = probe.messages('ball/true_pose')
    moving = {t.child_frame_id for t in tf[-1].transforms}
    assert moving == {'shoulder_link', 'upper_arm_link', 'forearm_link', 'wrist_1_link',
                      'wrist_2_link', 'wrist_3_link', 'rg2_left_finger', 'rg2_right_finger'}
    for msg in tf:  # one stamp per message
        assert len({stamp_ns(t) for t in msg.transforms}) == 1
    tf_stamps = [stamp_ns(m.transforms[0]) for m in tf]
    pose_stamps = [stamp_ns(m) for m in poses]
    # Where all three subscriptions were matched, the stamps are the same, one for one.
    start = max(joint_stamps[0], tf_stamps[0], pose_stamps[0])
    end = min(joint_stamps[-1], tf_stamps[-1], pose_stamps[-1])
    assert end - start >= 0.4e9

    def window(stamps):
        return [s for s in stamps if start <= s <= end]
    assert window(tf_stamps) == window(joint_stamps) == window(pose_stamps)
    assert len(window(tf_stamps)) >= 40


def red_blob_centre(color) -> np.ndarray:
    rgb = image_array(color).astype(int)
    mask = (rgb[..., 0] > 120) & (rgb[..., 1] < 70) & (rgb[..., 2] < 70)
    assert mask.sum() > 20, 'no red ball in the image'
    rows, columns = np.nonzero(mask)
    return np.array([columns.mean(), rows.mean()])


def assert_ball_projects_onto_its_image(probe: FrameProbe, after_ns: int = 0) -> None:
    color, _, info, _ = latest_frame(probe, after_ns)
    true_pose = probe.latest('ball/true_pose')
    assert true_pose.header.frame_id == 'world'
    p = true_pose.pose.position
    optical = probe.static_tree().lookup('camera_color_optical_frame', 'world')
    x, y, z, _ = optical @ [p.x, p.y, p.z, 1.0]
    k = np.array(info.k).reshape(3, 3)
    projected = np.array([k[0, 0] * x / z + k[0, 2], k[1, 1] * y / z + k[1, 2]])
    assert np.linalg.norm(projected - red_blob_centre(color)) <= 2.0


def test_ball_true_pose_through_the_tree_lands_on_the_rendered_ball(ros_graph):
    start_sim(ros_graph)
    probe = FrameProbe(ros_graph)
    assert_ball_projects_onto_its_image(probe)
    # A new camera pose republishes /tf_static; frames stamped after it use the new pose.
    position, look_at = np.array([1.0, -0.9, 0.8]), np.array([0.4, -0.3, 0.0])
    assert all(r.successful for r in probe.set_parameters(camera_position=list(position),
                                                          camera_look_at=list(look_at)))
    forward = (look_at - position) / np.linalg.norm(look_at - position)

    def moved():
        camera = probe.static_tree().lookup('world', 'camera_link')
        return np.allclose(camera[:3, 3], position) and np.allclose(camera[:3, 0], forward)
    wait_for(moved, 20, 'the new camera pose on /tf_static')
    changed_at = stamp_ns(probe.latest('/tf_static').transforms[0])
    assert_ball_projects_onto_its_image(probe, after_ns=changed_at)


def test_frame_prefix_applies_to_every_frame(ros_graph):
    start_sim(ros_graph, frame_prefix='r1/', camera_width=160, camera_height=120)
    probe = FrameProbe(ros_graph)
    tree = probe.static_tree()
    tree.add_message(probe.latest('/tf'))
    frames = tree.frames()
    assert 'r1/tool0' in frames and 'r1/camera_color_optical_frame' in frames
    for frame in frames:
        assert frame.startswith('r1/'), frame
        tree.lookup('r1/world', frame)  # raises if the frame is not connected to r1/world
    color, depth, info, depth_info = latest_frame(probe)
    for msg in (color, depth, info, depth_info):
        assert msg.header.frame_id == 'r1/camera_color_optical_frame'
    assert probe.latest('ball/true_pose').header.frame_id == 'r1/world'
    result = probe.set_parameters(frame_prefix='r2/')[0]
    assert not result.successful
    assert probe.get_parameter('frame_prefix') == 'r1/'

