"""ROS 2 node ``ur_rg2_policy``: a trained Reach policy driving the live graph.

``policy/run`` (std_srvs/Trigger) starts one episode: the arm first goes to the episode's
start pose (the environment's, ur_rg2_learning.envs.START_TCP, in the pick posture), then
the policy acts step by step. Its observation is built as the environment builds it: the TCP
from ``joint_states`` (closed-form forward kinematics of ``robot_description``), the goal
from the latest ``ball/position`` transformed through the tree into ``base_link``. Each action
moves the TCP target as in the environment; the joints that reach it (closed-form inverse
kinematics) go to the sim's ``joint_trajectory_controller/follow_joint_trajectory`` as a
one-point trajectory due one control period (0.1 s) later, and the next step starts when the
controller has finished it: in step with the simulation, as in training, however fast the sim
runs and however loaded the machine is. The episode ends when the TCP is at the ball (the
environment's success) or after the environment's episode length.
``policy/driving`` (std_msgs/Bool, latched) says whether the policy is driving the arm.
"""

from __future__ import annotations

import importlib.resources
import sys
import threading
import time

from control_msgs.action import FollowJointTrajectory
from geometry_msgs.msg import PointStamped
import numpy as np
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage
from ur_rg2_common.contract import ARM_JOINTS, LATCHED_QOS, TF_QOS, TRAJECTORY_ACTION, WORLD_FRAME
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
from ur_rg2_motion.planning import plan_joint_move

from ur_rg2_learning import EPISODE_STEPS, REACH_ID
from ur_rg2_learning.actor import Actor, PolicyError
from ur_rg2_learning.envs import (
    BALL_RADIUS,
    CONTROL_RATE,
    MAX_STEP,
    REACH_TOLERANCE,
    START_TCP,
    start_joints,
    target_bounds,
    tcp_pose,
)

NODE_NAME = 'ur_rg2_policy'
_START_SPEED_SCALE = 0.4  # share of the joints' velocity limits for the move to the start
_START_TIMEOUT = 30.0  # s for the start move beyond its duration
_STEP_TIMEOUT = 10.0  # s for one step's goal to be answered and done

_PARAMETERS = (
    ParameterSpec('policy_dir', '', 'Directory of the trained Reach policy (train_policy '
                  '--out); empty: the policy shipped with the package', read_only=True),
    ParameterSpec('ball_radius', BALL_RADIUS, "The ball's radius, m: the goal is its top",
                  bounds=(0.005, 0.2)),
    ParameterSpec('ball_timeout', 1.0, 'policy/run needs a ball/position received at most '
                  'this long ago, s', bounds=(0.05, 60.0)),
)


def shipped_policy() -> str:
    """Return the directory of the Reach policy that comes with the package."""
    return str(importlib.resources.files('ur_rg2_learning').joinpath('policies', 'reach'))


