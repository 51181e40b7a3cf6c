"""The robot state the motion and policy nodes keep, and requests that wait for it (no node)."""

import math
import threading

from geometry_msgs.msg import PointStamped, TransformStamped
import numpy as np
import pytest
from sensor_msgs.msg import JointState
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_JOINTS
from ur_rg2_common.tf_buffer import FrameLookupError
from ur_rg2_motion.kinematics import KinematicsError
from ur_rg2_motion.robot_state import NotReceivedError, RobotState
from ur_rg2_motion.waiting import WaitingRequests
from ur_rg2_sim.robot_model import write_robot_urdf

PEDESTAL = 0.2  # m, base_link above the floor


@pytest.fixture(scope='module')
def urdf(tmp_path_factory) -> str:
    return write_robot_urdf('ur5', tmp_path_factory.mktemp('ur5')).read_text()


def tf_message(parent: str, child: str, z: float) -> TFMessage:
    stamped = TransformStamped()
    stamped.header.frame_id, stamped.child_frame_id = parent, child
    stamped.transform.translation.z = z
    stamped.transform.rotation.w = 1.0
    return TFMessage(transforms=[stamped])


def joint_state(names, positions, velocities=()) -> JointState:
    return JointState(name=list(names), position=[float(p) for p in positions],
                      velocity=[float(v) for v in velocities])


def test_arm_and_gripper_come_in_any_message_and_values_not_finite_are_left_out():
    state = RobotState()
    with pytest.raises(NotReceivedError, match='no joint_states received yet'):
        state.joints()
    assert state.opening() is None
    state.add_joint_state(joint_state(ARM_JOINTS, range(6), (0.1, -0.3, 0, 0, 0, 0)))
    state.add_joint_state(joint_state(GRIPPER_JOINTS, [0.02] * len(GRIPPER_JOINTS)))
    assert np.allclose(state.joints(), range(6)) and state.speed() == pytest.approx(0.3)
    assert state.opening() == pytest.approx(0.02 * len(GRIPPER_JOINTS))
    state.add_joint_state(joint_state(ARM_JOINTS, [math.nan, 1, 2, 3, 4, 5]))
    state.add_joint_state(joint_state(GRIPPER_JOINTS, [math.inf] * len(GRIPPER_JOINTS)))
    assert np.allclose(state.joints(), range(6))
    assert state.opening() == pytest.approx(0.02 * len(GRIPPER_JOINTS))


def test_the_arm_model_needs_a_description_and_the_static_tree_and_has_its_floor(urdf):
    state = RobotState()
    with pytest.raises(NotReceivedError, match='no robot_description received yet'):
        state.kinematics()
    assert state.set_description(urdf) == 'ur5'
    assert state.velocity_limits.shape == (6,)
    # The arm's links on /tf before the latched world -> base_link: no model without a floor.
    state.tf.add_message(tf_message('base_link', 'shoulder_link', 0.1))
    with pytest.raises(NotReceivedError, match='no /tf_static received yet'):
        state.kinematics()
    state.add_static(tf_message('world', 'base_link', PEDESTAL))
    arm = state.kinematics()
    assert arm.floor_z == pytest.approx(-PEDESTAL)
    assert state.kinematics() is arm  # kept while nothing it is built from changes
    assert state.kinematics(clearance=0.01) is not arm


def test_a_tree_without_the_world_frame_gives_an_arm_without_a_floor(urdf):
    state = RobotState()
    state.set_description(urdf)
    state.add_static(tf_message('base_link', 'base', 0.0))  # a real cell's robot_state_publisher
    assert state.kinematics().floor_z == -math.inf


def test_an_unusable_description_is_refused_and_the_previous_one_stays(urdf):
    state = RobotState()
    state.set_description(urdf)
    with pytest.raises(KinematicsError, match='no TCP offset'):
        state.set_description(urdf.replace('rg2_tcp', 'rg2_point'))
    assert state.urdf == urdf


