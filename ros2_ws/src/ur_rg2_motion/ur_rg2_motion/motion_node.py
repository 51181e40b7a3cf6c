"""ROS 2 node ``ur_rg2_motion``: TCP moves and the vision-guided ball pick.

``tool_command`` and ``tool_jog`` become trajectories for the sim's
``joint_trajectory_controller/follow_joint_trajectory`` (closed-form inverse kinematics,
ur_rg2_motion.kinematics); ``pick_ball`` runs the pick on an executor thread, driving the arm
through that action and the RG2 through ``gripper_controller/gripper_cmd``. The robot comes
from ``robot_description``, the frames from ``/tf_static`` and ``/tf``.
"""

from collections.abc import Callable
import math
import sys
import threading
import time

from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory, GripperCommand
from geometry_msgs.msg import PointStamped, PoseStamped, TransformStamped
import numpy as np
from rclpy.action import ActionClient
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import (
    ARM_JOINTS,
    GRIPPER_ACTION,
    LATCHED_QOS,
    RG2_MAX_OPENING,
    TF_QOS,
    TRAJECTORY_ACTION,
    WORLD_FRAME,
)
from ur_rg2_common.parameters import ParameterSpec, declare_parameters
from ur_rg2_common.spin import run_node
from ur_rg2_common.tf_buffer import (
    FrameLookupError,
    TransformBuffer,
    pose_matrix,
)

from ur_rg2_motion.kinematics import (
    BASE_LINK,
    FLOOR_CLEARANCE,
    PEDESTAL_HALF_WIDTH,
    ArmKinematics,
    KinematicsError,
    arm_on_pedestal,
    urdf_velocity_limits,
)
from ur_rg2_motion.messages import ball_in_base_link, trajectory_goal
from ur_rg2_motion.planning import (
    Trajectory,
    grasp_check,
    plan_joint_move,
    plan_move,
    plan_pick,
)

NODE_NAME = 'ur_rg2_motion'
RG2_MAX_EFFORT = 40.0  # N
# A quaternion this close to unit length is a client's rounding: normalised without a word.
QUATERNION_NORM_TOLERANCE = 1e-3
# How long the pick waits for an action server to answer a goal, and beyond its duration.
_GOAL_ANSWER_TIMEOUT = 15.0  # s (a loaded machine: one pick in 100 of the bench waited over 5 s)
_GRIPPER_TIMEOUT = 10.0  # s
_MOTION_SLACK = 10.0  # s
# The shortest TCP move, so a tiny jog is still a smooth start and stop.
_MIN_MOVE_DURATION = 0.2  # s
# The pick starts once no arm joint moves faster than this (rad/s), waiting at most so long.
_REST_SPEED = 0.02
_REST_TIMEOUT = 10.0  # s
_STAYED_TOLERANCE = 0.02  # rad: the arm held at the ball sags less than this as it grips
# How often a pick waiting on a controller looks whether the vision node is still there, s.
_VISION_CHECK_PERIOD = 0.05
# The pick's straight moves must not take more than this share of the joint speed limits.
_PICK_SPEED_SCALE = 0.7

_PARAMETERS = (
    ParameterSpec('lift_height', 0.15, 'How high pick_ball lifts the ball, m', bounds=(0.0, 0.5)),
    ParameterSpec('approach_height', 0.10, 'pick_ball comes down onto the ball from this high '
                  'above the grasp, m', bounds=(0.02, 0.4)),
    ParameterSpec('speed_scale', 0.7, "Fraction of the joints' velocity limits that TCP moves "
                  'and the pick use at most', bounds=(0.05, 1.0)),
    ParameterSpec('tcp_speed', 0.25, 'Peak TCP speed of a straight tool_command or tool_jog '
                  'move, m/s', bounds=(0.01, 1.0)),
    ParameterSpec('approach_speed', 0.25, "Peak TCP speed of the pick's descent and lift, m/s",
                  bounds=(0.01, 0.5)),
    ParameterSpec('ball_timeout', 1.0, 'pick_ball uses a ball/position received at most this '
                  'long ago, s', bounds=(0.05, 60.0)),
    ParameterSpec('floor_clearance', FLOOR_CLEARANCE, 'Height above the floor that the TCP, '
                  'finger tips, wrist and elbow keep, m', bounds=(0.0, 0.2)),
    ParameterSpec('pedestal_half_width', PEDESTAL_HALF_WIDTH, 'Half the width of the pedestal '
                  'under base_link (floor to base_link), kept out of, m; 0: none',
                  bounds=(0.0, 1.0)),
    ParameterSpec('grasp_tolerance', 0.02, "A gripper stopped within this of the ball's "
                  'diameter holds the ball, m', bounds=(0.001, 0.05)),
)


