"""The 3D view: its HTTP side, the node with bad input, and the page in headless Chromium."""

import json
import os
from pathlib import Path
import urllib.error
import urllib.request
import xml.etree.ElementTree as ET

from ament_index_python.packages import get_package_share_directory
from conftest import RosGraph, start_sim, wait_for
import cv2
import numpy as np
import pytest
from rclpy.parameter import Parameter
from selenium.webdriver.common.by import By
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from test_ros2_cli import Launched
from test_viewer_browser import browser  # noqa: F401 - the headless Chromium fixture
from ur_rg2_common.contract import LATCHED_QOS
from ur_rg2_tools.view3d_node import View3dNode
from ur_rg2_tools.view3d_web import Scene, View3dServer, depth_cloud, served_description
from ur_rg2_vision.vision_node import VisionNode

URDF = """<robot name="r">
  <link name="a"><visual><geometry><mesh filename="file://{mesh}"/></geometry></visual>
    <collision><geometry><mesh filename="file://{mesh}"/></geometry></collision></link>
  <link name="b"><visual><geometry><mesh filename="http://example.com/b.stl"/></geometry>
    </visual><visual><geometry><mesh filename="file://{other}"/></geometry></visual></link>
</robot>"""


def get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


@pytest.fixture
def served(tmp_path):
    mesh = tmp_path / 'a.obj'
    mesh.write_text('v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n')
    secret = tmp_path / 'secret.txt'
    secret.write_text('not a mesh')
    scene = Scene()
    scene.set_description(URDF.format(mesh=mesh, other=secret))
    server = View3dServer(scene, '127.0.0.1', 0)
    server.start()
    try:
        yield server.url, mesh
    finally:
        server.stop()


def test_only_the_meshes_the_description_names_are_served(served):
    url, mesh = served
    status, urdf = get(url + 'robot.urdf')
    assert status == 200
    # The OBJ renamed for the page (once for both uses), the web mesh and the .txt left out.
    assert urdf.decode().count('filename="mesh/0.obj"') == 2
    assert 'http://' not in urdf.decode() and 'secret' not in urdf.decode()
    assert get(url + 'mesh/0.obj') == (200, mesh.read_bytes())
    for path in ('mesh/1.obj', 'mesh/0.txt', 'vendor/../view3d_web.py',
                 'vendor/%2e%2e/view3d_web.py', 'mesh/..%2fsecret.txt'):
        assert get(url + path)[0] == 404, path
    assert get(url + 'vendor/three/three.module.js')[0] == 200
    assert get(url + 'favicon.ico')[0] == 200  # the camera viewer's icon: no 404 in the console
    assert get(url + 'cloud')[0] == 503  # no depth image yet: said so, no crash


def test_bad_descriptions_are_refused_with_the_reason():
    with pytest.raises(ValueError, match='not XML'):
        served_description('<robot')
    text, files = served_description('<robot name="r"><link name="a"/></robot>')
    assert files == {} and 'link name="a"' in text


def test_depth_cloud_puts_pixels_where_they_are():
    depth = np.full((4, 6), 2.0, np.float32)
    depth[0, 0] = np.inf  # no return: left out
    k = [2.0, 0, 3.0, 0, 2.0, 2.0, 0, 0, 1]
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 0.0, 0.5)
    cloud = depth_cloud(depth, k, pose, 2)
    points = np.array(cloud['points']).reshape(-1, 3)
    assert len(points) == 5  # 2 x 3 sampled pixels, one without a return
    # Pixel (u=2, v=0) at 2 m: x = (2 - 3) * 2 / 2, y = (0 - 2) * 2 / 2, then the pose.
    assert points[0].tolist() == pytest.approx([1.0 - 1.0, -2.0, 2.5])
    assert len(cloud['colors']) == 15


