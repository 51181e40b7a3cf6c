"""The sim's trajectory and gripper actions through their contract (control_msgs actions)."""

import math
import select
import signal
import subprocess
import sys
import textwrap
import time

from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from conftest import start_sim, wait_for
from control_msgs.action import FollowJointTrajectory, GripperCommand
from control_msgs.msg import JointTolerance
import numpy as np
import pytest
from test_sim_node import FAST, GRIPPER_DOWN, Probe, run_sim, stamp_ns
from trajectory_msgs.msg import JointTrajectoryPoint
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_ACTION, TRAJECTORY_ACTION
from ur_rg2_sim.world import SimWorld, WorldConfig

SHUFFLED = ('wrist_2_joint', 'elbow_joint', 'shoulder_pan_joint', 'wrist_3_joint',
            'shoulder_lift_joint', 'wrist_1_joint')
GOAL_TOLERANCE = 0.01  # rad, the contract's default
# A joint that moved less than this in a while is holding still (rad).
STILL = 1e-3


def duration(seconds: float) -> Duration:
    ns = round(seconds * 1e9)
    return Duration(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)


def trajectory(joints, points, **fields) -> FollowJointTrajectory.Goal:
    """Return a goal from (time, positions[, velocities]) tuples and other goal fields."""
    goal = FollowJointTrajectory.Goal(**fields)
    goal.trajectory.joint_names = list(joints)
    for t, positions, *velocities in points:
        point = JointTrajectoryPoint(positions=[float(p) for p in positions],
                                     time_from_start=duration(t))
        if velocities:
            point.velocities = [float(v) for v in velocities[0]]
        goal.trajectory.points.append(point)
    return goal


class Controllers(Probe):
    """The probe with action clients for both controllers."""

    def __init__(self, graph) -> None:
        super().__init__(graph)
        self.arm = ThreadSafeActionClient(self.node, FollowJointTrajectory, TRAJECTORY_ACTION)
        self.gripper = ThreadSafeActionClient(self.node, GripperCommand, GRIPPER_ACTION)

    def send_goal(self, client, goal):
        """Send ``goal``; return its handle and the list its feedback is collected in."""
        wait_for(client.server_is_ready, 30, 'the action server')
        feedback = []
        future = client.send_goal_async(
            goal, feedback_callback=lambda msg: feedback.append((time.monotonic(),
                                                                 msg.feedback)))
        handle = wait_for(lambda: future.done() and future.result(), 30, 'the goal response')
        assert handle.accepted
        return handle, feedback

    def result(self, handle, timeout: float = 60.0):
        future = handle.get_result_async()
        wait_for(future.done, timeout, 'the goal result')
        return future.result()

    def run(self, client, goal, timeout: float = 60.0):
        handle, feedback = self.send_goal(client, goal)
        return self.result(handle, timeout), feedback

    def arm_positions(self) -> np.ndarray:
        positions = self.positions()
        return np.array([positions[name] for name in ARM_JOINTS])

    def assert_holds(self, held: np.ndarray, seconds: float = 0.5) -> None:
        """Assert the arm stays at ``held`` for ``seconds`` more of simulation time."""
        start = stamp_ns(self.latest('joint_states'))
        end = start + round(seconds * 1e9)
        recent = wait_for(lambda: stamp_ns(self.messages('joint_states')[-1]) >= end
                          and self.messages('joint_states'), 30.0,
                          f'{seconds} s more of simulation time')
        for message in recent:
            if stamp_ns(message) > start:
                assert np.array(message.position[:6]) == pytest.approx(held, abs=STILL)

    def wait_still(self, timeout: float = 30.0) -> np.ndarray:
        """Wait until the arm has not moved for 0.3 s of simulation time; return where it is."""
        def still():
            recent = self.messages('joint_states')
            if len(recent) < 31:
                return None
            span = np.array([m.position[:6] for m in recent[-31:]])
            return np.ptp(span, axis=0).max() < STILL and list(span[-1])
        return np.array(wait_for(still, timeout, 'the arm to hold still'))


@pytest.fixture
def sim(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=FAST)
    return Controllers(ros_graph)


