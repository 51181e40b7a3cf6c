"""ROS 2 node ``ur_rg2_motion``: TCP moves and the vision-guided ball pick.

``tool_command`` and ``tool_jog`` become trajectories for
``joint_trajectory_controller/follow_joint_trajectory`` (closed-form inverse kinematics,
ur_rg2_motion.kinematics); ``pick_ball``, an action (ur_rg2_motion.pick_server) and a Trigger
service, runs the pick (ur_rg2_motion.pick, ur_rg2_motion.pick_action) on an executor thread,
driving the arm through that action and the RG2 through
``gripper_controller/gripper_cmd`` (ur_rg2_motion.goals). The robot comes from
``robot_description`` (the sim's, or Universal Robots' own with ``tcp_offset``), the frames
from ``/tf_static`` and ``/tf``, the gripper's opening from its finger joints in any
``joint_states`` message (ur_rg2_motion.robot_state). A tool command that comes before them
waits for them a bounded moment (ur_rg2_motion.waiting).
"""

from collections.abc import Callable
import sys
import threading

from control_msgs.action import FollowJointTrajectory, GripperCommand
from geometry_msgs.msg import PoseStamped, TransformStamped
import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.contract import GRIPPER_ACTION, LATCHED_QOS, TRAJECTORY_ACTION
from ur_rg2_common.episode import EpisodeMarkers
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import run_node
from ur_rg2_common.tf_buffer import FrameLookupError, pose_matrix

from ur_rg2_motion.goals import ControllerArm
from ur_rg2_motion.kinematics import ArmKinematics, KinematicsError
from ur_rg2_motion.messages import FRAME_WAIT_S, finite, pose_of, unit_quaternion
from ur_rg2_motion.pick import MIN_MOVE_DURATION, PickError, Progress, no_progress, run_pick
from ur_rg2_motion.pick_action import REFUSED, PickOutcome, PickRun, attempt
from ur_rg2_motion.pick_server import PickActionServer
from ur_rg2_motion.planning import jog_target, limit_tcp_speed, plan_move
from ur_rg2_motion.robot_state import NotReceivedError, RobotState, subscribe
from ur_rg2_motion.settings import PARAMETERS, MotionSettings
from ur_rg2_motion.urdf import BASE_LINK
from ur_rg2_motion.waiting import WaitingRequests

NODE_NAME = 'ur_rg2_motion'
# The driver's speed slider (ur_robot_driver's speed_scaling_state_broadcaster), percent.
SPEED_SCALING_TOPIC = 'speed_scaling_state_broadcaster/speed_scaling'
RETRY_PERIOD = 0.05  # s between two tries of the tool commands waiting for the graph