def test_node_keeps_serving_through_bad_input(ros_graph):
    view = ros_graph.add(View3dNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    publisher = ros_graph.node('describer').create_publisher(String, 'robot_description',
                                                             LATCHED_QOS)
    publisher.publish(String(data='<robot name="r"><link name="base"/></robot>'))
    wait_for(lambda: get(view.url + 'robot.urdf')[0] == 200, 30, 'the description served')
    publisher.publish(String(data='<robot><link'))  # not XML: one warning, the old one kept
    joints = ros_graph.node('joints').create_publisher(JointState, 'joint_states', 10)
    wait_for(joints.get_subscription_count, 10, 'the view to subscribe to joint_states')
    joints.publish(JointState(name=['a', 'b'], position=[1.0]))  # mismatched: ignored
    joints.publish(JointState(name=['a'], position=[0.5]))
    wait_for(lambda: json.loads(get(view.url + 'scene')[1]).get('joints') == {'a': 0.5}, 30,
             'the well-formed joint state in /scene')
    assert 'link name="base"' in get(view.url + 'robot.urdf')[1].decode()
    # A second view on the same port: a clear start-up error, not a crash.
    port = int(view.url.rsplit(':', 1)[1].rstrip('/'))
    with pytest.raises(OSError, match=f'cannot serve on 127.0.0.1 port {port}'):
        View3dNode(context=ros_graph.context, parameter_overrides=[
            Parameter('port', value=port)])


def canvas(driver) -> np.ndarray:
    """Return the 3D view's canvas as the browser shows it (BGR)."""
    png = driver.find_element(By.TAG_NAME, 'canvas').screenshot_as_png
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def test_page_draws_the_robot_and_follows_the_arm(ros_graph, browser):  # noqa: F811
    # VIEW3D_SCREENSHOT=docs/view3d.png saves the picture of docs/recording-and-3d.md, at the
    # default camera size; the test alone renders a smaller one to spare the two cores.
    screenshot = os.environ.get('VIEW3D_SCREENSHOT')
    size = (640, 480) if screenshot else (320, 240)
    start_sim(ros_graph, camera_width=size[0], camera_height=size[1])
    if screenshot:  # the detected ball beside the true one in the picture
        ros_graph.add(VisionNode(context=ros_graph.context))
    view = ros_graph.add(View3dNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    jog = ros_graph.node('jogger').create_publisher(JointState, 'joint_jog', 10)

    browser.get(view.url)
    assert browser.title == 'UR + RG2 3D view'
    state = wait_for(lambda: (s := browser.execute_script('return window.view3d'))
                     and s['robotLoaded'] and s['meshesLoaded'] >= 7 and s['clouds'] and s,
                     90, 'the robot with its 7 arm meshes and a point cloud in the page')
    assert state['scenes'] > 0
    assert 'ball (true): x 0.' in browser.find_element(By.ID, 'ball-true').text
    before = canvas(browser)
    # Drawn: far from a blank canvas of the background colour.
    assert before.std() > 10 and (np.abs(before.astype(int) - (38, 33, 29)).sum(2) > 30).mean() \
        > 0.02
    wait_for(jog.get_subscription_count, 10, 'the sim to subscribe to joint_jog')
    jog.publish(JointState(name=['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint'],
                           position=[0.8, -0.6, 1.2]))

    def arm_turned() -> bool:
        scene = json.loads(get(view.url + 'scene')[1])
        joints = scene['joints']
        return all(abs(joints[name] - value) < 0.02 for name, value in (
            ('shoulder_pan_joint', 0.8), ('shoulder_lift_joint', -0.6), ('elbow_joint', 1.2)))

    wait_for(arm_turned, 60, 'the jogged joints in /scene')
    wait_for(lambda: np.abs(canvas(browser).astype(int) - before.astype(int)).mean() > 1.0,
             30, 'the drawn arm to move', interval=0.2)
    if screenshot:
        wait_for(lambda: browser.execute_script('return window.view3d.clouds') > 2, 30,
                 'a point cloud of the moved arm')
        browser.save_screenshot(screenshot)


def test_a_replay_after_the_sim_stopped_draws_the_robots_meshes(ros_graph, tmp_path,
                                                               browser):  # noqa: F811
    """A recording of a running sim, replayed once that sim is gone, on another domain."""
    path = tmp_path / 'run.mcap'
    topics = ['/robot_description', '/joint_states']
    sim_graph = RosGraph()
    try:
        start_sim(sim_graph, camera_rate=0.0)
        states = []
        sim_graph.node('witness').create_subscription(JointState, 'joint_states',
                                                      states.append, 10)
        recorder = Launched(['ros2', 'run', 'ur_rg2_tools', 'record', '-o', str(path),
                             *topics], sim_graph.env, tmp_path / 'record.log')
        try:
            wait_for(lambda: recorder.output.count('recording /') == len(topics) + 1
                     or recorder.process.poll() is not None, 120,
                     'the recorder to subscribe to its topics')
            seen = len(states)
            wait_for(lambda: len(states) > seen + 20, 60, 'joint states while recording')
            recorder.ctrl_c()
            assert recorder.wait(30) == 0, recorder.output
        finally:
            recorder.kill()
    finally:
        sim_graph.shutdown()  # the sim is gone, with its temporary files

    view = ros_graph.add(View3dNode(context=ros_graph.context, parameter_overrides=[
        Parameter('port', value=0)]))
    player = Launched(['ros2', 'run', 'ur_rg2_tools', 'replay', str(path)], ros_graph.env,
                      tmp_path / 'replay.log')
    try:
        assert player.wait(120) == 0, player.output  # it ends with the recording
    finally:
        player.kill()
    wait_for(view.scene.description, 10, 'the replayed robot_description')
    status, urdf = get(view.url + 'robot.urdf')
    assert status == 200
    # Every mesh URL the page fetches is served: the UR5's seven shipped meshes.
    urls = {mesh.get('filename') for mesh in ET.fromstring(urdf).iter('mesh')}
    served = {get(view.url + url) for url in urls}
    shipped = Path(get_package_share_directory('ur_rg2_sim')) / 'meshes' / 'ur5'
    assert served == {(200, file.read_bytes()) for file in shipped.glob('*.obj')}
    assert len(urls) == 7

    browser.get(view.url)
    wait_for(lambda: (s := browser.execute_script('return window.view3d'))
             and s['robotLoaded'] and s['meshesLoaded'] >= 7, 90,
             'the replayed robot with its 7 arm meshes in the page')
