"""The simulator node through its contract: topics, services, parameters, process behaviour."""

from collections import defaultdict
import math
import os
import select
import signal
import subprocess
import sys
import threading
import time

from conftest import GRIPPER_DOWN, start_sim, wait_for
from geometry_msgs.msg import PoseStamped
import numpy as np
import pytest
from rcl_interfaces.msg import Log
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_srvs.srv import Trigger
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import ARM_JOINTS, IMAGE_QOS
from ur_rg2_sim.world import SimWorld, WorldConfig

SIM_BIN = os.path.join(os.path.dirname(sys.executable), 'sim')
TOLERANCE = math.radians(0.1)
# Fast enough to keep tests short, slow enough that subscribers see every state.
FAST = 3.0


class Probe:
    """A helper node recording what the simulator publishes and calling its services."""

    def __init__(self, graph) -> None:
        self.node = graph.node('probe')
        self._lock = threading.Lock()
        self._messages = defaultdict(list)
        self._clients = {}
        for topic, kind, qos in (
                ('joint_states', JointState, 1000), ('/clock', Clock, 10),
                ('/rosout', Log, 100),
                ('camera/color/image_raw', Image, IMAGE_QOS),
                ('camera/depth/image_raw', Image, IMAGE_QOS),
                ('camera/color/camera_info', CameraInfo, IMAGE_QOS),
                ('camera/depth/camera_info', CameraInfo, IMAGE_QOS)):
            self.node.create_subscription(kind, topic, self._recorder(topic), qos)
        self.jog = self.node.create_publisher(JointState, 'joint_jog', 10)
        self.command = self.node.create_publisher(JointState, 'joint_command', 10)

    def _recorder(self, topic):
        def record(msg):
            with self._lock:
                self._messages[topic].append(msg)
                del self._messages[topic][:-400]
        return record

    def messages(self, topic: str) -> list:
        with self._lock:
            return list(self._messages[topic])

    def latest(self, topic: str, timeout: float = 20.0):
        return wait_for(lambda: self.messages(topic)[-1:], timeout, f'a message on {topic}')[0]

    def positions(self) -> dict[str, float]:
        msg = self.latest('joint_states')
        return dict(zip(msg.name, msg.position))

    def wait_positions(self, targets: dict[str, float], tolerance: float = TOLERANCE,
                       timeout: float = 30.0) -> dict[str, float]:
        def reached():
            current = self.positions()
            return all(abs(current[n] - v) < tolerance for n, v in targets.items()) and current
        return wait_for(reached, timeout, f'joints to reach {targets}')

    def send(self, publisher, names, positions) -> None:
        publisher.publish(JointState(name=list(names), position=[float(p) for p in positions]))

    def call(self, service: str, kind=Trigger, request=None, timeout: float = 30.0):
        if service not in self._clients:
            self._clients[service] = self.node.create_client(kind, service)
        client = self._clients[service]
        wait_for(client.service_is_ready, timeout, f'service {service}')
        future = client.call_async(request or kind.Request())
        wait_for(future.done, timeout, f'an answer from {service}')
        return future.result()

    def set_parameters(self, **values):
        request = SetParameters.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
        return self.call('ur_rg2_sim/set_parameters', SetParameters, request).results

    def get_parameter(self, name: str):
        request = GetParameters.Request(names=[name])
        value = self.call('ur_rg2_sim/get_parameters', GetParameters, request).values[0]
        return Parameter.from_parameter_msg(ParameterMsg(name=name, value=value)).value

    def warnings(self) -> list[str]:
        # One log record per (stamp, text): a /rosout sample delivered twice (seen once under
        # load) is not a second warning, while a line logged twice has two stamps.
        records = {(m.stamp.sec, m.stamp.nanosec, m.msg): m.msg for m in self.messages('/rosout')
                   if m.level >= Log.WARN}
        return list(records.values())


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def image_array(msg: Image) -> np.ndarray:
    dtype = np.float32 if msg.encoding == '32FC1' else np.uint8
    channels = 3 if msg.encoding == 'rgb8' else 1
    return np.frombuffer(bytes(msg.data), dtype).reshape(msg.height, msg.width, channels)