def test_three_points_in_shuffled_order_end_successful(sim):
    points = [(1.0, [0.3, 0.4, -0.2, 0.5, -0.3, 0.2]),
              (2.0, [0.6, 0.9, -0.5, 1.0, -0.6, 0.1]),
              (3.0, [0.2, 1.2, -0.8, 0.4, -0.9, 0.3])]
    response, feedback = sim.run(sim.arm, trajectory(SHUFFLED, points))
    assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.error_string
    assert response.result.error_code == FollowJointTrajectory.Result.SUCCESSFUL
    # joint_states may still be on its way: the arm holds still at the last point.
    final = dict(zip(ARM_JOINTS, sim.wait_still()))
    for name, value in zip(SHUFFLED, points[-1][1]):
        assert final[name] == pytest.approx(value, abs=GOAL_TOLERANCE), name
    assert feedback and all(list(f.joint_names) == list(SHUFFLED) for _, f in feedback)


def test_feedback_rate_and_tracking(ros_graph):
    start_sim(ros_graph, camera_rate=0.0)  # real time: feedback rates are in wall time
    sim = Controllers(ros_graph)
    goal = trajectory(ARM_JOINTS[:3], [(1.0, [0.5, -0.5, 0.5]), (2.0, [-0.3, -1.0, 1.2])])
    response, feedback = sim.run(sim.arm, goal)
    assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.error_string
    times = [t for t, _ in feedback]
    assert len(times) >= 10
    assert (len(times) - 1) / (times[-1] - times[0]) >= 10.0
    for _, f in feedback:
        desired, actual, error = (np.array(p.positions) for p in (f.desired, f.actual, f.error))
        assert error == pytest.approx(desired - actual, abs=1e-9)
        assert np.abs(error).max() < math.radians(2.0)


def invalid_goals():
    ok = [(1.0, [0.3])]
    codes = FollowJointTrajectory.Result
    return [
        ('unknown joint', trajectory(['elbow_joint', 'no_such_joint'], [(1.0, [0.3, 0.3])]),
         codes.INVALID_JOINTS),
        ('no joints', trajectory([], [(1.0, [])]), codes.INVALID_JOINTS),
        ('no points', trajectory(['elbow_joint'], []), codes.INVALID_GOAL),
        ('length mismatch', trajectory(['elbow_joint', 'wrist_1_joint'], ok),
         codes.INVALID_GOAL),
        ('velocity length mismatch', trajectory(['elbow_joint'], [(1.0, [0.3], [0.0, 0.0])]),
         codes.INVALID_GOAL),
        ('times not increasing', trajectory(['elbow_joint'], [(1.0, [0.3]), (1.0, [0.4])]),
         codes.INVALID_GOAL),
        ('times decreasing', trajectory(['elbow_joint'], [(2.0, [0.3]), (1.0, [0.4])]),
         codes.INVALID_GOAL),
        ('NaN', trajectory(['elbow_joint'], [(1.0, [math.nan])]), codes.INVALID_GOAL),
        ('inf', trajectory(['elbow_joint'], [(1.0, [math.inf])]), codes.INVALID_GOAL),
        ('too fast', trajectory(['elbow_joint'], [(0.1, [1.5])]), codes.INVALID_GOAL),
        ('out of range', trajectory(['elbow_joint'], [(3.0, [4.0])]), codes.INVALID_GOAL),
        ('tolerance of another joint',
         trajectory(['elbow_joint'], ok, goal_tolerance=[JointTolerance(name='wrist_1_joint')]),
         codes.INVALID_GOAL),
    ]


def test_every_invalid_goal_is_refused_with_its_code_and_the_arm_stays(sim):
    home = sim.arm_positions()
    for what, goal, code in invalid_goals():
        response, _ = sim.run(sim.arm, goal)
        assert response.status == GoalStatus.STATUS_ABORTED, what
        assert response.result.error_code == code, (what, response.result.error_string)
        assert response.result.error_string, what
        wait_for(lambda error=response.result.error_string: [
            w for w in sim.warnings() if error in w], 20, f'a warning about {what}')
    assert sim.arm_positions() == pytest.approx(home, abs=math.radians(0.1))
    # The node still works.
    response, _ = sim.run(sim.arm, trajectory(['elbow_joint'], [(0.5, [0.2])]))
    assert response.status == GoalStatus.STATUS_SUCCEEDED


