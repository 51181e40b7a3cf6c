"""Node ``ur_rg2_policy`` through its contract: policy/run drives the arm to the ball.

The sim runs in-process (camera off); a probe publishes ``ball/position`` in the world frame
where the sim has the ball, as the vision node would in its optical frame, and reads the TCP
back from /tf. The policy node runs the shipped Reach policy.
"""

import re
import threading

from conftest import start_sim, wait_for
from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from test_episode_markers import Markers
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import LATCHED_QOS
from ur_rg2_common.tf_buffer import TransformBuffer
from ur_rg2_learning.actor import PolicyError
from ur_rg2_learning.policy_node import PolicyNode
from ur_rg2_learning.tasks import REACH_TOLERANCE

TIMEOUT = 60.0  # s of wall time on a loaded 2-core machine

BALL = (0.45, -0.25, 0.03)  # world, on the floor
RADIUS = 0.03


def call(client) -> Trigger.Response:
    """Call the Trigger service of ``client`` (once it is there) and return its answer."""
    wait_for(client.service_is_ready, TIMEOUT, f'the {client.srv_name} service')
    future = client.call_async(Trigger.Request())
    wait_for(future.done, TIMEOUT, f'the {client.srv_name} answer')
    return future.result()


def test_policy_run_drives_the_tcp_to_the_ball(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=2.0, ball_position=list(BALL),
              ball_radius=RADIUS)
    policy = ros_graph.add(PolicyNode(context=ros_graph.context))
    ros_graph.executor.add_blocking_group(policy.blocking_group)  # as run_node does
    probe = ros_graph.node('probe')
    tree = TransformBuffer()
    probe.create_subscription(TFMessage, '/tf_static', tree.add_message, LATCHED_QOS)
    probe.create_subscription(TFMessage, '/tf', tree.add_message, 100)
    lock = threading.Lock()
    driving: list[bool] = []

    def on_driving(message: Bool) -> None:
        with lock:
            driving.append(message.data)

    probe.create_subscription(Bool, 'policy/driving', on_driving, LATCHED_QOS)
    results: list[str] = []
    probe.create_subscription(String, 'policy/result', lambda m: results.append(m.data),
                              LATCHED_QOS)
    markers = Markers(probe)
    ball = probe.create_publisher(PointStamped, 'ball/position', 10)
    run = probe.create_client(Trigger, 'policy/run')
    wait_for(run.service_is_ready, TIMEOUT, 'the policy/run service')
    wait_for(lambda: policy._trajectory.server_is_ready(), TIMEOUT, 'the trajectory controller')

    refused = call(run)  # no ball seen yet
    assert not refused.success
    assert refused.message.startswith('refused: no ball seen')

    def tcp_to_ball_top() -> float:
        tcp = tree.lookup('world', 'rg2_tcp')[:3, 3]
        return float(np.linalg.norm(tcp - np.add(BALL, (0, 0, RADIUS))))

    def publish_ball() -> None:
        point = PointStamped()
        point.header.frame_id = 'world'
        point.point.x, point.point.y, point.point.z = BALL
        ball.publish(point)

    far = PointStamped()
    far.header.frame_id = 'world'
    far.point.x, far.point.y, far.point.z = 1.5, -0.2, RADIUS
    far_timer = probe.create_timer(0.05, lambda: ball.publish(far))
    wait_for(lambda: policy.state.ball is not None, TIMEOUT,
             'the far ball to reach the policy node')
    out = call(run)
    assert not out.success
    assert out.message.startswith('refused: the ball is out of reach'), out.message
    probe.destroy_timer(far_timer)
    probe.create_timer(0.05, publish_ball)
    wait_for(lambda: policy.state.ball.point.x == BALL[0], TIMEOUT,
             'the ball to reach the policy node')
    wait_for(lambda: tree.frames() >= {'world', 'rg2_tcp'}, TIMEOUT, 'the transform tree')
    before = tcp_to_ball_top()
    started = call(run)
    assert started.success, started.message
    assert started.message.startswith('episode started')
    busy = call(run)
    assert not busy.success and 'already running' in busy.message
    wait_for(lambda: driving and driving[-1], TIMEOUT, 'policy/driving true')
    wait_for(lambda: not driving[-1], 3 * TIMEOUT, 'the episode to end')
    assert 1.5 * REACH_TOLERANCE < before
    # This process's /tf may lag the node's last step on a loaded machine.
    wait_for(lambda: tcp_to_ball_top() < 1.5 * REACH_TOLERANCE, 10.0,
             f'the TCP at the ball top (it is {tcp_to_ball_top():.3f} m away)')
    # The episode on 'episode' too; the refused runs marked none.
    wait_for(lambda: markers() == ['start', 'success'], 10.0, 'a start and a success marker')
    # The outcome line on policy/result, latched, with the time taken.
    wait_for(lambda: results, 10.0, 'the outcome on policy/result')
    assert len(results) == 1
    assert re.fullmatch(r'success: reached the ball: TCP \d+ mm from its top .*\(\d+\.\d s\)',
                        results[0]), results


