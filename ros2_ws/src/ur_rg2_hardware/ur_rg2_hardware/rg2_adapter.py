"""ROS 2 node ``ur_rg2_rg2_adapter``: the graph's gripper contract over OnRobot's RG2 driver.

Serves ``gripper_controller/gripper_cmd`` (control_msgs/GripperCommand, INTERFACES.md) and
the ``gripper/open`` / ``gripper/close`` services by sending OnRobot's driver (onrobot-ros2,
started in the namespace ``onrobot`` so that its own ``gripper_controller/gripper_cmd`` does
not clash with ours) a ``control_msgs/ParallelGripperCommand`` on its ``grip_stroke`` joint,
and maps its end to ours (ur_rg2_hardware.gripper_mapping: a grasp is SUCCEEDED + stalled).
Each ``grip_stroke`` the driver publishes is republished on ``joint_states`` as the RG2's two
finger joints (half the opening each), where the motion and policy nodes read the opening.
"""

from concurrent.futures import ThreadPoolExecutor
import sys
import threading
import time

from action_msgs.msg import GoalStatus
from control_msgs.action import GripperCommand, ParallelGripperCommand
from rclpy.action import CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.action_server import WorkerActionServer
from ur_rg2_common.contract import GRIPPER_ACTION, GRIPPER_JOINTS, RG2_MAX_OPENING
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import run_node

from ur_rg2_hardware.gripper_mapping import GripGoal, GripOutcome, grip_goal, outcome
from ur_rg2_hardware.settings import PARAMETERS, AdapterSettings

NODE_NAME = 'ur_rg2_rg2_adapter'
FEEDBACK_PERIOD = 0.05  # s: our feedback at 20 Hz while a goal runs
_ANSWER_TIMEOUT = 5.0  # s for the driver to accept or refuse a goal


class GripError(Exception):
    """A goal to the driver failed before it ended; str() says why."""


class Rg2Adapter(Node):
    """GripperCommand on our side, ParallelGripperCommand on OnRobot's."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = AdapterSettings.from_values(declare_parameters(self, PARAMETERS))
        follow_settings(self, PARAMETERS, AdapterSettings.from_values,
                        lambda settings: setattr(self, 'settings', settings))
        self._joint = s.stroke_joint
        self._driver_name = s.onrobot_action
        # The services wait for the driver: run them on worker threads (BlockingGroupExecutor).
        self.blocking_group = ReentrantCallbackGroup()
        self._lock = threading.Lock()
        self._stroke: float | None = None
        self._driver = ThreadSafeActionClient(self, ParallelGripperCommand, s.onrobot_action)
        self._states = self.create_publisher(JointState, 'joint_states', 10)
        self.create_subscription(JointState, s.onrobot_joint_states, self._on_state, 10)
        self._workers = ThreadPoolExecutor(2, thread_name_prefix='rg2')
        self._server = WorkerActionServer(
            self, GripperCommand, GRIPPER_ACTION, self._execute, workers=self._workers,
            cancel_callback=lambda _handle: CancelResponse.ACCEPT)
        for name, target in (('gripper/open', RG2_MAX_OPENING), ('gripper/close', 0.0)):
            self.create_service(Trigger, name,
                                lambda request, response, t=target: self._on_service(t, response),
                                callback_group=self.blocking_group)
        self.get_logger().info(f'serving {GRIPPER_ACTION} over {s.onrobot_action} ({self._joint})')

    def _on_state(self, message: JointState) -> None:
        if self._joint not in message.name:
            return
        stroke = message.position[message.name.index(self._joint)]
        with self._lock:
            self._stroke = stroke
        state = JointState(name=list(GRIPPER_JOINTS), position=[stroke / 2, stroke / 2])
        state.header = message.header
        self._states.publish(state)

    def stroke(self) -> float | None:
        """Return the latest opening the driver published (m), None before the first."""
        with self._lock:
            return self._stroke

    def _execute(self, handle) -> GripperCommand.Result:
        command = handle.request.command
        result = GripperCommand.Result()
        try:
            goal = grip_goal(command.position, command.max_effort)
            end = self._grip(goal, handle)
        except (ValueError, GripError) as error:
            self.get_logger().warning(f'{GRIPPER_ACTION}: {error}')
            result.position = self.stroke() or 0.0
            handle.abort()
            return result
        if end is None:
            handle.canceled()
            return result
        result.position, result.effort = end.position, end.effort
        result.stalled, result.reached_goal = end.stalled, end.reached_goal
        if end.succeeded:
            handle.succeed()
        else:
            self.get_logger().warning(
                f'{GRIPPER_ACTION}: the RG2 stopped at {end.position * 1000:.1f} mm, short of '
                f'{goal.position * 1000:.1f} mm, and its driver reported no stall')
            handle.abort()
        return result

    def _on_service(self, target: float, response: Trigger.Response) -> Trigger.Response:
        try:
            end = self._grip(grip_goal(target, 0.0))
        except GripError as error:
            response.success, response.message = False, str(error)
            return response
        response.success = end.succeeded
        response.message = (f"{'grasped an object' if end.stalled else 'nothing grasped'}, "
                            f'opening {end.position * 1000:.1f} mm')
        return response

    def _grip(self, goal: GripGoal, ours=None) -> GripOutcome | None:
        """Send ``goal`` to the driver and wait for its end; None when ``ours`` was cancelled.

        ``ours``: our goal's handle, for its feedback and its cancel.
        """
        if not self._driver.wait_for_server(timeout_sec=1.0):
            raise GripError(f"OnRobot's {self._driver_name} is not available (is its driver "
                            'running, in the namespace onrobot?)')
        request = ParallelGripperCommand.Goal()
        request.command.name = [self._joint]
        request.command.position = [goal.position]
        request.command.effort = [goal.effort]
        start = self.stroke()
        sent = self._wait(self._driver.send_goal_async(request), _ANSWER_TIMEOUT)
        if sent is None or not sent.accepted:
            raise GripError('the RG2 driver refused the goal' if sent is not None
                            else 'no answer from the RG2 driver')
        ended = sent.get_result_async()
        deadline = time.monotonic() + self.settings.goal_timeout
        while not ended.done():
            if ours is not None and ours.is_cancel_requested:
                sent.cancel_goal_async()
                return None
            if time.monotonic() > deadline:
                sent.cancel_goal_async()
                raise GripError('the RG2 driver did not end the goal in time')
            if ours is not None and self.stroke() is not None:
                ours.publish_feedback(GripperCommand.Feedback(position=self.stroke(),
                                                              effort=goal.effort))
            time.sleep(FEEDBACK_PERIOD)
        response = ended.result()
        state = response.result.state
        position = (state.position[state.name.index(self._joint)]
                    if self._joint in state.name else self.stroke())
        return outcome(goal, start, response.status == GoalStatus.STATUS_SUCCEEDED,
                       response.status == GoalStatus.STATUS_ABORTED, response.result.stalled,
                       position)

    @staticmethod
    def _wait(future, timeout: float):
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        return future.result() if future.done() else None


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM."""
    return run_node(Rg2Adapter, args, NODE_NAME)


if __name__ == '__main__':
    sys.exit(main())
