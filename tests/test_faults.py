"""Faults the graph survives (issue 21, point 3), through the nodes' contracts.

- A burst of malformed messages on every topic the nodes subscribe to: every node stays
  alive and its state is unchanged.
- The vision node stopped during a pick: the pick fails with the reason, the arm holds where
  it was, and picks work again once vision is back.
- The sim restarted under a running motion, keys, viewer and policy: each works again once it
  is back, without a restart of its own (the policy refuses to run while the sim is gone).

(An action client killed mid-goal is test_sim_controllers'
test_a_client_that_disappears_leaves_the_arm_holding_still.)
"""

import math
import os
import signal
import subprocess
import sys
import urllib.request

from conftest import start_sim, wait_for
from geometry_msgs.msg import PointStamped, PoseStamped, TransformStamped
import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import ARM_JOINTS, IMAGE_QOS, LATCHED_QOS
from ur_rg2_common.tf_buffer import TransformBuffer, quaternion_from_matrix
from ur_rg2_learning.policy_node import PolicyNode
from ur_rg2_learning.tasks import REACH_TOLERANCE
from ur_rg2_motion.motion_node import MotionNode
from ur_rg2_motion.planning import gripper_down
from ur_rg2_teleop.display import Console
from ur_rg2_teleop.keys_node import KeysNode
from ur_rg2_vision.viewer_node import ViewerNode
from ur_rg2_vision.vision_node import VisionNode

TIMEOUT = 60.0
BURST = 12  # malformed messages per topic
SIM_BIN = os.path.join(os.path.dirname(sys.executable), 'sim')
VISION_BIN = os.path.join(os.path.dirname(sys.executable), 'vision')
BALL = (0.45, -0.25, 0.03)  # world, on the floor
BALL_RADIUS = 0.03
# The arm is still when no joint moved more than this over STILL_STATES joint states.
STILL_RAD = 2e-4
STILL_STATES = 20


class Watch:
    """A probe node: joint states, ball positions, the tree, policy/driving; publishers."""

    def __init__(self, graph) -> None:
        node = self.node = graph.node('fault_probe')
        self.joints: list[tuple[int, np.ndarray]] = []
        self.balls: list[np.ndarray] = []
        self.tree = TransformBuffer()
        self.driving: list[bool] = []
        node.create_subscription(Bool, 'policy/driving',
                                 lambda message: self.driving.append(message.data), LATCHED_QOS)
        node.create_subscription(JointState, 'joint_states', self._on_joints, 100)
        node.create_subscription(PointStamped, 'ball/position', self._on_ball, 100)
        node.create_subscription(TFMessage, '/tf_static', self.tree.add_message, LATCHED_QOS)
        node.create_subscription(TFMessage, '/tf', self.tree.add_message, 100)
        self.command = node.create_publisher(PoseStamped, 'tool_command', 10)

    def _on_joints(self, msg: JointState) -> None:
        # The sim's: the arm joints, then the RG2's (a malformed one of the burst is not).
        if (len(msg.name) == len(msg.position) == 8 and list(msg.name[:6]) == list(ARM_JOINTS)
                and all(math.isfinite(p) for p in msg.position)):
            stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            self.joints.append((stamp, np.array(msg.position[:6])))

    def _on_ball(self, msg: PointStamped) -> None:
        point = np.array([msg.point.x, msg.point.y, msg.point.z])
        if np.isfinite(point).all() and msg.header.frame_id == 'camera_color_optical_frame':
            self.balls.append(point)  # vision's (a malformed one of the burst is not)

    def arm(self) -> np.ndarray:
        return wait_for(lambda: self.joints[-1:], TIMEOUT, 'joint states')[0][1]

    def wait_still(self) -> np.ndarray:
        """Wait until the arm holds still; return its joints."""
        def still():
            recent = [joints for _, joints in self.joints[-STILL_STATES:]]
            return (len(recent) == STILL_STATES
                    and np.ptp(np.array(recent), axis=0).max() < STILL_RAD and [recent[-1]])
        return wait_for(still, TIMEOUT, 'the arm to hold still')[0]

    def sim_seconds_pass(self, seconds: float) -> None:
        """Wait until ``seconds`` of simulation time have passed (joint_states' stamps)."""
        stamp = wait_for(lambda: self.joints[-1:], TIMEOUT, 'joint states')[0][0]
        wait_for(lambda: self.joints[-1][0] > stamp + seconds * 1e9, TIMEOUT,
                 f'{seconds:g} s of simulation time')

    def tcp(self) -> np.ndarray:
        return self.tree.lookup('base_link', 'rg2_tcp')[:3, 3]