def test_the_ball_is_placed_in_base_link_while_its_sighting_is_recent():
    state = RobotState()
    with pytest.raises(ValueError, match='no ball seen'):
        state.ball_centre(1.0)
    state.add_static(tf_message('world', 'base_link', PEDESTAL))
    ball = PointStamped()
    ball.header.frame_id = 'world'
    ball.point.x, ball.point.z = 0.4, 0.03
    state.add_ball(ball)
    assert state.ball is ball
    assert np.allclose(state.ball_centre(1.0), (0.4, 0.0, 0.03 - PEDESTAL))


def test_the_first_sighting_is_waited_for_a_bounded_moment_a_stale_one_is_not():
    state = RobotState()
    state.add_static(tf_message('world', 'base_link', PEDESTAL))
    ball = PointStamped()
    ball.header.frame_id = 'world'
    ball.point.x, ball.point.z = 0.4, 0.03
    threading.Timer(0.2, state.add_ball, (ball,)).start()
    assert np.allclose(state.ball_centre(1.0, wait=30.0), (0.4, 0.0, 0.03 - PEDESTAL))
    refusals = []

    def too_old() -> None:  # seen, but too long ago: refused without the wait
        with pytest.raises(ValueError, match='no ball seen in the last 0 s'):
            state.ball_centre(0.0, wait=600.0)
        refusals.append(True)

    asking = threading.Thread(target=too_old, daemon=True)
    asking.start()
    asking.join(timeout=60.0)
    assert refusals and not asking.is_alive()


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_a_request_waits_until_what_it_needs_comes_and_runs_once():
    clock, ready, done, expired = Clock(), [False], [], []

    def attempt(name: str):
        def run() -> None:
            if not ready[0]:
                raise FrameLookupError("unknown frame 'base_link'")
            done.append(name)
        return run

    requests = WaitingRequests(5.0, (FrameLookupError,), lambda *e: expired.append(e),
                               clock=clock)
    requests.submit('tool_command', attempt('first'))
    requests.submit('tool_jog', attempt('second'))
    assert (len(requests), done) == (2, [])
    clock.now = 4.9
    requests.retry()
    assert len(requests) == 2
    ready[0] = True
    requests.retry()
    assert (len(requests), done, expired) == (0, ['first', 'second'], [])
    requests.submit('tool_command', attempt('third'))  # ready: at once
    assert done[-1] == 'third' and len(requests) == 0


def test_a_request_still_waiting_when_its_time_is_up_is_given_up_with_the_reason():
    clock, expired = Clock(), []

    def never() -> None:
        raise NotReceivedError('robot_description')

    requests = WaitingRequests(5.0, (NotReceivedError,), lambda *e: expired.append(e),
                               limit=2, clock=clock)
    requests.submit('tool_command', never)
    clock.now = 5.0
    requests.retry()
    assert len(requests) == 0
    assert [(source, str(error)) for source, error in expired] == [
        ('tool_command', 'no robot_description received yet')]
    for _ in range(3):
        requests.submit('tool_jog', never)
    assert len(requests) == 2 and 'more than 2 requests waiting' in str(expired[-1][1])


def test_a_request_off_the_executor_thread_waits_a_bounded_moment_for_the_joints(urdf):
    state = RobotState()
    with pytest.raises(NotReceivedError, match='no joint_states received yet'):
        state.joints(wait=0.05)
    asked = threading.Event()

    def publish_later() -> None:
        asked.wait(10.0)
        state.add_joint_state(joint_state(ARM_JOINTS, range(6)))
        state.set_description(urdf)
        state.add_static(tf_message('world', 'base_link', PEDESTAL))

    publisher = threading.Thread(target=publish_later)
    publisher.start()
    try:
        asked.set()
        assert np.allclose(state.joints(wait=30.0), range(6))
        assert state.kinematics(wait=30.0).floor_z == pytest.approx(-PEDESTAL)
    finally:
        publisher.join(10.0)
