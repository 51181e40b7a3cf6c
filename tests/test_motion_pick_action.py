"""The pick as an action, without ROS (ur_rg2_motion.pick_action), and through the contract.

Plain: the phases a pick reports and the distance to go, one pick at a time and its cancel, the
outcome. Through the contract, with the sim in-process and ``ball/position`` published as vision
would: ``ros2 action send_goal /pick_ball ... --feedback`` picks the ball, a cancel mid-way holds
the arm where it is, and ``ros2 service call /pick_ball`` still picks.
"""

import math
import re
import subprocess
import threading

from action_msgs.msg import GoalStatus
from conftest import wait_for
from geometry_msgs.msg import PointStamped, PoseStamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from test_motion_node import TIMEOUT, Rig, ball_held
from test_motion_pick import BALL, SETTINGS, ScriptedArm, model  # noqa: F401 - a fixture
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_interfaces.action import PickBall
from ur_rg2_motion.pick import PickCancelledError, PickError, run_pick
from ur_rg2_motion.pick_action import (
    CANCELED,
    REFUSED,
    PickProgress,
    PickRun,
    attempt,
    distance_to_go,
)

CLI_TIMEOUT = 180.0  # s: a pick at real time with the ros2 CLI starting on a loaded machine
BALL_IN_WORLD = (0.4, -0.3, 0.03)
PHASES = ['planning', 'approaching', 'descending', 'grasping', 'lifting']


def test_a_pick_reports_each_phase_with_the_waypoints_still_to_go(model):  # noqa: F811
    reported = []
    run_pick(ScriptedArm(), model, BALL, SETTINGS,
             lambda phase, waypoints: reported.append((phase, [tuple(p) for p in waypoints])))
    assert [phase for phase, _ in reported] == PHASES
    waypoints = dict(reported)
    above, grasp, lift = (np.array(p) for p in waypoints['approaching'])
    assert waypoints['planning'] == []
    assert np.allclose(grasp[:2], BALL[:2]) and np.allclose(above - grasp, (0, 0, 0.1))
    assert np.allclose(lift - grasp, (0, 0, SETTINGS.lift_height))
    assert waypoints['descending'] == waypoints['grasping'] == [tuple(grasp), tuple(lift)]
    assert waypoints['lifting'] == [tuple(lift)]


def test_distance_to_go_is_the_path_through_the_waypoints():
    assert distance_to_go((0, 0, 0.3), [(0, 0, 0.1), (0, 0, 0.25)]) == pytest.approx(0.35)
    assert distance_to_go((0.3, 0, 0), [(0, 0.4, 0)]) == pytest.approx(0.5)
    assert math.isnan(distance_to_go((0, 0, 0), []))  # planning: not known yet
    assert math.isnan(distance_to_go(None, [(0, 0, 0)]))  # no joint states


def test_progress_gives_the_last_phase_and_the_distance_from_the_tcp():
    progress = PickProgress()
    phase, distance = progress.feedback((0, 0, 0))
    assert phase == 'planning' and math.isnan(distance)
    progress('descending', [np.array([0.4, 0.0, 0.1]), np.array([0.4, 0.0, 0.25])])
    assert progress.feedback((0.4, 0.0, 0.2)) == ('descending', pytest.approx(0.25))


def test_one_pick_at_a_time_stopped_for_the_first_reason_or_its_clients_cancel():
    run = PickRun()
    run.stop('nothing runs: no effect')
    assert run.start() and run.running and not run.start()
    run.check()
    run.stop('cancelled by a new arm command (tool_command)')
    run.stop('a second reason')
    with pytest.raises(PickCancelledError, match=r'\(tool_command\)$'):
        run.check()
    run.end()
    canceled = threading.Event()
    assert not run.running and run.start(canceled.is_set)
    run.check()  # the previous pick's reason is gone
    canceled.set()
    with pytest.raises(PickCancelledError, match=re.escape(CANCELED)):
        run.check()


def test_an_attempt_says_where_the_ball_was_and_how_long_it_took():
    clock = iter([10.0, 15.1, 20.0, 22.5, 30.0, 30.2]).__next__
    done = attempt(lambda: np.array([0.4, -0.3, -0.17]), lambda _ball: 0.057, clock)
    assert done.success and done.seconds == pytest.approx(5.1)
    assert done.message == ('picked the ball at (0.400, -0.300, -0.170) m in base_link in 5.1 s '
                            '(held at 57 mm)')

    def missed(_ball):
        raise PickError('missed: the gripper closed on nothing')
    failed = attempt(lambda: np.array([0.4, -0.3, -0.17]), missed, clock)
    assert not failed.success and failed.ball is not None
    assert failed.message == ('ball at (0.400, -0.300, -0.170) m in base_link: missed: the '
                              'gripper closed on nothing (after 2.5 s)')

    def unseen():
        raise PickError('no ball seen in the last 1 s')
    nothing = attempt(unseen, missed, clock)
    assert nothing.ball is None and nothing.message == 'no ball seen in the last 1 s (after 0.2 s)'
    assert not REFUSED.success and 'already running' in REFUSED.message


