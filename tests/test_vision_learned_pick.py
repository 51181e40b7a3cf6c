"""``pick_ball`` with ``detector:=learned`` and the shipped model: a white and a grey ball.

The sim (camera on), the vision node with the learned detector and the motion node in one
graph, as the motion tests' vision pick: a ball without a hue, which no colour rule finds, is
found by the network, located by the depth and picked.
"""

from conftest import wait_for
from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger
from test_motion_node import TIMEOUT, Rig, ball_held
from ur_rg2_vision.vision_node import VisionNode

# On the reachable floor in the sim's default camera's view (world, m).
PLACEMENTS = {'white': (0.5, -0.3, 0.03), 'grey': (0.45, -0.45, 0.03)}
COLORS = {'white': [1.0, 1.0, 1.0, 1.0], 'grey': [0.5, 0.5, 0.5, 1.0]}


@pytest.mark.parametrize('color', ['white', 'grey'])
def test_pick_ball_picks_a_ball_without_a_hue_the_network_finds(ros_graph, color):
    placement = PLACEMENTS[color]
    # The learned detector shares this process with the sim and motion: on a loaded machine
    # a second may pass between sightings, and the ball does not move.
    rig = Rig(ros_graph, {'ball_timeout': 5.0}, camera_rate=15.0, real_time_factor=1.0,
              ball_color=COLORS[color], ball_position=list(placement))
    ros_graph.add(VisionNode(context=ros_graph.context, parameter_overrides=[
        Parameter('detector', value='learned')]))
    truth: list = []
    rig.node.create_subscription(PoseStamped, 'ball/true_pose', truth.append, 10)
    seen: list = []
    rig.node.create_subscription(PointStamped, 'ball/position', seen.append, 10)
    opener = rig.node.create_client(Trigger, 'gripper/open')
    wait_for(opener.service_is_ready, TIMEOUT, 'the sim services')
    future = opener.call_async(Trigger.Request())
    wait_for(future.done, TIMEOUT, 'the gripper to open')
    wait_for(lambda: len(seen) > 3, TIMEOUT, f'vision to see the {color} ball')
    answer = rig.pick()
    held = ball_held(rig, truth)
    assert answer.success == held, answer.message
    assert answer.success, answer.message
    assert 'picked the ball at' in answer.message
    lifted = np.array([truth[-1].pose.position.x, truth[-1].pose.position.y])
    assert np.linalg.norm(lifted - placement[:2]) < 0.05  # that ball, not something else