PICK_PLACEMENTS = 5


def test_the_shipped_pick_policy_lifts_balls_the_camera_sees(ros_graph):
    """policy_dir:=pick, the ball from the vision node: placements never trained on."""
    from ur_rg2_vision.vision_node import VisionNode

    sim = start_sim(ros_graph, camera_rate=15.0, real_time_factor=1.0)
    ros_graph.add(VisionNode(context=ros_graph.context))
    policy = ros_graph.add(PolicyNode(context=ros_graph.context, parameter_overrides=[
        Parameter('policy_dir', value='pick')]))
    ros_graph.executor.add_blocking_group(policy.blocking_group)
    probe = ros_graph.node('probe')
    tree = TransformBuffer()
    probe.create_subscription(TFMessage, '/tf_static', tree.add_message, LATCHED_QOS)
    probe.create_subscription(TFMessage, '/tf', tree.add_message, 100)
    truth: list[PoseStamped] = []
    probe.create_subscription(PoseStamped, 'ball/true_pose', truth.append, 10)
    seen: list[PointStamped] = []
    probe.create_subscription(PointStamped, 'ball/position', seen.append, 10)
    driving: list[bool] = []
    probe.create_subscription(Bool, 'policy/driving', lambda m: driving.append(m.data),
                              LATCHED_QOS)
    joints: list[JointState] = []
    probe.create_subscription(JointState, 'joint_states', joints.append, 10)
    run = probe.create_client(Trigger, 'policy/run')
    reset = probe.create_client(Trigger, 'reset')
    opener = probe.create_client(Trigger, 'gripper/open')
    wait_for(lambda: policy._gripper.server_is_ready(), TIMEOUT, 'the gripper controller')

    def held_now() -> bool:
        ball = truth[-1].pose.position
        tcp = tree.lookup('world', 'rg2_tcp')[:3, 3]
        return ball.z > RADIUS + 0.1 and np.linalg.norm(tcp - (ball.x, ball.y, ball.z)) < 0.03

    def held() -> bool:
        # This process's /tf and ball/true_pose may lag the episode's end a little.
        try:
            wait_for(held_now, 5.0, 'the ball held')
        except AssertionError:
            return False
        return True

    # Placements seeded apart from every episode of training (the region the env samples).
    rng = np.random.default_rng(20261125)
    lifted = []
    for _ in range(PICK_PLACEMENTS):
        distance, heading = rng.uniform(0.37, 0.53), rng.uniform(-1.35, 0.3)
        placement = (distance * np.cos(heading), distance * np.sin(heading), RADIUS)
        call(opener)
        call(reset)
        wait_for(lambda: joints and np.abs(joints[-1].position[:6]).max() < 0.01, TIMEOUT,
                 'the arm at home')
        sim.set_parameters([Parameter('ball_position', value=list(placement))])
        wait_for(lambda at=placement: np.linalg.norm(np.subtract(
            [truth[-1].pose.position.x, truth[-1].pose.position.y], at[:2])) < 0.005,
            TIMEOUT, 'the ball at its placement')
        seen.clear()  # frames from before the move may still come
        wait_for(lambda: len(seen) > 6, TIMEOUT, f'vision to see the ball at {placement}')
        driving.clear()
        started = call(run)
        assert started.success, started.message
        wait_for(lambda: driving and not driving[-1], 3 * TIMEOUT, 'the episode to end')
        lifted.append(held())
    assert sum(lifted) >= PICK_PLACEMENTS - 1, lifted