# -- through the contract -------------------------------------------------------------------------

class BallRig(Rig):
    """The sim with its ball at BALL_IN_WORLD and a stand-in for vision seeing it there (10 Hz)."""

    def __init__(self, graph, **sim_parameters) -> None:
        super().__init__(graph, **sim_parameters)
        self.sim.set_parameters([Parameter('ball_position', value=list(BALL_IN_WORLD))])
        seen = PointStamped()
        seen.header.frame_id = 'world'
        seen.point.x, seen.point.y, seen.point.z = BALL_IN_WORLD
        self.node.create_timer(0.1, lambda: self.ball.publish(seen))
        self.truth: list = []
        self.node.create_subscription(PoseStamped, 'ball/true_pose', self.truth.append, 10)
        wait_for(lambda: self.motion.state.ball is not None, TIMEOUT, 'the ball seen')


def cli(env: dict[str, str], *args: str) -> str:
    """Run ``ros2 ARGS`` to its end; return its output, failing the test on a non-zero exit."""
    done = subprocess.run(['ros2', *args], env=env, capture_output=True, text=True,
                          timeout=CLI_TIMEOUT)
    assert done.returncode == 0, f'ros2 {" ".join(args)}:\n{done.stdout}{done.stderr}'
    return done.stdout


def test_ros2_action_send_goal_picks_the_ball_with_feedback(ros_graph):
    rig = BallRig(ros_graph, real_time_factor=1.0)
    out = cli(ros_graph.env, 'action', 'send_goal', '/pick_ball',
              'ur_rg2_interfaces/action/PickBall', '{}', '--feedback')
    assert 'Goal finished with status: SUCCEEDED' in out, out
    assert 'success: true' in out and 'picked the ball at' in out, out
    # Each phase in order, several messages of the moving ones, the distance shrinking.
    phases = re.findall(r'phase: (\w+)', out)
    assert [p for i, p in enumerate(phases) if i == 0 or p != phases[i - 1]] == PHASES, out
    assert phases.count('approaching') >= 3 and phases.count('lifting') >= 2, out
    # YAML's .nan while planning.
    distances = [float(d) for d in re.findall(r'distance_to_go: ([-\d.e+]+)\n', out)]
    assert re.search(r'phase: planning\n\s*distance_to_go: \.nan', out), out
    assert distances[-1] < 0.05 and max(distances) > 0.3, out
    position = re.search(r'ball_position:\s+x: ([-\d.]+)\s+y: ([-\d.]+)', out)
    # base_link is world lifted by the pedestal: x and y are the world's.
    assert (float(position[1]), float(position[2])) == pytest.approx(BALL_IN_WORLD[:2], abs=0.01)
    assert 0.0 < float(re.search(r'time_taken: ([\d.]+)', out)[1]) < 60.0
    assert ball_held(rig, rig.truth)


def test_a_cancel_mid_way_holds_the_arm_where_it_is(ros_graph):
    rig = BallRig(ros_graph, real_time_factor=1.0)
    client = ThreadSafeActionClient(rig.node, PickBall, 'pick_ball')
    wait_for(client.server_is_ready, TIMEOUT, 'the pick_ball action')
    feedback: list[PickBall.Feedback] = []
    sent = client.send_goal_async(PickBall.Goal(),
                                  feedback_callback=lambda msg: feedback.append(msg.feedback))
    wait_for(sent.done, TIMEOUT, 'the goal accepted')
    goal = sent.result()
    assert goal.accepted
    # On its way above the ball: the distance to go has begun to shrink.
    wait_for(lambda: any(f.phase == 'approaching' for f in feedback), 60.0, 'the approach')
    start = next(f.distance_to_go for f in feedback if f.phase == 'approaching')
    wait_for(lambda: feedback[-1].distance_to_go < start - 0.05, TIMEOUT, 'the arm moving')
    canceling = goal.cancel_goal_async()
    result = goal.get_result_async()
    wait_for(result.done, TIMEOUT, 'the result')
    assert canceling.result().goals_canceling
    assert result.result().status == GoalStatus.STATUS_CANCELED
    answer = result.result().result
    assert not answer.success and CANCELED in answer.message, answer.message
    assert answer.ball_position.x == pytest.approx(BALL_IN_WORLD[0], abs=0.01)
    # The arm stops where it was, short of the ball, and stays there; no further feedback.
    held = rig.wait_still()
    ball = rig.tree.lookup('base_link', 'world') @ (*BALL_IN_WORLD, 1.0)
    assert np.linalg.norm(rig.tcp()[:2, 3] - ball[:2]) > 0.02, 'the arm went on above the ball'
    count = len(feedback)
    rig.wait_still()
    assert np.abs(rig.joints() - held).max() < 1e-3
    assert len(feedback) == count


def test_ros2_service_call_pick_ball_still_picks(ros_graph):
    rig = BallRig(ros_graph, real_time_factor=1.0)
    out = cli(ros_graph.env, 'service', 'call', '/pick_ball', 'std_srvs/srv/Trigger')
    assert 'success=True' in out and 'picked the ball at' in out, out
    assert ball_held(rig, rig.truth)
