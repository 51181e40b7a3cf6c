"""ROS 2 node ``ur_rg2_policy``: a trained Reach or Pick policy driving the live graph.

``policy/run`` (std_srvs/Trigger) starts one episode (ur_rg2_learning.episode): the arm goes to
the environment's start pose, then the policy acts step by step on observations built as the
environment builds them, from the robot's state (ur_rg2_motion.robot_state) and the latest
``ball/position``. Each step is a one-point trajectory for
``joint_trajectory_controller/follow_joint_trajectory`` and, for Pick, a gripper goal; the
next step starts when the controllers have finished them, in step with the simulation however
fast it runs. ``policy/driving`` (std_msgs/Bool, latched) says whether the policy drives the arm;
``policy/result`` (std_msgs/String, latched) is each episode's outcome line, as
``pick_ball/result`` is each pick's: ``success: ...`` or ``failed: ...``, then the time taken.
"""

from __future__ import annotations

import math
import sys
import threading
import time

from control_msgs.action import FollowJointTrajectory, GripperCommand
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.contract import (
    GRIPPER_ACTION,
    LATCHED_QOS,
    RG2_MAX_OPENING,
    TRAJECTORY_ACTION,
)
from ur_rg2_common.episode import EpisodeMarkers
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import run_node
from ur_rg2_motion.kinematics import ArmKinematics, KinematicsError
from ur_rg2_motion.messages import FRAME_WAIT_S, gripper_goal, trajectory_goal
from ur_rg2_motion.robot_state import RobotState, subscribe
from ur_rg2_motion.urdf import BASE_LINK

from ur_rg2_learning import PICK_ID, REACH_ID
from ur_rg2_learning.actor import SHIPPED, Actor, PolicyError, shipped_policy
from ur_rg2_learning.episode import Episode, Outcome, start_episode
from ur_rg2_learning.settings import PARAMETERS, PolicySettings

NODE_NAME = 'ur_rg2_policy'
_STEP_TIMEOUT = 10.0  # s for one step's goal to be answered and done, beyond its duration


class PolicyNode(Node):
    """Runs a Reach or Pick policy episode on request, through the controllers' actions."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = PolicySettings.from_values(declare_parameters(self, PARAMETERS))
        follow_settings(self, PARAMETERS, PolicySettings.from_values,
                        lambda settings: setattr(self, 'settings', settings))
        name = self.settings.policy_dir
        directory = shipped_policy(name) if name in SHIPPED else name
        self.actor = Actor.load(directory)
        if self.actor.env_id not in (REACH_ID, PICK_ID):
            raise PolicyError(f'{directory} holds a {self.actor.env_id} policy; the node runs '
                              f'{REACH_ID} and {PICK_ID} policies')
        self._picks = self.actor.env_id == PICK_ID
        self._lock = threading.Lock()
        self.state = RobotState()
        self._episode: Episode | None = None  # the running episode

        subscribe(self, self.state, self._on_description)
        self._trajectory = ThreadSafeActionClient(self, FollowJointTrajectory, TRAJECTORY_ACTION)
        self._gripper = ThreadSafeActionClient(self, GripperCommand, GRIPPER_ACTION)
        self._driving = self.create_publisher(Bool, 'policy/driving', LATCHED_QOS)
        self._driving.publish(Bool(data=False))
        self._result = self.create_publisher(String, 'policy/result', LATCHED_QOS)
        self._episodes = EpisodeMarkers(self)  # each episode on 'episode' too
        # policy/run may wait for the tree (bounded): on a worker thread (run_node's
        # BlockingGroupExecutor), so that the transforms it waits for keep arriving.
        self.blocking_group = ReentrantCallbackGroup()
        self.create_service(Trigger, 'policy/run', self._on_run,
                            callback_group=self.blocking_group)
        self.create_timer(1.0, self._watch)
        self.get_logger().info(f'{self.actor.env_id} policy from {directory}; policy/run '
                               'starts an episode')

    def _on_description(self, message: String) -> None:
        try:
            self.state.set_description(message.data)
        except ValueError as error:  # KinematicsError too
            self.get_logger().error(f'robot_description unusable: {error}')

    def _kinematics(self, wait: float = 0.0) -> ArmKinematics:
        """Return the arm on its pedestal; KinematicsError while the floor is not known."""
        arm = self.state.kinematics(wait=wait)
        if not math.isfinite(arm.floor_z):
            raise KinematicsError('invalid', 'no floor known (no world frame on /tf_static)')
        return arm

    def _ball_centre(self, wait: float = 0.0):
        """Return the ball's centre in base_link from the latest ball/position (ValueError)."""
        return self.state.ball_centre(self.settings.ball_timeout, wait)

    # -- the episode ----------------------------------------------------------------------------

    def _on_run(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = False
        radius = self.settings.ball_radius
        try:
            with self._lock:
                if self._episode is not None:
                    raise ValueError('an episode is already running')
            joints = self.state.joints(wait=FRAME_WAIT_S)
            clients = ((self._trajectory, TRAJECTORY_ACTION), (self._gripper, GRIPPER_ACTION))
            for client, name in clients[:2 if self._picks else 1]:
                if not client.wait_for_server(timeout_sec=FRAME_WAIT_S):
                    raise ValueError(f'{name} is not available (is the sim running?)')
            centre = self._ball_centre(wait=FRAME_WAIT_S)  # bounded waits, as for joints
            episode, trajectory = start_episode(
                self._picks, self._kinematics(wait=FRAME_WAIT_S), joints, centre,
                radius, self.state.velocity_limits)
            with self._lock:  # a second policy/run may have started one meanwhile
                if self._episode is not None:
                    raise ValueError('an episode is already running')
                self._episode = episode
        except ValueError as error:  # KinematicsError too
            response.message = f'refused: {error}'
            self.get_logger().warning(f'policy/run {response.message}')
            return response
        self._driving.publish(Bool(data=True))
        self._episodes.start()
        self._send(trajectory.times, trajectory.positions).add_done_callback(
            lambda future: self._on_start_goal(future, episode))
        response.success = True
        what = 'ball' if self._picks else 'ball top'
        shown = centre if self._picks else centre + (0.0, 0.0, radius)
        response.message = (f'episode started: {what} at ({shown[0]:.3f}, {shown[1]:.3f}, '
                            f'{shown[2]:.3f}) m in {BASE_LINK}')
        self.get_logger().info(f'policy/run: {response.message}')
        return response

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
        try:
            arm, joints = self._kinematics(), self.state.joints()
            observation = episode.observe(arm, joints, self.state.opening(), self._ball_centre)
        except ValueError as error:  # KinematicsError too
            self._end(episode, f'stopped: {error}')
            return
        if isinstance(observation, Outcome):
            self._end(episode, observation.text, reached=observation.reached)
            return
        step = episode.act(self.actor(observation), arm, joints, self.state.velocity_limits,
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
        self._gripper.send_goal_async(gripper_goal(position)).add_done_callback(
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
        seconds = time.monotonic() - episode.started
        # The outcome first: whoever waits for policy/driving to turn false finds it there.
        self._result.publish(String(
            data=f"{'success' if reached else 'failed'}: {outcome} ({seconds:.1f} s)"))
        self._driving.publish(Bool(data=False))
        self._episodes.end(success=reached)
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