class PickCancelledError(Exception):
    """The pick was cancelled by another arm command."""


class PickError(Exception):
    """The pick cannot go on; str() says why."""


class MotionNode(Node):
    """TCP moves through the trajectory controller, and the ball pick."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        declare_parameters(self, _PARAMETERS)
        # pick_ball waits for the controllers: run it on a worker thread (BlockingGroupExecutor)
        # while everything else, quick, stays on the spinning thread.
        self.blocking_group = ReentrantCallbackGroup()
        self._tf = TransformBuffer()
        self._lock = threading.Lock()
        self._urdf: str | None = None
        self._arm: ArmKinematics | None = None
        self._arm_key: tuple | None = None
        self._velocity_limits: np.ndarray | None = None
        self._joints: np.ndarray | None = None
        self._speed = 0.0  # the fastest arm joint's speed, rad/s
        self._opening: float | None = None
        self._ball: tuple[float, PointStamped] | None = None  # (monotonic receipt, message)
        self._tool_target: np.ndarray | None = None  # the running tool move's target
        # Held from the cancel check to the goal's sending, so that a pick never sends a
        # move after a tool command (which cancels it) has sent its own.
        self._send_lock = threading.Lock()
        self._pick_running = False
        self._pick_cancel: str | None = None
        # Whether the running pick still goes by vision's reading of the ball (until it grips).
        self._pick_needs_vision = False

        self.create_subscription(String, 'robot_description', self._on_description, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf_static', self._tf.add_message, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf', self._tf.add_message, TF_QOS)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                 qos_profile_sensor_data)
        self.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)
        self.create_subscription(PoseStamped, 'tool_command', self._on_tool_command, 10)
        self.create_subscription(TransformStamped, 'tool_jog', self._on_tool_jog, 100)
        # Joint moves by others end a pick (the sim preempts the pick's trajectory as well).
        for topic in ('joint_jog', 'joint_command'):
            self.create_subscription(JointState, topic, self._on_joint_move(topic), 100)
        self._trajectory = ActionClient(self, FollowJointTrajectory, TRAJECTORY_ACTION)
        self._gripper = ActionClient(self, GripperCommand, GRIPPER_ACTION)
        self._result_pub = self.create_publisher(String, 'pick_ball/result', LATCHED_QOS)
        self.create_service(Trigger, 'pick_ball', self._on_pick,
                            callback_group=self.blocking_group)

    # -- state from the graph -------------------------------------------------------------------

    def _on_description(self, message: String) -> None:
        try:
            model = ArmKinematics.from_urdf(message.data).model
        except (KinematicsError, ValueError) as error:
            self.get_logger().error(f'robot_description unusable: {error}')
            return
        with self._lock:
            first = self._urdf is None
            self._urdf = message.data
            self._arm = None  # rebuilt on the next command, with the floor of the tree
        if first:
            self.get_logger().info(f'ready: {model.upper()} kinematics from robot_description; '
                                   'tool_command, tool_jog and pick_ball served')

    def _on_joint_states(self, message: JointState) -> None:
        positions = dict(zip(message.name, message.position))
        try:
            joints = np.array([positions[name] for name in ARM_JOINTS])
        except KeyError:
            return
        fingers = [value for name, value in positions.items() if name.startswith('rg2_')]
        speeds = dict(zip(message.name, message.velocity))
        speed = max((abs(speeds.get(name, 0.0)) for name in ARM_JOINTS), default=0.0)
        with self._lock:
            self._joints = joints
            self._speed = speed
            self._opening = sum(fingers) if fingers else None

    def _on_ball(self, message: PointStamped) -> None:
        with self._lock:
            self._ball = (time.monotonic(), message)

    def _on_joint_move(self, topic: str) -> Callable[[JointState], None]:
        def cancel(_message: JointState) -> None:
            self._cancel_pick(topic)
        return cancel

    def _kinematics(self) -> ArmKinematics:
        """Return the arm model with the floor and pedestal as the tree has them now."""
        with self._lock:
            urdf = self._urdf
        if urdf is None:
            raise KinematicsError('invalid', 'no robot_description received yet')
        try:
            base = self._tf.lookup(WORLD_FRAME, BASE_LINK)
        except FrameLookupError:
            base = None  # no world frame: no floor known
        height = float(base[2, 3]) if base is not None else math.inf
        half = self.get_parameter('pedestal_half_width').value
        clearance = self.get_parameter('floor_clearance').value
        key = (id(urdf), height, half, clearance)
        with self._lock:
            if self._arm is not None and self._arm_key == key:
                return self._arm
        arm = arm_on_pedestal(urdf, height, half, clearance)
        limits = urdf_velocity_limits(urdf)
        with self._lock:
            self._arm, self._arm_key, self._velocity_limits = arm, key, limits
        return arm

    def _current_joints(self) -> np.ndarray:
        with self._lock:
            joints = self._joints
        if joints is None:
            raise KinematicsError('invalid', 'no joint_states received yet')
        return joints

    # -- tool_command and tool_jog --------------------------------------------------------------

    def _on_tool_command(self, message: PoseStamped) -> None:
        try:
            target = self._in_base_link(message.header.frame_id, _pose_of(message.pose))
        except (ValueError, FrameLookupError) as error:
            self.get_logger().warning(f'tool_command rejected: {error}')
            return
        self._move_tool(target, 'tool_command')

    def _on_tool_jog(self, message: TransformStamped) -> None:
        t, r = message.transform.translation, message.transform.rotation
        try:
            step = pose_matrix(_finite('translation', (t.x, t.y, t.z)),
                               _unit_quaternion((r.x, r.y, r.z, r.w)))
            frame = self._tf.lookup(BASE_LINK, message.header.frame_id or BASE_LINK)
        except (ValueError, FrameLookupError) as error:
            self.get_logger().warning(f'tool_jog rejected: {error}')
            return
        with self._lock:
            start = self._tool_target
        try:
            if start is None:
                start = self._kinematics().tcp_pose(self._current_joints())
        except KinematicsError as error:
            self.get_logger().warning(f'tool_jog rejected: {error}')
            return
        # Translation along the frame's axes; rotation about the TCP, about the frame's axes.
        axes = frame[:3, :3]
        target = start.copy()
        target[:3, 3] = start[:3, 3] + axes @ step[:3, 3]
        target[:3, :3] = axes @ step[:3, :3] @ axes.T @ start[:3, :3]
        self._move_tool(target, 'tool_jog')

    def _in_base_link(self, frame: str, pose: np.ndarray) -> np.ndarray:
        return self._tf.lookup(BASE_LINK, frame or BASE_LINK) @ pose

    def _move_tool(self, target: np.ndarray, source: str) -> None:
        """Plan the TCP move to ``target`` (base_link) and send it; warn when refused."""
        try:
            arm = self._kinematics()
            trajectory = plan_move(arm, self._current_joints(), target, self._velocity_limits,
                                   self.get_parameter('speed_scale').value, _MIN_MOVE_DURATION)
            trajectory = _limit_tcp_speed(trajectory, arm, self._current_joints(),
                                          self.get_parameter('tcp_speed').value)
        except KinematicsError as error:
            self.get_logger().warning(f'{source} rejected: {error}')
            return
        if not self._trajectory.server_is_ready():
            self.get_logger().warning(f'{source} not executed: {TRAJECTORY_ACTION} is not '
                                      'available (is the sim running?)')
            return
        with self._send_lock:
            self._cancel_pick(source)
            with self._lock:
                self._tool_target = target
            future = self._trajectory.send_goal_async(
                trajectory_goal(trajectory.times, trajectory.positions))
        future.add_done_callback(lambda done: self._on_tool_goal(done, target, source))

    def _on_tool_goal(self, future, target: np.ndarray, source: str) -> None:
        handle = future.result()
        if not handle.accepted:
            self.get_logger().warning(f'{source}: the trajectory controller refused the move')
            self._end_tool_move(target)
            return
        handle.get_result_async().add_done_callback(
            lambda done: self._on_tool_result(done, target, source))

    def _on_tool_result(self, future, target: np.ndarray, source: str) -> None:
        response = future.result()
        with self._lock:
            replaced = self._tool_target is not target  # by a newer move: no news
        if not replaced and response.status != GoalStatus.STATUS_SUCCEEDED:
            self.get_logger().warning(
                f'{source}: the move ended early: {response.result.error_string}')
        self._end_tool_move(target)

    def _end_tool_move(self, target: np.ndarray) -> None:
        with self._lock:
            if self._tool_target is target:
                self._tool_target = None

    # -- pick_ball ------------------------------------------------------------------------------

    def _cancel_pick(self, source: str) -> None:
        with self._lock:
            if self._pick_running and self._pick_cancel is None:
                self._pick_cancel = source

    def _on_pick(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            busy = self._pick_running
            if not busy:
                self._pick_running, self._pick_cancel = True, None
                self._tool_target = None
        if busy:
            response.success = False
            response.message = 'refused: a pick is already running'
            self.get_logger().warning(f'pick_ball {response.message}')
            return response
        started = time.monotonic()
        ball = None
        try:
            ball = self._ball_in_base_link()
            opening = self._pick(ball)
            response.success = True
            response.message = (
                f'picked the ball at {_xyz(ball)} m in {BASE_LINK} in '
                f'{time.monotonic() - started:.1f} s (held at {opening * 1000:.0f} mm)')
            self.get_logger().info(f'pick_ball: {response.message}')
        except (PickError, PickCancelledError, KinematicsError) as error:
            where = f'ball at {_xyz(ball)} m in {BASE_LINK}: ' if ball is not None else ''
            response.success = False
            response.message = f'{where}{error} (after {time.monotonic() - started:.1f} s)'
            self.get_logger().warning(f'pick_ball failed: {response.message}')
        finally:
            self._pick_needs_vision = False
            with self._lock:
                self._pick_running = False
        self._result_pub.publish(String(
            data=f"{'success' if response.success else 'failed'}: {response.message}"))
        return response

    def _ball_in_base_link(self) -> np.ndarray:
        with self._lock:
            ball = self._ball
        try:
            return ball_in_base_link(self._tf, ball, self.get_parameter('ball_timeout').value)
        except ValueError as error:
            raise PickError(str(error)) from None

    def _pick(self, ball: np.ndarray) -> float:
        """Pick the ball at ``ball`` (base_link); return the opening it is held at."""
        self._pick_needs_vision = True
        arm = self._kinematics()
        self._wait_for_rest()
        joints = self._current_joints()
        try:
            plan = plan_pick(arm, joints, ball, self.get_parameter('approach_height').value,
                             self.get_parameter('lift_height').value)
        except KinematicsError as error:
            raise PickError(f'out of reach: {error}') from None
        for client, name in ((self._trajectory, TRAJECTORY_ACTION),
                             (self._gripper, GRIPPER_ACTION)):
            if not client.server_is_ready():
                raise PickError(f'{name} is not available (is the sim running?)')
        scale = self.get_parameter('speed_scale').value
        approach = self.get_parameter('approach_speed').value
        # Opening while the arm swings over: the fingers are clear of the ball above it.
        opening = self._start_gripper(RG2_MAX_OPENING)
        self._run_trajectory(plan_joint_move(joints, plan.joints_above, self._velocity_limits,
                                             scale, _MIN_MOVE_DURATION), 'moving above the ball')
        self._finish_gripper(opening, 'opening the gripper')
        self._straight(arm, plan.grasp, approach, min(scale, _PICK_SPEED_SCALE),
                       'descending to the ball')
        at_ball = self._current_joints()
        closing = self._start_gripper(0.0)
        result = self._finish_gripper(closing, 'closing the gripper')
        self._pick_needs_vision = False  # the ball is in the hand or missed: no reading counts
        self._check_arm_stayed(at_ball, 'closing the gripper')
        missed = grasp_check(result.position, result.stalled, plan.radius,
                             self.get_parameter('grasp_tolerance').value)
        if missed:
            raise PickError(missed)
        self._straight(arm, plan.lift, approach, min(scale, _PICK_SPEED_SCALE),
                       'lifting the ball')
        with self._lock:
            held = self._opening
        # Slipped out during the lift, the fingers would have closed on after it.
        if held is None or abs(held - result.position) > 0.005:
            raise PickError(f'dropped: the gripper is at {1000 * (held or 0):.1f} mm after the '
                             f'lift, {1000 * result.position:.1f} mm when it closed')
        return held

    def _wait_for_rest(self) -> None:
        """Wait for the arm to stop (a reset or jog under way): moves are planned from rest."""
        deadline = time.monotonic() + _REST_TIMEOUT
        while True:
            self._check_cancel()
            self._check_vision()
            with self._lock:
                speed = self._speed
            if speed < _REST_SPEED:
                return
            if time.monotonic() > deadline:
                raise PickError(f'the arm did not come to rest within {_REST_TIMEOUT:g} s')
            time.sleep(0.02)

    def _check_arm_stayed(self, joints: np.ndarray, what: str) -> None:
        """Give up when the arm left ``joints`` during a gripper step: something else drives it.

        The sim's ``reset`` service is such a command that this node cannot see being sent;
        lifting from where the arm went would override it.
        """
        with self._lock:
            speed = self._speed
        moved = float(np.abs(self._current_joints() - joints).max())
        if moved > _STAYED_TOLERANCE or speed >= _REST_SPEED:
            raise PickCancelledError(
                f'cancelled: the arm was moved by another command while {what} '
                f'({math.degrees(moved):.1f} deg away, a reset?)')

    def _straight(self, arm: ArmKinematics, pose: np.ndarray, speed: float, scale: float,
                  what: str) -> None:
        joints = self._current_joints()
        trajectory = _limit_tcp_speed(
            plan_move(arm, joints, pose, self._velocity_limits, scale, _MIN_MOVE_DURATION),
            arm, joints, speed)
        self._run_trajectory(trajectory, what)

    def _check_vision(self) -> None:
        """Give up the pick when nothing publishes ``ball/position`` any more: vision is gone.

        The pick goes where vision last saw the ball; without vision it would go on blind, and
        the user would not learn that the graph has lost its eyes. A vision node that exits
        leaves the graph at once; one killed outright (SIGKILL) only when DDS's lease runs out.
        """
        if self._pick_needs_vision and self.count_publishers('ball/position') == 0:
            raise PickError('vision lost: nothing publishes ball/position any more (is the '
                            'vision node running?); the pick stopped and the arm holds')

    def _check_cancel(self) -> None:
        with self._lock:
            source = self._pick_cancel
        if source is not None:
            raise PickCancelledError(f'cancelled by a new arm command ({source})')

    def _run_trajectory(self, trajectory: Trajectory, what: str) -> None:
        with self._send_lock:
            self._check_cancel()
            future = self._trajectory.send_goal_async(
                trajectory_goal(trajectory.times, trajectory.positions))
        handle = self._wait(future, _GOAL_ANSWER_TIMEOUT, what)
        if not handle.accepted:
            raise PickError(f'{what}: the trajectory controller refused the move')
        # Simulation time may run slower than the wall clock (a loaded machine).
        response = self._wait(handle.get_result_async(),
                              3 * trajectory.duration + _MOTION_SLACK, what, handle)
        self._check_cancel()
        if response.status != GoalStatus.STATUS_SUCCEEDED:
            raise PickError(f'{what}: the move ended early: {response.result.error_string}')

    def _start_gripper(self, position: float):
        goal = GripperCommand.Goal()
        goal.command.position = position
        goal.command.max_effort = RG2_MAX_EFFORT
        with self._send_lock:
            self._check_cancel()
            return self._gripper.send_goal_async(goal)

    def _finish_gripper(self, future, what: str) -> GripperCommand.Result:
        handle = self._wait(future, _GOAL_ANSWER_TIMEOUT, what)
        if not handle.accepted:
            raise PickError(f'{what}: the gripper controller refused the goal')
        response = self._wait(handle.get_result_async(), _GRIPPER_TIMEOUT, what, handle)
        self._check_cancel()
        if response.status != GoalStatus.STATUS_SUCCEEDED:
            raise PickError(f'{what}: the gripper goal ended early')
        return response.result

    def _wait(self, future, timeout: float, what: str, handle=None):
        """Wait for an action future (completed by other executor threads); return its result.

        Given up (its goal cancelled: the arm or the RG2 holds) after ``timeout`` s or when
        vision is lost meanwhile. ``handle``: the goal's, when ``future`` is its result.
        """
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + timeout
        while not done.wait(max(0.0, min(_VISION_CHECK_PERIOD, deadline - time.monotonic()))):
            try:
                if time.monotonic() >= deadline:
                    raise PickError(f'{what}: no answer from the controller within '
                                    f'{timeout:.0f} s')
                self._check_vision()
            except PickError:
                _cancel_goal(future, handle)
                raise
        return future.result()


def _cancel_goal(future, handle) -> None:
    """Cancel the goal of ``handle``, or else the goal ``future`` answers once it is accepted."""
    if handle is not None:
        handle.cancel_goal_async()
        return

    def cancel(answered) -> None:
        if answered.result().accepted:
            answered.result().cancel_goal_async()
    future.add_done_callback(cancel)


# -- messages ------------------------------------------------------------------------------------

def _finite(what: str, values) -> tuple[float, ...]:
    values = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f'{what} {values} is not finite')
    return values


def _unit_quaternion(values) -> tuple[float, ...]:
    """Return the quaternion normalised when its length is 1 within rounding, else raise."""
    values = _finite('orientation', values)
    norm = math.sqrt(sum(v * v for v in values))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise ValueError(f'orientation quaternion {values} has length {norm:.4f}, not 1 '
                         f'(within {QUATERNION_NORM_TOLERANCE:g}): not normalised, rejected')
    return tuple(v / norm for v in values)


def _pose_of(pose) -> np.ndarray:
    p, q = pose.position, pose.orientation
    return pose_matrix(_finite('position', (p.x, p.y, p.z)),
                       _unit_quaternion((q.x, q.y, q.z, q.w)))


def _xyz(point) -> str:
    return '({:.3f}, {:.3f}, {:.3f})'.format(*point)


def _limit_tcp_speed(trajectory: Trajectory, arm: ArmKinematics, start: np.ndarray,
                     speed: float) -> Trajectory:
    """Return the trajectory slowed so that a straight move's TCP peaks at ``speed`` m/s."""
    if not trajectory.straight:
        return trajectory
    distance = np.linalg.norm(arm.tcp_pose(trajectory.positions[-1])[:3, 3]
                              - arm.tcp_pose(start)[:3, 3])
    # A minimum-jerk profile peaks at 1.875 times its mean speed.
    needed = 1.875 * distance / speed
    if needed <= trajectory.duration:
        return trajectory
    return Trajectory(trajectory.times * (needed / trajectory.duration), trajectory.positions,
                      trajectory.straight)


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM."""
    return run_node(MotionNode, args, NODE_NAME)


if __name__ == '__main__':
    sys.exit(main())
