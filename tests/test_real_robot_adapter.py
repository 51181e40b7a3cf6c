"""ur_rg2_hardware's rg2_adapter: our GripperCommand contract over OnRobot's RG2 driver.

The mapping alone (plain), then the node between a GripperCommand client and an OnRobot-shaped
ParallelGripperCommand stand-in (tests/real_robot_standins.py).
"""

from action_msgs.msg import GoalStatus
from conftest import wait_for
from control_msgs.action import GripperCommand
import pytest
from real_robot_standins import OnRobotGripper, add
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.contract import GRIPPER_ACTION, GRIPPER_JOINTS
from ur_rg2_hardware.gripper_mapping import grip_goal, outcome
from ur_rg2_hardware.rg2_adapter import Rg2Adapter

TIMEOUT = 30.0  # s on a loaded machine


def test_goals_are_clamped_as_the_contract_says():
    assert grip_goal(0.2, 0.0) == grip_goal(0.110, 40.0)
    assert grip_goal(-0.01, 100.0).position == 0.0
    assert grip_goal(0.05, 1.0).effort == 3.0
    assert grip_goal(0.05, -1.0).effort == 40.0
    with pytest.raises(ValueError, match='not finite'):
        grip_goal(float('nan'), 10.0)


@pytest.mark.parametrize(('succeeded', 'aborted', 'stalled', 'end', 'expected'), [
    # OnRobot's controller (allow_stalling: true): a stall on the ball succeeds, stalled.
    (True, False, True, 0.060, (True, True, False)),
    # ros2_controllers' default (allow_stalling: false): the stall aborts; still our grasp.
    (False, True, True, 0.060, (True, True, False)),
    # Closed on nothing: reached, not stalled.
    (True, False, False, 0.0, (True, False, True)),
    # A driver that says nothing of the stall but stopped short: a grasp.
    (True, False, False, 0.060, (True, True, False)),
    # Aborted short without a stall flag: a fault, not a grasp.
    (False, True, False, 0.060, (False, False, False)),
])
def test_a_driver_end_maps_to_our_result(succeeded, aborted, stalled, end, expected):
    result = outcome(grip_goal(0.0, 40.0), 0.110, succeeded, aborted, stalled, end)
    assert (result.succeeded, result.stalled, result.reached_goal) == expected
    assert result.position == end


def test_an_opening_that_reaches_its_target_succeeds():
    result = outcome(grip_goal(0.110, 0.0), 0.06, True, False, False, 0.1095)
    assert result.succeeded and result.reached_goal and not result.stalled


@pytest.mark.parametrize('allow_stalling', [True, False])
def test_the_adapter_reports_a_grasp_as_succeeded_and_stalled_and_feeds_the_opening(
        ros_graph, allow_stalling):
    gripper = add(ros_graph, OnRobotGripper(context=ros_graph.context))
    gripper.allow_stalling = allow_stalling
    add(ros_graph, Rg2Adapter(context=ros_graph.context))
    probe = ros_graph.node('probe')
    openings = []
    probe.create_subscription(JointState, 'joint_states', lambda m: openings.append(
        sum(m.position[m.name.index(n)] for n in GRIPPER_JOINTS)), 10)
    client = ThreadSafeActionClient(probe, GripperCommand, GRIPPER_ACTION)
    wait_for(client.server_is_ready, TIMEOUT, 'the adapter')
    wait_for(lambda: openings, TIMEOUT, 'the opening on joint_states')
    assert abs(openings[-1] - 0.110) < 1e-6

    def run(position):
        goal = GripperCommand.Goal()
        goal.command.position, goal.command.max_effort = position, 20.0
        sent = client.send_goal_async(goal)
        wait_for(sent.done, TIMEOUT, 'the goal accepted')
        assert sent.result().accepted
        ended = sent.result().get_result_async()
        wait_for(ended.done, TIMEOUT, 'the goal to end')
        return ended.result()

    gripper.object_width = 0.06
    closed = run(0.0)
    assert closed.status == GoalStatus.STATUS_SUCCEEDED
    assert closed.result.stalled and not closed.result.reached_goal
    assert abs(closed.result.position - 0.06) < 1e-3
    sent = gripper.goals[-1].command
    assert (sent.name, list(sent.position), list(sent.effort)) == (['grip_stroke'], [0.0], [20.0])
    wait_for(lambda: abs(openings[-1] - 0.06) < 1e-3, TIMEOUT, 'the held opening')
    opened = run(0.2)  # clamped to the RG2's 0.110
    assert opened.status == GoalStatus.STATUS_SUCCEEDED
    assert opened.result.reached_goal and not opened.result.stalled
    assert abs(opened.result.position - 0.110) < 1e-3
    # The keys' services, as the sim serves them.
    close = probe.create_client(Trigger, 'gripper/close')
    wait_for(close.service_is_ready, TIMEOUT, 'gripper/close')
    answer = close.call_async(Trigger.Request())
    wait_for(answer.done, TIMEOUT, 'the gripper/close answer')
    assert answer.result().success and 'grasped an object' in answer.result().message


def test_without_the_driver_a_goal_fails_saying_what_is_missing(ros_graph, capfd):
    add(ros_graph, Rg2Adapter(context=ros_graph.context))
    probe = ros_graph.node('probe')
    client = ThreadSafeActionClient(probe, GripperCommand, GRIPPER_ACTION)
    wait_for(client.server_is_ready, TIMEOUT, 'the adapter')
    sent = client.send_goal_async(GripperCommand.Goal())
    wait_for(sent.done, TIMEOUT, 'the goal accepted')
    ended = sent.result().get_result_async()
    wait_for(ended.done, TIMEOUT, 'the goal to end')
    assert ended.result().status == GoalStatus.STATUS_ABORTED
    err: list[str] = []
    wait_for(lambda: err.append(capfd.readouterr().err) or 'onrobot/gripper_controller/'
             'gripper_cmd is not available' in ''.join(err), TIMEOUT, 'the warning')