def malformed(rng: np.random.Generator) -> dict[str, tuple[type, list]]:
    """Return, per subscribed topic, its type and a list of malformed messages."""
    nan, inf = math.nan, math.inf
    huge = 100_000

    def joint_state(i: int) -> JointState:
        # Each malformed for sure: lengths, names, values.
        names, positions = [
            (list(ARM_JOINTS[:3]), list(rng.normal(size=2))),
            (['no_such_joint'], [0.1]),
            (['elbow_joint'], [nan]),
            ([], []),
            (['elbow_joint'] * huge, [0.1] * huge),
            (list(ARM_JOINTS), [inf, -inf, nan, 1e300, -1e300, 0.0]),
        ][i % 6]
        return JointState(name=names, position=positions,
                          velocity=list(rng.normal(size=int(rng.integers(0, 4)))))

    def pose(i: int) -> PoseStamped:
        msg = PoseStamped()
        frame, position, quaternion = [
            ('base_link', (nan, 0.3, 0.2), (0.0, 0.0, 0.0, 1.0)),
            ('base_link', (0.3, 0.0, 0.2), (2.0, 0.0, 0.0, 0.0)),
            ('nowhere', (0.3, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0)),
            ('', (inf, 1e9, -inf), (0.0, 0.0, 0.0, 0.0)),
        ][i % 4]
        msg.header.frame_id = frame
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z = position
        q.x, q.y, q.z, q.w = quaternion
        return msg

    def jog(i: int) -> TransformStamped:
        msg = TransformStamped()
        frame, translation, rotation = [
            ('base_link', (nan, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
            ('base_link', (0.01, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)),
            ('nowhere', (0.01, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
            ('', (inf, 0.0, 0.0), (5.0, 0.0, 0.0, 1.0)),
        ][i % 4]
        msg.header.frame_id = frame
        t, r = msg.transform.translation, msg.transform.rotation
        t.x, t.y, t.z = translation
        r.x, r.y, r.z, r.w = rotation
        return msg

    def point(i: int) -> PointStamped:
        msg = PointStamped()
        msg.header.frame_id = ['nowhere', '', 'camera_color_optical_frame'][i % 3]
        msg.point.x, msg.point.y, msg.point.z = [(nan, 0.0, 1.0), (inf, 0.0, 1.0),
                                                 (0.0, -inf, nan)][i % 3]
        return msg

    def image(_i: int) -> Image:
        width, height = (int(v) for v in rng.integers(0, 2000, size=2))
        msg = Image(width=width, height=height,
                    encoding=str(rng.choice(['rgb8', '32FC1', 'mono16', 'bgr8', '', 'x'])),
                    step=int(rng.integers(0, 10000)),
                    data=bytes(int(rng.choice([0, 7, 640 * 480 * 3, 3 * huge]))))
        msg.header.frame_id = str(rng.choice(['', 'nowhere', 'camera_color_optical_frame']))
        return msg

    def camera_info(_i: int) -> CameraInfo:
        msg = CameraInfo(width=int(rng.integers(0, 5000)), height=int(rng.integers(0, 5000)))
        msg.k = [float(v) for v in rng.choice([nan, inf, 0.0, -1.0, 500.0], size=9)]
        msg.header.frame_id = str(rng.choice(['', 'nowhere']))
        return msg

    def transforms(_i: int) -> TFMessage:
        msg = TFMessage()
        for _ in range(int(rng.integers(0, 4))):
            t = TransformStamped()
            t.header.frame_id = str(rng.choice(['', 'world', 'base_link']))
            # Frames the sim does not publish again on /tf (rg2_tcp, world) stay as a
            # well-formed re-parenting leaves them, as in tf2: those are not sent here.
            t.child_frame_id = str(rng.choice(['', 'world', 'nowhere']))
            t.transform.translation.x = float(rng.choice([nan, inf, 1.0]))
            t.transform.rotation.w = float(rng.choice([nan, 0.0, 1.0]))
            msg.transforms.append(t)
        return msg

    makers = {
        'joint_jog': (JointState, joint_state), 'joint_command': (JointState, joint_state),
        'joint_states': (JointState, joint_state),
        'tool_command': (PoseStamped, pose), 'tool_jog': (TransformStamped, jog),
        'ball/position': (PointStamped, point),
        'camera/color/image_raw': (Image, image), 'camera/depth/image_raw': (Image, image),
        'ball/image': (Image, image),
        'camera/color/camera_info': (CameraInfo, camera_info),
        '/tf': (TFMessage, transforms),
        'pick_ball/result': (String, lambda _i: String(data='x' * int(rng.integers(0, huge)))),
    }
    return {topic: (kind, [make(i) for i in range(BURST)]) for topic, (kind, make) in
            makers.items()}


def viewer_answers(url: str) -> bool:
    with urllib.request.urlopen(url, timeout=10) as page:
        return page.status == 200 and bool(page.read(100))


def send_tool_command(watch: Watch, target: np.ndarray) -> None:
    """Send a tool_command to ``target`` (base_link)."""
    msg = PoseStamped()
    msg.header.frame_id = 'base_link'
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in target[:3, 3])
    q.x, q.y, q.z, q.w = quaternion_from_matrix(target)
    watch.command.publish(msg)


def tcp_at(watch: Watch, target: np.ndarray) -> bool:
    try:
        return bool(np.linalg.norm(watch.tcp() - target[:3, 3]) < 0.003)
    except LookupError:
        return False


def add_nodes(graph, *nodes):
    for node in nodes:
        blocking = getattr(node, 'blocking_group', None)
        if blocking is not None:
            graph.executor.add_blocking_group(blocking)
        graph.add(node)
    return nodes


def test_a_burst_of_malformed_messages_leaves_every_node_alive_and_unchanged(ros_graph):
    start_sim(ros_graph, camera_width=320, camera_height=240, camera_rate=10.0)
    _, motion, viewer = add_nodes(
        ros_graph, VisionNode(context=ros_graph.context), MotionNode(context=ros_graph.context),
        ViewerNode(context=ros_graph.context, parameter_overrides=[Parameter('port', value=0)]))
    watch = Watch(ros_graph)
    wait_for(lambda: len(watch.balls) > 3, TIMEOUT, 'vision to see the ball')
    wait_for(lambda: motion.state.urdf is not None and motion._trajectory.server_is_ready(),
             TIMEOUT, 'the motion node')
    before = watch.arm()
    ball_before = np.mean(watch.balls[-3:], axis=0)

    for topic, (kind, messages) in malformed(np.random.default_rng(21)).items():
        qos = (IMAGE_QOS if kind in (Image, CameraInfo) else
               LATCHED_QOS if topic == 'pick_ball/result' else 100)
        publisher = watch.node.create_publisher(kind, topic, qos)
        wait_for(publisher.get_subscription_count, TIMEOUT, f'a subscriber of {topic}')
        for message in messages:
            publisher.publish(message)

    # Alive and unchanged: the sim still stepping, the arm where it was, the ball seen where
    # it was, the viewer serving, a tool_command executed.
    stamp = watch.joints[-1][0]
    wait_for(lambda: watch.joints[-1][0] > stamp + 5 * 10 ** 8, TIMEOUT, 'the sim stepping')
    assert np.abs(watch.arm() - before).max() < 1e-3
    count = len(watch.balls)
    wait_for(lambda: len(watch.balls) > count + 3, TIMEOUT, 'vision to go on')
    assert np.linalg.norm(np.mean(watch.balls[-3:], axis=0) - ball_before) < 0.005
    assert viewer_answers(viewer.url)
    target = gripper_down((0.35, -0.1, 0.15), 0.0)
    send_tool_command(watch, target)
    wait_for(lambda: tcp_at(watch, target), TIMEOUT, 'the TCP at the target')


def call(node, service: str, timeout: float = TIMEOUT) -> Trigger.Response:
    """Call a Trigger service of the graph from ``node``; return the answer."""
    client = node.create_client(Trigger, service)
    try:
        wait_for(client.service_is_ready, TIMEOUT, f'the {service} service')
        future = client.call_async(Trigger.Request())
        wait_for(future.done, timeout, f'the {service} answer')
        return future.result()
    finally:
        node.destroy_client(client)


def start_process(binary: str, graph, *parameters: str) -> subprocess.Popen:
    """Start a node's executable in ``graph``'s domain with ``name:=value`` parameters."""
    arguments = [binary, '--ros-args'] + [word for p in parameters for word in ('-p', p)]
    return subprocess.Popen(arguments, env=graph.env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def stop_process(process: subprocess.Popen) -> None:
    process.send_signal(signal.SIGINT)
    process.wait(15)


def test_vision_stopped_during_a_pick_fails_it_with_the_reason_and_the_arm_holds(ros_graph):
    start_sim(ros_graph, camera_rate=10.0, camera_width=320, camera_height=240)
    (motion,) = add_nodes(ros_graph, MotionNode(context=ros_graph.context))
    watch = Watch(ros_graph)
    results: list[str] = []
    watch.node.create_subscription(String, 'pick_ball/result',
                                   lambda message: results.append(message.data), LATCHED_QOS)
    vision = start_process(VISION_BIN, ros_graph)
    try:
        wait_for(lambda: len(watch.balls) > 3, TIMEOUT, 'vision to see the ball')
        wait_for(lambda: motion.state.urdf is not None and motion._trajectory.server_is_ready(),
                 TIMEOUT, 'the motion node')
        # Slow moves: the pick is still on its way to the ball when the vision node has gone,
        # however long that takes on a loaded machine.
        defaults = motion.get_parameters(['speed_scale', 'approach_speed'])
        motion.set_parameters([Parameter('speed_scale', value=0.1),
                               Parameter('approach_speed', value=0.02)])
        home = watch.wait_still()
        client = watch.node.create_client(Trigger, 'pick_ball')
        wait_for(client.service_is_ready, TIMEOUT, 'the pick_ball service')
        pick = client.call_async(Trigger.Request())
        wait_for(lambda: np.abs(watch.arm() - home).max() > 0.02, TIMEOUT,
                 'the pick to move the arm')
        vision.terminate()  # SIGTERM, as kill sends it
        vision.wait(15)
        wait_for(pick.done, TIMEOUT, 'the pick to end')
        answer = pick.result()
        assert not answer.success
        assert 'vision lost: nothing publishes ball/position' in answer.message, answer.message
        wait_for(lambda: results and 'vision lost' in results[-1], TIMEOUT, 'the result topic')
        assert results[-1].startswith('failed: ')
        # Stopped on its way (not at home), and no further motion.
        held = watch.wait_still()
        assert np.abs(held - home).max() > 0.02
        watch.sim_seconds_pass(1.0)
        assert np.abs(watch.arm() - held).max() < 1e-3

        # Vision back: a pick works again, at the usual speed, from home.
        vision = start_process(VISION_BIN, ros_graph)
        motion.set_parameters(defaults)
        assert call(watch.node, 'reset').success
        wait_for(lambda: np.abs(watch.arm()).max() < 0.01, TIMEOUT, 'the arm at home')
        count = len(watch.balls)
        wait_for(lambda: len(watch.balls) > count + 3, TIMEOUT, 'vision to see the ball again')
        answer = call(watch.node, 'pick_ball', 3 * TIMEOUT)
        assert answer.success, answer.message
        assert 'picked the ball at' in answer.message
    finally:
        stop_process(vision)


def serves_again(watch: Watch, motion: MotionNode, keys: KeysNode, viewer: ViewerNode,
                 run: int) -> None:
    """Check that keys, motion, viewer and policy work with the sim that has just started."""
    watch.joints.clear()
    home = watch.arm()
    keys.handle_key('q')  # shoulder_pan + one step
    wait_for(lambda: abs(watch.arm()[0] - home[0] - math.radians(5.0)) < 0.01, TIMEOUT,
             f'the jog key to move the arm (sim run {run})')
    wait_for(motion._trajectory.server_is_ready, TIMEOUT, 'the trajectory controller')
    target = gripper_down((0.35, -0.1, 0.15), 0.0)
    send_tool_command(watch, target)
    wait_for(lambda: tcp_at(watch, target), TIMEOUT, f'the TCP at the target (sim run {run})')
    assert viewer_answers(viewer.url)
    # The policy drives the TCP to the ball's top (the ball as the probe reports it).
    watch.driving.clear()
    started = call(watch.node, 'policy/run')
    assert started.success, f'sim run {run}: {started.message}'
    wait_for(lambda: watch.driving[-1:] == [True], TIMEOUT, f'policy/driving (sim run {run})')
    wait_for(lambda: watch.driving[-1:] == [False], 3 * TIMEOUT,
             f'the policy episode to end (sim run {run})')
    top = np.add(BALL, (0.0, 0.0, BALL_RADIUS))
    # This process's /tf may lag the episode's last step on a loaded machine.
    wait_for(lambda: np.linalg.norm(watch.tree.lookup('world', 'rg2_tcp')[:3, 3] - top)
             < 1.5 * REACH_TOLERANCE, 10.0, f'the TCP at the ball top (sim run {run})')


def test_a_sim_restarted_under_motion_keys_viewer_and_policy_serves_them_again(ros_graph):
    motion, viewer, keys, policy = add_nodes(
        ros_graph, MotionNode(context=ros_graph.context),
        ViewerNode(context=ros_graph.context, parameter_overrides=[Parameter('port', value=0)]),
        KeysNode(Console(open(os.devnull, 'w')), context=ros_graph.context),
        PolicyNode(context=ros_graph.context))
    watch = Watch(ros_graph)
    ball = watch.node.create_publisher(PointStamped, 'ball/position', 10)

    def publish_ball() -> None:  # as vision would (in the world frame here)
        point = PointStamped()
        point.header.frame_id = 'world'
        point.point.x, point.point.y, point.point.z = BALL
        ball.publish(point)

    watch.node.create_timer(0.05, publish_ball)
    for run in (1, 2):
        sim = start_process(SIM_BIN, ros_graph, 'camera_rate:=5.0', 'camera_width:=160',
                            'camera_height:=120', f'ball_position:={list(BALL)}',
                            f'ball_radius:={BALL_RADIUS}')
        try:
            serves_again(watch, motion, keys, viewer, run)
        finally:
            stop_process(sim)
        # Gone: the policy notices and refuses to run, with the reason.
        wait_for(lambda: not policy._trajectory.server_is_ready(), TIMEOUT,
                 'the policy node to see the trajectory controller go')
        refused = call(watch.node, 'policy/run')
        assert not refused.success
        assert 'is not available (is the sim running?)' in refused.message, refused.message