def slow_goal(target: float = 1.5, seconds: float = 4.0) -> FollowJointTrajectory.Goal:
    return trajectory(['shoulder_pan_joint'], [(seconds, [target])])


def wait_moving(sim, above: float = 0.2) -> None:
    wait_for(lambda: sim.positions()['shoulder_pan_joint'] > above, 30, 'the arm to move')


def test_cancel_holds_the_arm_where_it_is(sim):
    # Slow, in real time: the positions read before and after the cancel lag the simulation
    # by however long this process waits for the CPU; at 0.25 rad/s at most, 0.15 rad of
    # margin is 0.6 s of such lag.
    assert all(result.successful for result in sim.set_parameters(real_time_factor=1.0))
    handle, _ = sim.send_goal(sim.arm, slow_goal(seconds=12.0))
    wait_moving(sim)
    before_cancel = sim.positions()['shoulder_pan_joint']
    cancel = handle.cancel_goal_async()
    wait_for(cancel.done, 30, 'the cancel response')
    after_cancel = sim.positions()['shoulder_pan_joint']
    response = sim.result(handle)
    assert response.status == GoalStatus.STATUS_CANCELED
    held = sim.wait_still()
    # The cancel takes effect somewhere between the request and its answer (a loaded machine
    # stretches that); from there the arm stops within a short braking distance.
    assert before_cancel - 0.15 < held[0] < after_cancel + 0.15
    assert held[0] < 1.0
    sim.assert_holds(held)


@pytest.mark.parametrize('preemptor', ['goal', 'joint_jog', 'joint_command', 'reset'])
def test_preemption(sim, preemptor):
    handle, _ = sim.send_goal(sim.arm, slow_goal())
    wait_moving(sim)
    if preemptor == 'goal':
        second, _ = sim.send_goal(sim.arm, trajectory(['elbow_joint'], [(1.0, [0.3])]))
    elif preemptor == 'joint_jog':
        sim.send(sim.jog, ['wrist_3_joint'], [0.1])
    elif preemptor == 'joint_command':
        sim.send(sim.command, ['wrist_3_joint'], [0.1])
    else:
        assert sim.call('reset').success
    response = sim.result(handle)
    assert response.status == GoalStatus.STATUS_ABORTED
    assert 'preempted by' in response.result.error_string
    assert ('trajectory goal' if preemptor == 'goal' else preemptor) in \
        response.result.error_string
    if preemptor == 'goal':
        assert sim.result(second).status == GoalStatus.STATUS_SUCCEEDED
        # The first goal's joint holds where the second goal found it.
        pan = sim.positions()['shoulder_pan_joint']
        assert 0.2 < pan < 1.4
    held = sim.wait_still()
    if preemptor in ('joint_jog', 'joint_command'):
        assert held[5] == pytest.approx(0.1, abs=math.radians(0.5))
    if preemptor == 'reset':
        assert held == pytest.approx(np.zeros(6), abs=math.radians(0.5))


def gripper_goal(position: float, max_effort: float = 0.0) -> GripperCommand.Goal:
    goal = GripperCommand.Goal()
    goal.command.position = position
    goal.command.max_effort = max_effort
    return goal


def test_gripper_action_openings(sim):
    response, feedback = sim.run(sim.gripper, gripper_goal(0.060, 20.0))
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    result = response.result
    assert result.reached_goal and not result.stalled
    assert result.position == pytest.approx(0.060, abs=0.002)
    assert feedback and feedback[-1][1].position == pytest.approx(0.060, abs=0.005)
    times = [t for t, _ in feedback]
    assert (len(times) - 1) / (times[-1] - times[0]) >= 10.0
    fingers = [name for name in sim.positions() if name.startswith('rg2_')]
    sim.wait_positions(dict.fromkeys(fingers, 0.030), tolerance=1e-3)
    # Beyond the stroke is clamped to it.
    response, _ = sim.run(sim.gripper, gripper_goal(0.2))
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    assert response.result.reached_goal and not response.result.stalled
    assert response.result.position == pytest.approx(0.110, abs=0.002)
    # A malformed goal is refused; the node goes on.
    response, _ = sim.run(sim.gripper, gripper_goal(math.nan))
    assert response.status == GoalStatus.STATUS_ABORTED
    wait_for(lambda: [w for w in sim.warnings() if 'gripper goal refused' in w], 20,
             'the refusal warning')


