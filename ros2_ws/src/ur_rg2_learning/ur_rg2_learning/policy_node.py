"""ROS 2 node ``ur_rg2_policy``: a trained Reach or Pick policy driving the live graph.

``policy/run`` (std_srvs/Trigger) starts one episode: the arm first goes to the episode's
start pose (the environment's, ur_rg2_learning.envs.START_TCP, in the pick posture; for Pick
the RG2 opens), then the policy acts step by step. Its observation is built as the
environment builds it (ur_rg2_learning.envs.reach_observation / pick_observation): the TCP
from ``joint_states`` (closed-form forward kinematics of ``robot_description``), the RG2's
opening from its finger joints, the ball from the latest ``ball/position`` transformed
through the tree into ``base_link``. Each action moves the TCP target as in the environment
(ur_rg2_learning.envs.move_target); the joints that reach it go to the sim's
``joint_trajectory_controller/follow_joint_trajectory`` as a one-point trajectory due one
control period (0.1 s) later, or later where a joint would be too fast for that
(ur_rg2_learning.envs.step_duration: the controller refuses a goal too fast rather than slow
it down, where the environment's motors only lag), and a change of Pick's gripper sign to
``gripper_controller/gripper_cmd``; the next step starts when the controllers have finished
them: in step with the simulation, as in training, however fast the sim runs and however
loaded the machine is. A step whose arm goal is refused or stops short puts the target back
where the arm is, so that the next step moves on from there. A Reach episode ends when the
TCP is at the ball's top; a Pick episode when the ball is held at its goal (15 cm above where
it lay); both after the environment's episode length at the latest, or earlier when the
camera has lost the ball (Pick: not held and unseen for ``episode.LOST_STEPS`` steps; the arm hides
it for a few steps of every grasp). ``policy/driving`` (std_msgs/Bool, latched) says whether
the policy is driving the arm.
"""

from __future__ import annotations

import sys
import threading
import time

from control_msgs.action import FollowJointTrajectory, GripperCommand
from geometry_msgs.msg import PointStamped
import numpy as np
from rclpy.action import ActionClient
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import (
    ARM_JOINTS,
    GRIPPER_ACTION,
    GRIPPER_JOINTS,
    LATCHED_QOS,
    RG2_MAX_FORCE,
    RG2_MAX_OPENING,
    TF_QOS,
    TRAJECTORY_ACTION,
    WORLD_FRAME,
)
from ur_rg2_common.parameters import ParameterSpec, declare_parameters
from ur_rg2_common.spin import run_node
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer
from ur_rg2_motion.kinematics import (
    BASE_LINK,
    ArmKinematics,
    KinematicsError,
    arm_on_pedestal,
    urdf_velocity_limits,
)
from ur_rg2_motion.messages import ball_in_base_link, trajectory_goal
from ur_rg2_motion.planning import plan_joint_move, plan_pick

from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.actor import SHIPPED, Actor, PolicyError, shipped_policy
from ur_rg2_learning.envs import (
    BALL_RADIUS,
    CONTROL_RATE,
    LIFT_GOAL,
    START_TCP,
    pick_goal,
    start_joints,
    tcp_pose,
)
from ur_rg2_learning.episode import Episode, Outcome
from ur_rg2_learning.scripted import APPROACH_HEIGHT

NODE_NAME = 'ur_rg2_policy'
_START_SPEED_SCALE = 0.4  # share of the joints' velocity limits for the move to the start
_START_TIMEOUT = 30.0  # s for the start move beyond its duration
_STEP_TIMEOUT = 10.0  # s for one step's goal to be answered and done, beyond its duration
# policy/run waits this long (s) for the latched transforms that place the ball and the floor
# in base_link: a node started with the graph may be asked before /tf_static reached it.
_TREE_WAIT = 5.0

_PARAMETERS = (
    ParameterSpec('policy_dir', 'reach', 'The policy to run: a directory written by '
                  "train_policy --out, or a policy shipped with the package: 'reach', "
                  "'pick' or 'pick_cloned' (empty: 'reach')", read_only=True),
    ParameterSpec('ball_radius', BALL_RADIUS, "The ball's radius, m: Reach's goal is its top, "
                  "Pick's success its bottom 10 cm above the floor", bounds=(0.005, 0.2)),
    ParameterSpec('ball_timeout', 1.0, 'policy/run needs a ball/position received at most '
                  'this long ago, s', bounds=(0.05, 60.0)),
)