class MotionNode(Node):
    """TCP moves through the trajectory controller, and the ball pick."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = MotionSettings.from_values(declare_parameters(self, PARAMETERS))
        follow_settings(self, PARAMETERS, MotionSettings.from_values,
                        lambda settings: setattr(self, 'settings', settings))
        # pick_ball waits for the controllers: run it on a worker thread (BlockingGroupExecutor)
        # while everything else, quick, stays on the spinning thread.
        self.blocking_group = ReentrantCallbackGroup()
        self.state = RobotState(self.settings.tcp_offset)
        self._lock = threading.Lock()
        self._ready = False
        self._speed_scaling: float | None = None
        self._tool_target: np.ndarray | None = None  # the running tool move's target
        # Held from the cancel check to the goal's sending, so that a pick never sends a
        # move after a tool command (which cancels it) has sent its own.
        self._send_lock = threading.Lock()
        self._pick = PickRun()
        # Whether the running pick still goes by vision's reading of the ball (until it grips).
        self._pick_needs_vision = False

        self._waiting = WaitingRequests(FRAME_WAIT_S, (FrameLookupError, NotReceivedError),
                                        self._on_expired)
        self._retry_timer = self.create_timer(RETRY_PERIOD, self._retry, autostart=False)

        subscribe(self, self.state, self._on_description)
        self.create_subscription(Float64, SPEED_SCALING_TOPIC, self._on_speed_scaling, 10)
        self.create_subscription(
            PoseStamped, 'tool_command',
            lambda message: self._submit('tool_command', self._tool_command, message), 10)
        self.create_subscription(
            TransformStamped, 'tool_jog',
            lambda message: self._submit('tool_jog', self._tool_jog, message), 100)
        # Joint moves by others end a pick (the sim preempts the pick's trajectory as well).
        for topic in ('joint_jog', 'joint_command'):
            self.create_subscription(JointState, topic,
                                     lambda _message, t=topic: self._cancel_pick(t), 100)
        self._trajectory = ThreadSafeActionClient(self, FollowJointTrajectory, TRAJECTORY_ACTION)
        self._gripper = ThreadSafeActionClient(self, GripperCommand, GRIPPER_ACTION)
        self._arm_io = ControllerArm(
            self._trajectory, self._gripper, self.state, self._send_lock, self._check_pick,
            self._check_pick, self._vision_done, lambda: self._speed_scaling)
        self._result_pub = self.create_publisher(String, 'pick_ball/result', LATCHED_QOS)
        self._episodes = EpisodeMarkers(self)  # each pick an episode on 'episode'
        self.create_service(Trigger, 'pick_ball', self._on_pick,
                            callback_group=self.blocking_group)
        PickActionServer(self, self._run_pick, self._tcp)

    # -- state from the graph -------------------------------------------------------------------

    def _on_description(self, message: String) -> None:
        try:
            model = self.state.set_description(message.data)
        except (KinematicsError, ValueError) as error:
            hint = (" (set the motion node's tcp_offset, or add the RG2 to the description)"
                    if 'TCP offset' in str(error) else '')
            self.get_logger().error(f'robot_description unusable: {error}{hint}')
            return
        if not self._ready:
            self._ready = True
            self.get_logger().info(f'ready: {model.upper()} kinematics from robot_description; '
                                   'tool_command, tool_jog and pick_ball served')

    def _on_speed_scaling(self, message: Float64) -> None:
        self._speed_scaling = message.data

    def _kinematics(self) -> ArmKinematics:
        """Return the arm model with the floor and pedestal as the tree has them now."""
        return self.state.kinematics(self.settings.pedestal_half_width,
                                     self.settings.floor_clearance)

    # -- tool_command and tool_jog --------------------------------------------------------------

    def _submit(self, source: str, handle, message) -> None:
        """Handle a tool message now, or once what it needs has come (WaitingRequests)."""
        def attempt() -> None:
            try:
                handle(message)
            except (NotReceivedError, FrameLookupError):
                raise  # it waits
            except ValueError as error:  # KinematicsError too: a bad or unreachable target
                self.get_logger().warning(f'{source} rejected: {error}')
        self._waiting.submit(source, attempt)
        if len(self._waiting):
            self._retry_timer.reset()

    def _retry(self) -> None:
        self._waiting.retry()
        if not len(self._waiting):
            self._retry_timer.cancel()

    def _on_expired(self, source: str, error: Exception) -> None:
        self.get_logger().warning(f'{source} rejected: {error} (after waiting '
                                  f'{self._waiting.timeout:g} s for it; send it again)')

    def _tool_command(self, message: PoseStamped) -> None:
        pose = pose_of(message.pose)  # ValueError first: a bad pose is refused at once
        self._move_tool(self.state.tf.lookup(
            BASE_LINK, message.header.frame_id or BASE_LINK) @ pose, 'tool_command')

    def _tool_jog(self, message: TransformStamped) -> None:
        t, r = message.transform.translation, message.transform.rotation
        step = pose_matrix(finite('translation', (t.x, t.y, t.z)),
                           unit_quaternion((r.x, r.y, r.z, r.w)))
        frame = self.state.tf.lookup(BASE_LINK, message.header.frame_id or BASE_LINK)
        with self._lock:
            start = self._tool_target
        if start is None:
            start = self._kinematics().tcp_pose(self.state.joints())
        self._move_tool(jog_target(start, frame, step), 'tool_jog')

    def _move_tool(self, target: np.ndarray, source: str) -> None:
        """Plan the TCP move to ``target`` (base_link) and send it.

        Raises NotReceivedError while the node lacks what it needs, KinematicsError when the
        move is refused.
        """
        arm = self._kinematics()
        joints = self.state.joints()
        if not self._trajectory.server_is_ready():
            raise NotReceivedError(TRAJECTORY_ACTION, f'{TRAJECTORY_ACTION} is not available '
                                   '(is the sim or the driver running?)')
        trajectory = limit_tcp_speed(
            plan_move(arm, joints, target, self.state.velocity_limits,
                      self.settings.speed_scale, MIN_MOVE_DURATION),
            arm, joints, self.settings.tcp_speed)
        with self._send_lock:
            self._cancel_pick(source)
            with self._lock:
                self._tool_target = target
            self._arm_io.send(trajectory, lambda refused, why: self._on_tool_end(
                target, source, refused, why))

    def _on_tool_end(self, target: np.ndarray, source: str, refused: bool,
                     why: str | None) -> None:
        with self._lock:
            replaced = self._tool_target is not target  # by a newer move: no news
            if not replaced:
                self._tool_target = None
        if why is not None and (refused or not replaced):
            self.get_logger().warning(f'{source}: {why}')

    # -- pick_ball: the pick's Arm (ur_rg2_motion.pick) ------------------------------------------

    def _cancel_pick(self, source: str) -> None:
        self._pick.stop(f'cancelled by a new arm command ({source})')

    def _on_pick(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        outcome = self._run_pick()
        response.success, response.message = outcome.success, outcome.message
        return response

    def _run_pick(self, progress: Progress = no_progress,
                  canceled: Callable[[], bool] | None = None) -> PickOutcome:
        """Run one pick unless one runs; log it and publish it on ``pick_ball/result``."""
        if not self._pick.start(canceled):
            self.get_logger().info(f'pick_ball {REFUSED.message}')
            return REFUSED
        with self._lock:
            self._tool_target = None
        try:
            outcome = attempt(self._ball_in_base_link,
                              lambda ball: self._pick_up(ball, progress))
        finally:
            self._pick_needs_vision = False
            self._pick.end()
        if outcome.success:
            self.get_logger().info(f'pick_ball: {outcome.message}')
        else:
            self.get_logger().info(f'pick_ball failed: {outcome.message}')
        self._result_pub.publish(String(
            data=f"{'success' if outcome.success else 'failed'}: {outcome.message}"))
        return outcome

    def _tcp(self) -> np.ndarray | None:
        try:
            return self._kinematics().tcp_pose(self.state.joints())[:3, 3]
        except (NotReceivedError, FrameLookupError):
            return None

    def _ball_in_base_link(self) -> np.ndarray:
        try:
            return self.state.ball_centre(self.settings.ball_timeout, FRAME_WAIT_S)
        except ValueError as error:
            raise PickError(str(error)) from None

    def _pick_up(self, ball: np.ndarray, progress: Progress) -> float:
        self._pick_needs_vision = True
        # On a worker thread: what a pick needs of the graph may be waited for.
        arm = self.state.kinematics(self.settings.pedestal_half_width,
                                    self.settings.floor_clearance, FRAME_WAIT_S)
        self.state.joints(FRAME_WAIT_S)
        for client, name in ((self._trajectory, TRAJECTORY_ACTION),
                             (self._gripper, GRIPPER_ACTION)):
            if not client.wait_for_server(timeout_sec=FRAME_WAIT_S):
                raise PickError(f'{name} is not available (is the sim or the driver running?)')
        with self._episodes.marked():
            return run_pick(self._arm_io, arm, ball, self.settings.pick(), progress)

    def _check_pick(self) -> None:
        """Raise when the running pick was cancelled, or lost vision while it needs it.

        Vision is gone when nothing publishes ``ball/position`` any more; else the pick would
        go on blind to where vision last saw the ball. A vision node that exits leaves the
        graph at once; one killed (SIGKILL) only when DDS's lease runs out.
        """
        self._pick.check()
        if self._pick_needs_vision and self.count_publishers('ball/position') == 0:
            raise PickError('vision lost: nothing publishes ball/position any more (is the '
                            'vision node running?); the pick stopped and the arm holds')

    def _vision_done(self) -> None:
        self._pick_needs_vision = False


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM."""
    return run_node(MotionNode, args, NODE_NAME)


if __name__ == '__main__':
    sys.exit(main())