def test_pick_refuses_a_ball_unseen_or_out_of_reach_and_stops_when_it_is_lost(ros_graph,
                                                                              capfd):
    """policy/run's reasons, and the outcome line of an episode whose ball vanishes.

    The probe stands in for the vision node: it publishes nothing, then a ball out of reach,
    then one where the sim has none, which it stops publishing once the episode is under way.
    Reasons are read from the node's console, as in test_motion_node (not /rosout).
    """
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=2.0, ball_position=list(BALL),
              ball_radius=RADIUS)
    policy = ros_graph.add(PolicyNode(context=ros_graph.context, parameter_overrides=[
        Parameter('policy_dir', value='pick')]))
    ros_graph.executor.add_blocking_group(policy.blocking_group)
    probe = ros_graph.node('probe')
    driving: list[bool] = []
    probe.create_subscription(Bool, 'policy/driving', lambda m: driving.append(m.data),
                              LATCHED_QOS)
    results: list[str] = []
    probe.create_subscription(String, 'policy/result', lambda m: results.append(m.data),
                              LATCHED_QOS)
    ball = probe.create_publisher(PointStamped, 'ball/position', 10)
    run = probe.create_client(Trigger, 'policy/run')
    shown: list[tuple[float, float, float] | None] = [None]

    def publish_ball() -> None:
        if shown[0] is not None:
            point = PointStamped()
            point.header.frame_id = 'world'
            point.point.x, point.point.y, point.point.z = shown[0]
            ball.publish(point)

    probe.create_timer(0.05, publish_ball)
    wait_for(run.service_is_ready, TIMEOUT, 'the policy/run service')
    wait_for(lambda: policy._gripper.server_is_ready(), TIMEOUT, 'the gripper controller')

    console = ['']

    def said(text: str) -> bool:
        console[0] += capfd.readouterr().err
        return text in console[0]

    def ball_seen_at(at) -> bool:
        seen = policy.state.ball
        return seen is not None and np.allclose((seen.point.x, seen.point.y, seen.point.z), at)

    refused = call(run)
    assert not refused.success and refused.message.startswith('refused: no ball seen')
    wait_for(lambda: said('policy/run refused: no ball seen'), 10.0, 'the refusal logged')
    far = (1.5, -0.2, RADIUS)
    shown[0] = far
    wait_for(lambda: ball_seen_at(far), TIMEOUT, 'the far ball at the policy node')
    refused = call(run)
    assert not refused.success
    assert refused.message.startswith('refused: the ball is out of reach'), refused.message
    ghost = (0.4, 0.1, RADIUS)  # the sim's ball lies at BALL
    shown[0] = ghost
    wait_for(lambda: ball_seen_at(ghost), TIMEOUT, 'the ball at the policy node')
    started = call(run)
    assert started.success, started.message
    wait_for(lambda: policy._episode is None or policy._episode.step >= 2, 3 * TIMEOUT,
             'the episode under way')
    shown[0] = None
    wait_for(lambda: driving and not driving[-1], 3 * TIMEOUT, 'the episode to end')
    wait_for(lambda: said('policy episode: stopped: the ball is no longer seen'), 10.0,
             'the outcome line naming the lost ball')
    wait_for(lambda: results, 10.0, 'the outcome on policy/result')
    assert re.fullmatch(r'failed: stopped: the ball is no longer seen.*\(\d+\.\d s\)',
                        results[0]), results


def test_a_directory_without_a_policy_is_refused_at_start(ros_graph, tmp_path):
    with pytest.raises(PolicyError, match='no usable policy'):
        PolicyNode(context=ros_graph.context, parameter_overrides=[
            Parameter('policy_dir', value=str(tmp_path))])