class PolicyNode(Node):
    """Runs a Reach or Pick policy episode on request, through the controllers' actions."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, _PARAMETERS)
        name = values['policy_dir'] or 'reach'
        directory = shipped_policy(name) if name in SHIPPED else name
        self.actor = Actor.load(directory)
        if self.actor.env_id not in (REACH_ID, PICK_ID):
            raise PolicyError(f'{directory} holds a {self.actor.env_id} policy; the node runs '
                              f'{REACH_ID} and {PICK_ID} policies')
        self._picks = self.actor.env_id == PICK_ID
        self._lock = threading.Lock()
        self._tf = TransformBuffer()
        self._tree_changed = threading.Condition()
        self._arm = None
        self._robot: str | None = None
        self._velocity_limits: np.ndarray | None = None
        self._joints: np.ndarray | None = None
        self._opening: float | None = None
        self._ball: tuple[float, PointStamped] | None = None
        self._episode: Episode | None = None  # the running episode

        self.create_subscription(String, 'robot_description', self._on_description, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf_static', self._on_tf, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf', self._on_tf, TF_QOS)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                 qos_profile_sensor_data)
        self.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)
        self._trajectory = ActionClient(self, FollowJointTrajectory, TRAJECTORY_ACTION)
        self._gripper = ActionClient(self, GripperCommand, GRIPPER_ACTION)
        self._driving = self.create_publisher(Bool, 'policy/driving', LATCHED_QOS)
        self._driving.publish(Bool(data=False))
        # policy/run may wait for the tree (bounded): on a worker thread (run_node's
        # BlockingGroupExecutor), so that the transforms it waits for keep arriving.
        self.blocking_group = ReentrantCallbackGroup()
        self.create_service(Trigger, 'policy/run', self._on_run,
                            callback_group=self.blocking_group)
        self.create_timer(1.0, self._watch)
        self.get_logger().info(f'{self.actor.env_id} policy from {directory}; policy/run '
                               'starts an episode')

    # -- state from the graph -------------------------------------------------------------------

    def _on_tf(self, message: TFMessage) -> None:
        self._tf.add_message(message)
        with self._tree_changed:
            self._tree_changed.notify_all()

    def _wait_for_tree(self) -> None:
        """Wait up to _TREE_WAIT s for the tree to place the ball's frame and the floor."""
        with self._lock:
            ball = self._ball
        frames = {WORLD_FRAME} | ({ball[1].header.frame_id} if ball is not None else set())

        def connected() -> bool:
            try:
                for frame in frames:
                    self._tf.lookup(BASE_LINK, frame)
            except FrameLookupError:
                return False
            return True

        with self._tree_changed:
            self._tree_changed.wait_for(connected, _TREE_WAIT)

    def _on_description(self, message: String) -> None:
        try:
            limits = urdf_velocity_limits(message.data)
        except (KinematicsError, ValueError) as error:
            self.get_logger().error(f'robot_description unusable: {error}')
            return
        with self._lock:
            self._robot, self._velocity_limits = message.data, limits
            self._arm = None  # rebuilt with the pedestal height of the tree

    def _on_joint_states(self, message: JointState) -> None:
        positions = dict(zip(message.name, message.position))
        if all(name in positions for name in ARM_JOINTS):
            joints = np.array([positions[name] for name in ARM_JOINTS])
            if np.isfinite(joints).all():
                with self._lock:
                    self._joints = joints
        if all(name in positions for name in GRIPPER_JOINTS):
            opening = sum(positions[name] for name in GRIPPER_JOINTS)
            if np.isfinite(opening):
                with self._lock:
                    self._opening = opening

    def _on_ball(self, message: PointStamped) -> None:
        with self._lock:
            self._ball = (time.monotonic(), message)

    def _kinematics(self) -> ArmKinematics:
        with self._lock:
            if self._arm is not None:
                return self._arm
        if self._velocity_limits is None:
            raise KinematicsError('invalid', 'no robot_description received yet')
        try:
            height = float(self._tf.lookup(WORLD_FRAME, BASE_LINK)[2, 3])
        except FrameLookupError as error:
            raise KinematicsError('invalid', f'no floor known yet: {error}') from None
        arm = arm_on_pedestal(self._robot, height)
        with self._lock:
            self._arm = arm
        return arm

    def _ball_centre(self) -> np.ndarray:
        """Return the ball's centre in base_link from the latest ball/position (ValueError)."""
        with self._lock:
            ball = self._ball
        return ball_in_base_link(self._tf, ball, self.get_parameter('ball_timeout').value)

    # -- the episode ----------------------------------------------------------------------------

    def _on_run(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = False
        with self._lock:
            busy, joints = self._episode is not None, self._joints
        try:
            if busy:
                raise ValueError('an episode is already running')
            if joints is None:
                raise ValueError('no joint_states received yet (is the sim running?)')
            clients = ((self._trajectory, TRAJECTORY_ACTION), (self._gripper, GRIPPER_ACTION))
            for client, name in clients[:2 if self._picks else 1]:
                if not client.server_is_ready():
                    raise ValueError(f'{name} is not available (is the sim running?)')
            self._wait_for_tree()
            centre = self._ball_centre()
            arm = self._kinematics()
            start = np.array(START_TCP)
            start_q = start_joints(arm, start)
            try:
                if self._picks:
                    plan_pick(arm, start_q, centre, APPROACH_HEIGHT, LIFT_GOAL)
                else:
                    arm.solve(tcp_pose(centre + (0.0, 0.0, self._radius())), start_q)
            except KinematicsError as error:
                raise ValueError(f'the ball is out of reach: {error}') from None
        except (ValueError, KinematicsError) as error:
            response.message = f'refused: {error}'
            self.get_logger().warning(f'policy/run {response.message}')
            return response
        trajectory = plan_joint_move(joints, start_q, self._velocity_limits,
                                     _START_SPEED_SCALE, 1.0 / CONTROL_RATE)
        episode = Episode(self._picks, start, start_q, pick_goal(centre), self._radius(),
                          time.monotonic() + trajectory.duration + _START_TIMEOUT)
        with self._lock:
            self._episode = episode
        self._driving.publish(Bool(data=True))
        self._send(trajectory.times, trajectory.positions).add_done_callback(
            lambda future: self._on_start_goal(future, episode))
        response.success = True
        what = 'ball' if self._picks else 'ball top'
        shown = centre if self._picks else centre + (0.0, 0.0, self._radius())
        response.message = (f'episode started: {what} at ({shown[0]:.3f}, {shown[1]:.3f}, '
                            f'{shown[2]:.3f}) m in {BASE_LINK}')
        self.get_logger().info(f'policy/run: {response.message}')
        return response

    def _radius(self) -> float:
        return self.get_parameter('ball_radius').value

    def _on_start_goal(self, future, episode: Episode) -> None:
        handle = future.result()
        if not handle.accepted:
            self._end(episode, 'the trajectory controller refused the move to the start pose')
            return
        handle.get_result_async().add_done_callback(
            lambda done: self._on_start_reached(done, episode))

    def _on_start_reached(self, future, episode: Episode) -> None:
        if future.result().result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            self._end(episode, 'the move to the start pose ended early: '
                      f'{future.result().result.error_string}')
            return
        if self._picks:  # the environment starts its episodes with the RG2 open
            episode.pending = 1
            self._send_gripper(RG2_MAX_OPENING, episode)
        else:
            self._step(episode)

    def _step(self, episode: Episode) -> None:
        """Observe, act and send one step; the next starts when the controllers are done."""
        with self._lock:
            if self._episode is not episode:
                return
            joints, opening = self._joints, self._opening
        try:
            arm = self._kinematics()
            observation = episode.observe(arm, joints, opening, self._ball_centre)
        except (ValueError, KinematicsError) as error:
            self._end(episode, f'stopped: {error}')
            return
        if isinstance(observation, Outcome):
            self._end(episode, observation.text, reached=observation.reached)
            return
        step = episode.act(self.actor(observation), arm, joints, self._velocity_limits,
                           RG2_MAX_OPENING)
        episode.deadline = time.monotonic() + step.duration + _STEP_TIMEOUT
        episode.pending = 1 + (step.gripper is not None)
        if step.gripper is not None:
            self._send_gripper(step.gripper, episode)
        self._send([step.duration], step.joints[None]).add_done_callback(
            lambda future: self._on_step_goal(future, episode))

    def _on_step_goal(self, future, episode: Episode) -> None:
        handle = future.result()
        if not handle.accepted:  # the arm holds where it is: the next step starts there
            episode.held_back = True
            self._step_done(episode)
            return
        handle.get_result_async().add_done_callback(
            lambda done: self._on_step_result(done, episode))

    def _on_step_result(self, future, episode: Episode) -> None:
        if future.result().result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            episode.held_back = True  # stopped short (a contact, a preempting command)
        self._step_done(episode)

    def _send_gripper(self, position: float, episode: Episode) -> None:
        goal = GripperCommand.Goal()
        goal.command.position = position
        goal.command.max_effort = RG2_MAX_FORCE
        self._gripper.send_goal_async(goal).add_done_callback(
            lambda future: self._on_gripper_goal(future, episode))

    def _on_gripper_goal(self, future, episode: Episode) -> None:
        handle = future.result()
        if not handle.accepted:
            self._end(episode, f'{GRIPPER_ACTION} refused the goal')
            return
        handle.get_result_async().add_done_callback(lambda _: self._step_done(episode))

    def _step_done(self, episode: Episode) -> None:
        """Count one finished goal of the step; the last of them starts the next step."""
        with self._lock:
            episode.pending -= 1
            last = episode.pending == 0
        if last:
            self._step(episode)

    def _watch(self) -> None:
        with self._lock:
            episode = self._episode
        if episode is not None and time.monotonic() > episode.deadline:
            self._end(episode, f'no answer from {TRAJECTORY_ACTION} in time')

    def _send(self, times, positions):
        return self._trajectory.send_goal_async(trajectory_goal(times, positions))

    def _end(self, episode: Episode, outcome: str, reached: bool = False) -> None:
        with self._lock:
            if self._episode is not episode:
                return
            self._episode = None
        self._driving.publish(Bool(data=False))
        seconds = time.monotonic() - episode.started
        # rclpy refuses two severities from one call site: one call each.
        if reached:
            self.get_logger().info(f'policy episode: {outcome} ({seconds:.1f} s)')
        else:
            self.get_logger().warning(f'policy episode: {outcome} ({seconds:.1f} s)')


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM; exit code 1 when the policy cannot be loaded."""
    return run_node(PolicyNode, args, NODE_NAME, startup_errors=(PolicyError,))


if __name__ == '__main__':
    sys.exit(main())