class CameraModel:
    """The camera as a consumer knows it: camera_info intrinsics and the pose parameters."""

    def __init__(self, probe: Probe, info: CameraInfo) -> None:
        self.k = np.array(info.k).reshape(3, 3)
        self.position = np.array(probe.get_parameter('camera_position'))
        self.rotation = optical_rotation(self.position, probe.get_parameter('camera_look_at'))

    def pixel(self, point) -> tuple[int, int]:
        x, y, z = self.rotation.T @ (np.asarray(point) - self.position)
        return (round(self.k[0, 0] * x / z + self.k[0, 2]),
                round(self.k[1, 1] * y / z + self.k[1, 2]))

    def surface_depth(self, pixel, centre, radius: float) -> float:
        """Optical z where the ray through ``pixel`` first meets a sphere."""
        u, v = pixel
        ray = np.array([(u - self.k[0, 2]) / self.k[0, 0], (v - self.k[1, 2]) / self.k[1, 1], 1])
        c = self.rotation.T @ (np.asarray(centre) - self.position)
        a, b, cc = ray @ ray, -2 * ray @ c, c @ c - radius ** 2
        return (-b - math.sqrt(b * b - 4 * a * cc)) / (2 * a)


def latest_frame(probe: Probe, after_ns: int = 0):
    """Return colour image, depth image, colour and depth camera_info, all with one stamp."""
    def matched():
        others = [{stamp_ns(m): m for m in probe.messages(topic)} for topic in (
            'camera/depth/image_raw', 'camera/color/camera_info', 'camera/depth/camera_info')]
        for color in reversed(probe.messages('camera/color/image_raw')):
            stamp = stamp_ns(color)
            if stamp > after_ns and all(stamp in other for other in others):
                return (color, *(other[stamp] for other in others))
        return None
    return wait_for(matched, 30.0, 'a colour + depth + camera_info frame')


def assert_ball_seen_at(probe: Probe, centre, radius: float = 0.03, after_ns: int = 0) -> None:
    color, depth, info, _ = latest_frame(probe, after_ns)
    camera = CameraModel(probe, info)
    u, v = camera.pixel(centre)
    r, g, b = image_array(color)[v, u]
    assert r > 120 and g < 70 and b < 70, f'pixel {(u, v)} is {(r, g, b)}, not the red ball'
    expected = camera.surface_depth((u, v), centre, radius)
    assert image_array(depth)[v, u, 0] == pytest.approx(expected, abs=0.01)


def test_joint_states_names_order_and_rate(ros_graph):
    start_sim(ros_graph, camera_rate=0.0)
    probe = Probe(ros_graph)
    msg = probe.latest('joint_states')
    assert list(msg.name[:6]) == list(ARM_JOINTS)
    assert len(msg.name) > 6 and all(n.startswith('rg2_') for n in msg.name[6:])
    assert len(msg.position) == len(msg.velocity) == len(msg.effort) == len(msg.name)
    # 100 Hz of simulation time: count stamps over one simulated second.
    first = stamp_ns(msg)
    wait_for(lambda: stamp_ns(probe.latest('joint_states')) > first + 1.1e9, 30, '1.1 s of sim')
    stamps = [stamp_ns(m) for m in probe.messages('joint_states')]
    in_window = [s for s in stamps if first <= s < first + 1_000_000_000]
    assert len(in_window) == pytest.approx(100, abs=1)
    clock = probe.latest('/clock')
    assert clock.clock.sec * 1e9 + clock.clock.nanosec >= first


