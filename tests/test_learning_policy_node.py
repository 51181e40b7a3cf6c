"""Node ``ur_rg2_policy`` through its contract: policy/run drives the arm to the ball.

The sim runs in-process (camera off); a probe publishes ``ball/position`` in the world frame
where the sim has the ball, as the vision node would in its optical frame, and reads the TCP
back from /tf. The policy node runs the shipped Reach policy.
"""

import threading

from conftest import start_sim, wait_for
from geometry_msgs.msg import PointStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import LATCHED_QOS
from ur_rg2_common.tf_buffer import TransformBuffer
from ur_rg2_learning.actor import PolicyError
from ur_rg2_learning.envs import REACH_TOLERANCE
from ur_rg2_learning.policy_node import PolicyNode

TIMEOUT = 60.0  # s of wall time on a loaded 2-core machine
BALL = (0.45, -0.25, 0.03)  # world, on the floor
RADIUS = 0.03


def test_policy_run_drives_the_tcp_to_the_ball(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=2.0, ball_position=list(BALL),
              ball_radius=RADIUS)
    policy = ros_graph.add(PolicyNode(context=ros_graph.context))
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
    ball = probe.create_publisher(PointStamped, 'ball/position', 10)
    run = probe.create_client(Trigger, 'policy/run')
    wait_for(run.service_is_ready, TIMEOUT, 'the policy/run service')
    wait_for(lambda: policy._trajectory.server_is_ready(), TIMEOUT, 'the trajectory controller')

    def call() -> Trigger.Response:
        future = run.call_async(Trigger.Request())
        wait_for(future.done, TIMEOUT, 'the policy/run answer')
        return future.result()

    refused = call()  # no ball seen yet
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

    probe.create_timer(0.05, publish_ball)
    wait_for(lambda: policy._ball is not None, TIMEOUT, 'the ball to reach the policy node')
    wait_for(lambda: tree.frames() >= {'world', 'rg2_tcp'}, TIMEOUT, 'the transform tree')
    before = tcp_to_ball_top()
    started = call()
    assert started.success, started.message
    assert started.message.startswith('episode started')
    busy = call()
    assert not busy.success and 'already running' in busy.message
    wait_for(lambda: driving and driving[-1], TIMEOUT, 'policy/driving true')
    wait_for(lambda: not driving[-1], 3 * TIMEOUT, 'the episode to end')
    after = tcp_to_ball_top()
    assert after < 1.5 * REACH_TOLERANCE < before, (before, after)


def test_a_directory_without_a_policy_is_refused_at_start(ros_graph, tmp_path):
    with pytest.raises(PolicyError, match='no usable policy'):
        PolicyNode(context=ros_graph.context, parameter_overrides=[
            Parameter('policy_dir', value=str(tmp_path))])
