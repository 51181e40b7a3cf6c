"""The viewer node in a ROS graph, fed by fake publishers of the contract's topics."""

import json
import math
import socket
import subprocess
import urllib.request

from conftest import wait_for
import cv2
from geometry_msgs.msg import PointStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Bool, Header, String
from ur_rg2_vision.ros_image import rgb_to_image
from ur_rg2_vision.viewer_node import ViewerNode

ARM = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
       'wrist_2_joint', 'wrist_3_joint']


def fetch(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=10) as response:
        return response.read()


def state(viewer: ViewerNode) -> dict:
    return json.loads(fetch(viewer.url + 'state'))


def test_viewer_serves_what_the_topics_say(ros_graph):
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    assert viewer.get_name() == 'ur_rg2_viewer'
    assert viewer.url.startswith('http://127.0.0.1:')
    fake = ros_graph.node('fake_graph')
    images = fake.create_publisher(Image, 'ball/image', 10)
    joints = fake.create_publisher(JointState, 'joint_states', 10)
    ball = fake.create_publisher(PointStamped, 'ball/position', 10)
    wait_for(lambda: images.get_subscription_count() and joints.get_subscription_count()
             and ball.get_subscription_count(), 10, 'the viewer to subscribe')

    frame = np.zeros((60, 80, 3), np.uint8)
    frame[:, :40] = (255, 0, 0)  # left half red, as RGB

    def published_frame_arrived():
        images.publish(rgb_to_image(frame, Header()))
        return state(viewer)['camera']['frames'] > 0

    wait_for(published_frame_arrived, 10, 'a frame to reach the viewer')
    snapshot = cv2.imdecode(np.frombuffer(fetch(viewer.url + 'snapshot'), np.uint8),
                            cv2.IMREAD_COLOR)
    assert snapshot.shape == (60, 80, 3)
    assert snapshot[30, 10, 2] > 200 and snapshot[30, 10, 0] < 50  # red (BGR) on the left
    assert snapshot[30, 70].max() < 50

    positions = [0.5, -1.0, 0.0, 0.0, 0.0, 3.14159, 0.02, 0.02]
    names = ARM + ['rg2_left_finger_joint', 'rg2_right_finger_joint']

    def joints_shown():
        joints.publish(JointState(name=names, position=positions))
        return state(viewer).get('joints')

    shown = wait_for(joints_shown, 10, 'joint angles in /state')
    assert [j['name'] for j in shown] == ARM
    assert [j['deg'] for j in shown] == pytest.approx([28.648, -57.296, 0, 0, 0, 180], abs=1e-3)
    assert state(viewer)['gripper']['opening_mm'] == pytest.approx(40.0)

    point = PointStamped()
    point.header.frame_id = 'camera_color_optical_frame'
    point.point.x, point.point.y, point.point.z = 0.1, 0.2, 1.5

    def ball_shown():
        ball.publish(point)
        return state(viewer).get('ball')

    # No sim to give the camera pose: no world coordinates.
    assert wait_for(ball_shown, 10, 'the ball in /state') == {
        'frame_id': 'camera_color_optical_frame', 'x': 0.1, 'y': 0.2, 'z': 1.5, 'world': None,
        'base_link': None, 'via': None}

    # The policy node's latched state: shown as it comes.
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    driving = fake.create_publisher(Bool, 'policy/driving', latched)
    assert 'policy_driving' not in state(viewer)
    driving.publish(Bool(data=True))
    wait_for(lambda: state(viewer).get('policy_driving') is True, 10, 'policy driving')
    driving.publish(Bool(data=False))
    wait_for(lambda: state(viewer).get('policy_driving') is False, 10, 'policy idle')
    # Each episode's outcome, latched, as the pick's.
    result = fake.create_publisher(String, 'policy/result', latched)
    outcome = 'success: picked the ball: held 12 cm above the floor after 40 steps (6.3 s)'
    result.publish(String(data=outcome))
    wait_for(lambda: state(viewer).get('policy_result') == outcome, 10, 'the policy outcome')