class PolicyNode(Node):
    """Runs a Reach policy episode on request, through the trajectory controller."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare_parameters(self, _PARAMETERS)
        directory = values['policy_dir'] or shipped_policy()
        self.actor = Actor.load(directory)
        if self.actor.env_id != REACH_ID:
            raise PolicyError(f'{directory} holds a {self.actor.env_id} policy; the node runs '
                              f'{REACH_ID} policies')
        self._lock = threading.Lock()
        self._tf = TransformBuffer()
        self._arm = None
        self._robot: str | None = None
        self._velocity_limits: np.ndarray | None = None
        self._joints: np.ndarray | None = None
        self._ball: tuple[float, PointStamped] | None = None
        self._episode: dict | None = None  # the running episode's state

        self.create_subscription(String, 'robot_description', self._on_description, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf_static', self._tf.add_message, LATCHED_QOS)
        self.create_subscription(TFMessage, '/tf', self._tf.add_message, TF_QOS)
        self.create_subscription(JointState, 'joint_states', self._on_joint_states,
                                 qos_profile_sensor_data)
        self.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)
        self._trajectory = ActionClient(self, FollowJointTrajectory, TRAJECTORY_ACTION)
        self._driving = self.create_publisher(Bool, 'policy/driving', LATCHED_QOS)
        self._driving.publish(Bool(data=False))
        self.create_service(Trigger, 'policy/run', self._on_run)
        self.create_timer(1.0, self._watch)
        self.get_logger().info(f'{REACH_ID} policy from {directory}; policy/run starts an '
                               'episode')

    # -- state from the graph -------------------------------------------------------------------

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

    def _goal(self) -> np.ndarray:
        """Return the ball's top in base_link from the latest ball/position (ValueError)."""
        with self._lock:
            ball = self._ball
        centre = ball_in_base_link(self._tf, ball, self.get_parameter('ball_timeout').value)
        return centre + (0.0, 0.0, self.get_parameter('ball_radius').value)

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
            if not self._trajectory.server_is_ready():
                raise ValueError(f'{TRAJECTORY_ACTION} is not available (is the sim running?)')
            goal = self._goal()
            arm = self._kinematics()
            start = np.array(START_TCP)
            start_q = start_joints(arm, start)
        except (ValueError, KinematicsError) as error:
            response.message = f'refused: {error}'
            self.get_logger().warning(f'policy/run {response.message}')
            return response
        trajectory = plan_joint_move(joints, start_q, self._velocity_limits,
                                     _START_SPEED_SCALE, 1.0 / CONTROL_RATE)
        episode = {'target': start, 'joints': start_q, 'step': 0,
                   'previous': None, 'started': time.monotonic(),
                   'deadline': time.monotonic() + trajectory.duration + _START_TIMEOUT}
        with self._lock:
            self._episode = episode
        self._driving.publish(Bool(data=True))
        self._send(trajectory.times, trajectory.positions).add_done_callback(
            lambda future: self._on_start_goal(future, episode))
        response.success = True
        response.message = (f'episode started: ball top at ({goal[0]:.3f}, {goal[1]:.3f}, '
                            f'{goal[2]:.3f}) m in {BASE_LINK}')
        self.get_logger().info(f'policy/run: {response.message}')
        return response

    def _on_start_goal(self, future, episode: dict) -> None:
        handle = future.result()
        if not handle.accepted:
            self._end(episode, 'the trajectory controller refused the move to the start pose')
            return
        handle.get_result_async().add_done_callback(
            lambda done: self._on_start_reached(done, episode))

    def _on_start_reached(self, future, episode: dict) -> None:
        if future.result().result.error_code != FollowJointTrajectory.Result.SUCCESSFUL:
            self._end(episode, 'the move to the start pose ended early: '
                      f'{future.result().result.error_string}')
            return
        self._step(episode)

    def _step(self, episode: dict) -> None:
        """Observe, act and send one step; the next starts when the controller is done."""
        with self._lock:
            if self._episode is not episode:
                return
            joints = self._joints
        try:
            goal = self._goal()
            arm = self._kinematics()
        except (ValueError, KinematicsError) as error:
            self._end(episode, f'stopped: {error}')
            return
        tcp = arm.tcp_pose(joints)[:3, 3]
        previous = episode['previous']
        velocity = np.zeros(3) if previous is None else (tcp - previous) * CONTROL_RATE
        episode['previous'] = tcp
        distance = float(np.linalg.norm(tcp - goal))
        if distance < REACH_TOLERANCE:
            self._end(episode, f'reached the ball: TCP {distance * 1000:.0f} mm from its top '
                      f'after {episode["step"]} steps', reached=True)
            return
        if episode['step'] >= EPISODE_STEPS[REACH_ID]:
            self._end(episode, f'not reached after {episode["step"]} steps: TCP '
                      f'{distance * 1000:.0f} mm from the ball top')
            return
        action = self.actor({'observation': np.concatenate([tcp, velocity]),
                             'achieved_goal': tcp, 'desired_goal': goal})
        low, high = target_bounds(arm)
        target = np.clip(episode['target'] + MAX_STEP * np.clip(action, -1.0, 1.0), low, high)
        try:
            episode['joints'] = arm.solve(tcp_pose(target), episode['joints'])
            episode['target'] = target
        except KinematicsError:
            pass  # as in the environment: the arm holds its target
        episode['step'] += 1
        episode['deadline'] = time.monotonic() + _STEP_TIMEOUT
        self._send([1.0 / CONTROL_RATE], episode['joints'][None]).add_done_callback(
            lambda future: self._on_step_goal(future, episode))

    def _on_step_goal(self, future, episode: dict) -> None:
        handle = future.result()
        if not handle.accepted:  # refused (too fast for a joint): the arm holds, go on
            self._step(episode)
            return
        handle.get_result_async().add_done_callback(lambda _: self._step(episode))

    def _watch(self) -> None:
        with self._lock:
            episode = self._episode
        if episode is not None and time.monotonic() > episode['deadline']:
            self._end(episode, f'no answer from {TRAJECTORY_ACTION} in time')

    def _send(self, times, positions):
        return self._trajectory.send_goal_async(trajectory_goal(times, positions))

    def _end(self, episode: dict, outcome: str, reached: bool = False) -> None:
        with self._lock:
            if self._episode is not episode:
                return
            self._episode = None
        self._driving.publish(Bool(data=False))
        seconds = time.monotonic() - episode['started']
        log = self.get_logger().info if reached else self.get_logger().warning
        log(f'policy episode: {outcome} ({seconds:.1f} s)')


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM; exit code 1 when the policy cannot be loaded."""
    return run_node(PolicyNode, args, NODE_NAME, startup_errors=(PolicyError,))


if __name__ == '__main__':
    sys.exit(main())