def test_jog_each_joint_by_five_degrees(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    probe = Probe(ros_graph)
    home = probe.positions()
    step = math.radians(5.0)
    for joint in ARM_JOINTS:
        probe.send(probe.jog, [joint], [step])
        probe.wait_positions({joint: home[joint] + step})
    final = probe.positions()
    for joint in ARM_JOINTS:
        assert final[joint] == pytest.approx(home[joint] + step, abs=TOLERANCE)


def test_absolute_command_clamping_and_reset(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    probe = Probe(ros_graph)
    probe.send(probe.command, ['shoulder_pan_joint', 'wrist_2_joint'], [0.5, -0.7])
    probe.wait_positions({'shoulder_pan_joint': 0.5, 'wrist_2_joint': -0.7})
    # The UR wrists are limited to +-2 pi: a target beyond stops there. (The elbow's +-pi is
    # out of reach: folded that far, the arm meets itself or the floor first.)
    probe.send(probe.command, ['wrist_3_joint'], [10.0])
    probe.wait_positions({'wrist_3_joint': 2 * math.pi})
    response = probe.call('reset')
    assert response.success, response.message
    probe.wait_positions(dict.fromkeys(ARM_JOINTS, 0.0))


def test_reset_answers_briefly_in_degrees(ros_graph):
    home = [0.0, -math.pi / 2, 0.0, -math.pi / 2, 0.25, 0.0]
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST, home_position=home)
    response = Probe(ros_graph).call('reset')
    assert response.success, response.message
    assert response.message == 'arm going home: [0, -90, 0, -90, 14.3, 0] deg'


@pytest.mark.parametrize('topic', ['joint_jog', 'joint_command'])
def test_malformed_messages_are_rejected_whole(ros_graph, topic):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    probe = Probe(ros_graph)
    publisher = probe.jog if topic == 'joint_jog' else probe.command
    home = probe.positions()
    malformed = [
        (['shoulder_pan_joint', 'no_such_joint'], [0.3, 0.3], 'unknown joint'),
        (['shoulder_pan_joint', 'elbow_joint'], [0.3], 'names but'),
        (['shoulder_pan_joint'], [math.nan], 'not a finite number'),
        (['shoulder_pan_joint'], [math.inf], 'not a finite number'),
        ([], [], 'no joint names'),
    ]
    for names, positions, reason in malformed:
        probe.send(publisher, names, positions)
        wait_for(lambda reason=reason: [w for w in probe.warnings()
                                        if topic in w and reason in w], 20, f'warning {reason}')
    # A valid message afterwards on the same topic is applied; nothing else moved.
    probe.send(publisher, ['wrist_3_joint'], [0.2])
    probe.wait_positions({'wrist_3_joint': home['wrist_3_joint'] + 0.2})
    final = probe.positions()
    for joint in ARM_JOINTS[:-1]:
        assert final[joint] == pytest.approx(home[joint], abs=TOLERANCE), joint
    assert len([w for w in probe.warnings() if topic in w]) == len(malformed)


def test_gripper_services_report_the_opening(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    probe = Probe(ros_graph)
    fingers = [name for name in probe.positions() if name.startswith('rg2_')]
    closed = probe.call('gripper/close')
    assert closed.success and 'nothing grasped' in closed.message
    # joint_states may still be on its way when the answer arrives.
    probe.wait_positions(dict.fromkeys(fingers, 0.0), tolerance=1e-3)
    opened = probe.call('gripper/open')
    assert opened.success and '110.0 mm' in opened.message
    probe.wait_positions(dict.fromkeys(fingers, 0.055), tolerance=1e-3)


def test_camera_images_and_camera_info(ros_graph):
    start_sim(ros_graph)
    probe = Probe(ros_graph)
    color, depth, info, depth_info = latest_frame(probe)
    assert (color.encoding, color.width, color.height, color.step) == ('rgb8', 640, 480, 1920)
    assert (depth.encoding, depth.width, depth.height, depth.step) == ('32FC1', 640, 480, 2560)
    assert color.header.frame_id == depth.header.frame_id == 'camera_color_optical_frame'
    assert info.header.frame_id == 'camera_color_optical_frame'
    assert (info.width, info.height, info.distortion_model) == (640, 480, 'plumb_bob')
    assert list(info.d) == [0.0] * 5
    fx = info.k[0]
    assert 2 * math.degrees(math.atan(320 / fx)) == pytest.approx(57.0, abs=1e-6)
    assert list(info.p) == [fx, 0, info.k[2], 0, 0, info.k[4], info.k[5], 0, 0, 0, 1, 0]
    assert list(depth_info.k) == list(info.k)
    assert_ball_seen_at(probe, probe.get_parameter('ball_position'))


def test_ball_position_parameter_moves_the_ball(ros_graph):
    start_sim(ros_graph, camera_width=320, camera_height=240)
    probe = Probe(ros_graph)
    truth = []
    probe.node.create_subscription(PoseStamped, 'ball/true_pose', truth.append, 100)
    target = [0.2, -0.5, 0.03]
    assert probe.set_parameters(ball_position=target)[0].successful
    # The move is applied between two physics steps after the answer: frames are judged from
    # the first ground truth that has the ball there.
    moved = wait_for(lambda: next((m for m in list(truth) if abs(m.pose.position.x - 0.2) < 1e-3
                                   and abs(m.pose.position.y + 0.5) < 1e-3), None), 20,
                     'the ball at its new position')
    assert_ball_seen_at(probe, target, after_ns=stamp_ns(moved))
    for bad, reason in (([0.1, math.nan, 0.03], 'finite'), ([0.1, 0.2], 'needs 3 numbers')):
        result = probe.set_parameters(ball_position=bad)[0]
        assert not result.successful and reason in result.reason
    assert list(probe.get_parameter('ball_position')) == target


def test_grasp_and_lift_the_ball(ros_graph):
    start_sim(ros_graph, camera_width=320, camera_height=240, real_time_factor=2.0)
    probe = Probe(ros_graph)
    ball = np.array(probe.get_parameter('ball_position'))
    # Inverse kinematics from the same UR model, used as a user's motion planner would be.
    planner = SimWorld(WorldConfig())
    try:
        def plan(tcp):
            return planner.inverse_kinematics(tcp, GRIPPER_DOWN)
        above, at, lifted = plan(ball + [0, 0, 0.15]), plan(ball), plan(ball + [0, 0, 0.3])
    finally:
        planner.close()
    assert probe.call('gripper/open').success
    for pose in (above, at):
        probe.send(probe.command, pose.keys(), pose.values())
        probe.wait_positions(pose, tolerance=math.radians(0.5))
    closed = probe.call('gripper/close')
    assert closed.success and 'grasped' in closed.message and 'nothing' not in closed.message
    probe.send(probe.command, lifted.keys(), lifted.values())
    probe.wait_positions(lifted, tolerance=math.radians(0.5))
    lifted_at = stamp_ns(probe.latest('joint_states'))
    assert_ball_seen_at(probe, ball + [0, 0, 0.3], after_ns=lifted_at)


def test_ur3_runs(ros_graph):
    start_sim(ros_graph, robot_model='ur3', camera_rate=0.0, real_time_factor=FAST)
    probe = Probe(ros_graph)
    probe.send(probe.jog, ['elbow_joint'], [math.radians(5)])
    probe.wait_positions({'elbow_joint': math.radians(5)})
    assert probe.get_parameter('robot_model') == 'ur3'


def run_sim(*parameters: str, domain_id: int = 231) -> subprocess.Popen:
    args = [SIM_BIN, '--ros-args']
    for parameter in parameters:
        args += ['-p', parameter]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(domain_id))
    return subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)