def test_gripper_action_stalls_on_the_ball(ros_graph):
    start_sim(ros_graph, camera_rate=0.0, real_time_factor=2.0)
    sim = Controllers(ros_graph)
    ball = np.array(sim.get_parameter('ball_position'))
    planner = SimWorld(WorldConfig())
    try:
        above, at = (planner.inverse_kinematics(tcp, GRIPPER_DOWN)
                     for tcp in (ball + [0, 0, 0.15], ball))
    finally:
        planner.close()
    for pose in (above, at):  # through the trajectory action, as a client would
        response, _ = sim.run(sim.arm, trajectory(pose.keys(), [(2.0, list(pose.values()))]))
        assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.error_string
    response, _ = sim.run(sim.gripper, gripper_goal(0.0))
    assert response.status == GoalStatus.STATUS_SUCCEEDED
    result = response.result
    assert result.stalled and not result.reached_goal
    assert result.position == pytest.approx(2 * 0.03, abs=0.005)
    assert result.effort == pytest.approx(40.0, abs=2.0)


def test_across_processes_goals_run_while_joint_states_flow(ros_graph):
    process = run_sim('camera_rate:=0.0', domain_id=ros_graph.domain_id)
    try:
        sim = Controllers(ros_graph)
        sim.latest('joint_states', timeout=60)
        handle, feedback = sim.send_goal(sim.arm, trajectory(
            ['shoulder_pan_joint', 'elbow_joint'], [(1.0, [0.4, -0.3]), (2.5, [0.8, 0.2])]))
        started = stamp_ns(sim.latest('joint_states'))
        # The gripper's goal runs beside the arm's.
        gripper, _ = sim.run(sim.gripper, gripper_goal(0.05))
        assert gripper.status == GoalStatus.STATUS_SUCCEEDED and gripper.result.reached_goal
        response = sim.result(handle)
        assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.error_string
        ended = stamp_ns(sim.latest('joint_states'))
        assert dict(zip(ARM_JOINTS, sim.wait_still()))['elbow_joint'] == pytest.approx(
            0.2, abs=GOAL_TOLERANCE)
        assert len(feedback) >= 10
        # joint_states kept their 100 Hz while both goals ran.
        stamps = [stamp_ns(m) for m in sim.messages('joint_states')
                  if started <= stamp_ns(m) <= ended]
        assert len(stamps) >= 0.99 * (ended - started) / 1e7
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=10)
    assert process.returncode == 0


CLIENT = textwrap.dedent("""
    import sys, rclpy
    from rclpy.action import ActionClient
    from control_msgs.action import FollowJointTrajectory
    from trajectory_msgs.msg import JointTrajectoryPoint
    from builtin_interfaces.msg import Duration
    rclpy.init()
    node = rclpy.create_node('doomed_client')
    client = ActionClient(node, FollowJointTrajectory, sys.argv[1])
    client.wait_for_server()
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ['shoulder_pan_joint']
    goal.trajectory.points = [JointTrajectoryPoint(positions=[1.0],
                                                   time_from_start=Duration(sec=3))]
    future = client.send_goal_async(goal)
    rclpy.spin_until_future_complete(node, future)
    print('sent', flush=True)
    rclpy.spin(node)
""")


def test_a_client_that_disappears_leaves_the_arm_holding_still(sim, ros_graph):
    client = subprocess.Popen([sys.executable, '-c', CLIENT, TRAJECTORY_ACTION],
                              stdout=subprocess.PIPE, env=ros_graph.env)
    try:
        assert select.select([client.stdout], [], [], 60)[0], 'the client sent no goal'
        assert client.stdout.readline().strip() == b'sent'
        wait_moving(sim, above=0.1)
        client.kill()
        client.wait(10)
        held = sim.wait_still()
        assert held[0] == pytest.approx(1.0, abs=GOAL_TOLERANCE)
        sim.assert_holds(held)
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()