def test_the_ball_is_shown_in_world_coordinates_from_the_sims_camera_pose(ros_graph):
    # A stand-in for the sim: its camera 1 m above the floor at x = 1, looking at the origin.
    # Optical z then points along (-1, 0, -1)/sqrt(2), x along world y, y along (1, 0, -1)/sqrt(2).
    sim = ros_graph.node('ur_rg2_sim')
    sim.declare_parameter('camera_position', [1.0, 0.0, 1.0])
    sim.declare_parameter('camera_look_at', [0.0, 0.0, 0.0])
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    ball = ros_graph.node('fake_vision').create_publisher(PointStamped, 'ball/position', 10)
    wait_for(ball.get_subscription_count, 10, 'the viewer to subscribe')
    point = PointStamped()
    point.header.frame_id = 'camera_color_optical_frame'
    point.point.x, point.point.y, point.point.z = 0.1, 0.2, math.sqrt(2)

    def world_shown():
        ball.publish(point)
        return state(viewer).get('ball', {}).get('world')

    world = wait_for(world_shown, 20, 'world coordinates in /state')
    assert world['frame_id'] == 'world'
    r = 0.2 / math.sqrt(2)
    assert [world['x'], world['y'], world['z']] == pytest.approx([r, 0.1, -r], abs=1e-9)
    assert state(viewer)['ball']['z'] == pytest.approx(math.sqrt(2))  # and the optical frame

    # The pose may change at run time: the viewer follows.
    sim.set_parameters([Parameter('camera_position', value=[1.0, 0.0, 2.0]),
                        Parameter('camera_look_at', value=[0.0, 0.0, 1.0])])
    wait_for(lambda: world_shown()['z'] == pytest.approx(1 - r), 20, 'the new camera pose')
    # A point in another frame is not converted.
    point.header.frame_id = 'somewhere_else'
    wait_for(lambda: (ball.publish(point), state(viewer)['ball'])[1]['frame_id']
             == 'somewhere_else', 10, 'the other frame')
    assert state(viewer)['ball']['world'] is None


def test_image_topic_parameter_selects_the_raw_camera(ros_graph):
    viewer = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0), Parameter('image_topic', value='camera/color/image_raw')]))
    fake = ros_graph.node('fake_camera')
    raw = fake.create_publisher(Image, 'camera/color/image_raw', 10)
    wait_for(raw.get_subscription_count, 10, 'the viewer to subscribe to the raw camera')

    def frame_arrived():
        raw.publish(rgb_to_image(np.full((8, 8, 3), 128, np.uint8), Header()))
        return state(viewer)['camera']['width'] == 8

    wait_for(frame_arrived, 10, 'a raw camera frame to reach the viewer')


def test_busy_port_fails_clearly(ros_graph):
    first = ros_graph.add(ViewerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    port = int(first.url.rsplit(':', 1)[1].strip('/'))
    with pytest.raises(OSError):
        ViewerNode(context=ros_graph.context, parameter_overrides=[Parameter('port', value=port)])


def run_viewer(ros_graph, port: str) -> subprocess.CompletedProcess:
    """Run the viewer executable with ``port:=PORT``; return how it ended."""
    return subprocess.run(['viewer', '--ros-args', '-p', f'port:={port}'], env=ros_graph.env,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize('port', ['99999', '-1'])
def test_a_port_out_of_range_ends_the_viewer_with_one_line(ros_graph, port):
    ended = run_viewer(ros_graph, port)
    assert ended.returncode == 1
    assert 'Traceback' not in ended.stderr + ended.stdout
    lines = ended.stderr.splitlines()
    assert len(lines) == 1 and '[ERROR]' in lines[0], ended.stderr
    assert 'cannot start' in lines[0] and 'port' in lines[0] and port in lines[0]


def test_a_port_in_use_ends_the_viewer_with_one_line(ros_graph):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        port = str(busy.getsockname()[1])
        ended = run_viewer(ros_graph, port)
    assert ended.returncode == 1
    assert 'Traceback' not in ended.stderr + ended.stdout
    lines = ended.stderr.splitlines()
    assert len(lines) == 1 and '[ERROR]' in lines[0], ended.stderr
    assert f'cannot serve on 127.0.0.1 port {port}' in lines[0]