def read_until(process: subprocess.Popen, text: bytes, timeout: float) -> bytes:
    """Read the process's stderr until ``text`` appears; fail after ``timeout`` seconds."""
    seen = b''
    deadline = time.monotonic() + timeout
    while text not in seen:
        assert time.monotonic() < deadline, f'no {text!r} within {timeout} s: {seen!r}'
        if select.select([process.stderr], [], [], 0.2)[0]:
            chunk = os.read(process.stderr.fileno(), 4096)
            assert chunk or process.poll() is None, f'exited {process.returncode}: {seen!r}'
            seen += chunk
    return seen


@pytest.mark.parametrize('parameter, reason', [
    ('robot_model:=ur7', 'robot_model must be ur5 or ur3'),
    ('physics_rate:=-5.0', 'physics_rate must be between'),
    ('camera_position:=[1.0, 2.0]', 'camera_position needs 3 numbers'),
    ('camera_rate:=fast', "'camera_rate' to 'fast' of type 'STRING', expecting type 'DOUBLE'"),
    ('renderer:=opengl', "renderer must be auto, egl, tiny, got 'opengl'"),
])
def test_bad_start_up_parameter_exits_non_zero_with_one_line(parameter, reason):
    process = run_sim(parameter)
    out, err = (text.decode() for text in process.communicate(timeout=60))
    assert process.returncode != 0
    assert reason in err
    assert 'Traceback' not in err + out
    assert len([line for line in err.splitlines() if 'FATAL' in line]) == 1


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_the_node_within_two_seconds(sig):
    process = run_sim('camera_rate:=0.0')
    try:
        read_until(process, b'simulating', 60)
        sent = time.monotonic()
        process.send_signal(sig)
        out, err = (text.decode() for text in process.communicate(timeout=10))
        assert time.monotonic() - sent < 2.0
        assert process.returncode == 0
        assert 'Traceback' not in err + out
    finally:
        if process.poll() is None:
            process.kill()


def test_commands_are_served_while_a_service_waits(ros_graph):
    """In the sim process, a gripper motion in progress delays neither jogs nor publishing."""
    process = run_sim('camera_rate:=0.0', domain_id=ros_graph.domain_id)
    try:
        probe = Probe(ros_graph)
        probe.latest('joint_states', timeout=60)
        client = probe.node.create_client(Trigger, 'gripper/close')
        wait_for(client.service_is_ready, 30, 'the gripper/close service')
        closing = client.call_async(Trigger.Request())
        probe.send(probe.jog, ['wrist_3_joint'], [0.05])
        probe.wait_positions({'wrist_3_joint': 0.05}, tolerance=math.radians(0.5))
        assert not closing.done(), 'the jog waited for the gripper to close'
        wait_for(closing.done, 30, 'the gripper to close')
        assert closing.result().success
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=10)
