"""The sim's ros2_control-style controllers: trajectory and gripper action servers.

``joint_trajectory_controller/follow_joint_trajectory`` and ``gripper_controller/gripper_cmd``
behave as ros2_control's controllers of those names (see INTERFACES.md). The motion itself is
sampled on the simulation thread (ur_rg2_sim.drivers); here each goal's execute callback, on a
worker thread, validates it, hands it to the simulation, publishes feedback and answers.
"""

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
import math
import time

from builtin_interfaces.msg import Duration, Time
from control_msgs.action import FollowJointTrajectory, GripperCommand
from rclpy.action import CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from ur_rg2_common.action_server import WorkerActionServer
from ur_rg2_common.contract import ARM_JOINTS, GRIPPER_ACTION, TRAJECTORY_ACTION

from ur_rg2_sim.drivers import ArmDriver, ArmRun, Ended, GripperDriver, GripperRun
from ur_rg2_sim.simulation import NS, SimulationLoop, SimulationUnavailableError, answer
from ur_rg2_sim.trajectory import (
    INVALID_GOAL,
    INVALID_JOINTS,
    PATH_TOLERANCE_VIOLATED,
    Point,
    Tolerance,
    TrajectoryError,
)
from ur_rg2_sim.trajectory import validate as validate_trajectory
from ur_rg2_sim.world import SimWorld

FEEDBACK_PERIOD = 0.05  # s of wall time: 20 Hz, twice the contract's minimum
# How long a worker waits for the simulation thread to take a goal (it takes one step).
_SIM_ANSWER_TIMEOUT = 10.0  # s


class Controllers:
    """The two action servers of ``node``, driving the world of ``sim``."""

    def __init__(self, node: Node, sim: SimulationLoop) -> None:
        self._node = node
        self._sim = sim
        self._logger = node.get_logger()
        self._arm = ArmDriver()
        self._gripper = GripperDriver()
        sim.step_hooks += [self._arm.step, self._gripper.step]
        # Goals of both actions may run side by side, and a preempted one winds down while
        # its successor starts.
        self._workers = ThreadPoolExecutor(4, thread_name_prefix='action')
        self._closed = False
        # Goal id -> how to cancel it on the simulation thread, while it runs.
        self._cancels: dict[bytes, Callable[[], None]] = {}
        common = dict(goal_callback=lambda _: GoalResponse.ACCEPT,
                      cancel_callback=self._on_cancel, workers=self._workers)
        self._servers = [
            WorkerActionServer(node, FollowJointTrajectory, TRAJECTORY_ACTION,
                                self._execute_trajectory, **common),
            WorkerActionServer(node, GripperCommand, GRIPPER_ACTION, self._execute_gripper,
                                **common),
        ]

    def _on_cancel(self, goal_handle: ServerGoalHandle) -> CancelResponse:
        # Held at once, not at the next feedback period: the arm stops where it was asked to.
        cancel = self._cancels.get(bytes(goal_handle.goal_id.uuid))
        if cancel is not None:
            cancel()
        return CancelResponse.ACCEPT

    def arm_commanded(self, source: str) -> None:
        """Preempt a running trajectory: ``source`` commands the arm (simulation thread)."""
        self._arm.preempt(f'preempted by {source}')

    @property
    def arm_running(self) -> bool:
        """Whether a trajectory drives the arm (simulation thread)."""
        return self._arm.active is not None

    def arm_blocked(self, reason: str) -> None:
        """Abort a running trajectory whose path is blocked, the reason logged (sim thread)."""
        self._arm.preempt(reason, PATH_TOLERANCE_VIOLATED, logged=True)

    def close(self) -> None:
        """End running goals and stop taking new ones; call after the simulation stopped."""
        self._closed = True
        self._arm.close('the simulation stopped')
        self._gripper.close('the simulation stopped')
        # The running callbacks see their goals ended within a feedback period.
        self._workers.shutdown(wait=True, cancel_futures=True)
        for server in self._servers:
            server.destroy()

    # -- follow_joint_trajectory -------------------------------------------------------------

    def _execute_trajectory(self, goal_handle: ServerGoalHandle) -> FollowJointTrajectory.Result:
        request = goal_handle.request
        try:
            goal = _trajectory_goal(request)
            stamp = request.trajectory.header.stamp
            start_ns = stamp.sec * NS + stamp.nanosec or None
            run = self._on_sim(lambda world: self._arm.start(
                world, self._sim.sim_time_ns, goal, start_ns))
        except (TrajectoryError, SimulationUnavailableError) as error:
            self._logger.warning(f'follow_joint_trajectory goal refused: {error}')
            goal_handle.abort()
            return FollowJointTrajectory.Result(error_code=getattr(error, 'code', INVALID_GOAL),
                                                error_string=str(error))
        ended = self._follow(goal_handle, run, self._arm.cancel,
                             lambda: self._trajectory_feedback(goal_handle, run))
        self._log_end('follow_joint_trajectory', ended)
        return FollowJointTrajectory.Result(error_code=ended.code, error_string=ended.message)

    def _trajectory_feedback(self, goal_handle: ServerGoalHandle, run: ArmRun) -> None:
        sample = run.sample
        if sample is None:
            return
        desired, actual = sample.desired, sample.actual
        feedback = FollowJointTrajectory.Feedback(joint_names=list(run.execution.goal.joints))
        feedback.header.stamp = _time(sample.time)
        elapsed = _duration(max(sample.time - run.execution.spline.start_time, 0.0))
        for point, positions, velocities in (
                (feedback.desired, desired[0], desired[1]), (feedback.actual, *actual),
                (feedback.error, desired[0] - actual[0], desired[1] - actual[1])):
            point.positions = positions.tolist()
            point.velocities = velocities.tolist()
            point.time_from_start = elapsed
        feedback.desired.accelerations = desired[2].tolist()
        goal_handle.publish_feedback(feedback)

    # -- gripper_cmd ------------------------------------------------------------------------

    def _execute_gripper(self, goal_handle: ServerGoalHandle) -> GripperCommand.Result:
        command = goal_handle.request.command
        if not (math.isfinite(command.position) and math.isfinite(command.max_effort)):
            message = (f'gripper goal refused: position {command.position} and max_effort '
                       f'{command.max_effort} must be finite numbers')
            self._logger.warning(message)
            goal_handle.abort()
            return GripperCommand.Result()
        try:
            run = self._on_sim(lambda world: self._gripper.start(
                world, self._sim.sim_time_ns, command.position, command.max_effort))
        except SimulationUnavailableError as error:
            self._logger.warning(f'gripper goal refused: {error}')
            goal_handle.abort()
            return GripperCommand.Result()
        ended = self._follow(goal_handle, run, self._gripper.cancel,
                             lambda: goal_handle.publish_feedback(_gripper_message(
                                 GripperCommand.Feedback(), run)))
        self._log_end('gripper_cmd', ended)
        return _gripper_message(GripperCommand.Result(), run)

    # -- shared -----------------------------------------------------------------------------

    def _on_sim(self, function: Callable[[SimWorld], object]):
        """Run ``function`` on the simulation thread and return its result (or raise its error)."""
        return answer(self._sim.call(function), _SIM_ANSWER_TIMEOUT)

    def _follow(self, goal_handle: ServerGoalHandle, run: ArmRun | GripperRun,
                cancel: Callable[[SimWorld, object], None],
                publish_feedback: Callable[[], None]) -> Ended:
        """Publish feedback until ``run`` ends; pass on a cancel request; set the goal's state."""
        done: Future = run.done
        goal_id = bytes(goal_handle.goal_id.uuid)
        self._cancels[goal_id] = lambda: self._sim.call(lambda world: cancel(world, run))
        cancel_sent = False
        next_feedback = time.monotonic()
        try:
            while True:
                # On a fixed grid, so that the time spent publishing does not slow the rate.
                next_feedback += FEEDBACK_PERIOD
                try:
                    ended = done.result(timeout=max(next_feedback - time.monotonic(), 0.0))
                    break
                except FutureTimeout:
                    next_feedback = max(next_feedback, time.monotonic() - FEEDBACK_PERIOD)
                if self._closed:
                    ended = Ended('aborted', INVALID_GOAL, 'the simulation stopped')
                    break
                if goal_handle.is_cancel_requested and not cancel_sent:
                    self._cancels[goal_id]()  # asked before the goal was registered here
                    cancel_sent = True
                self._unless_shut_down(publish_feedback)
        finally:
            del self._cancels[goal_id]
        if ended.status == 'succeeded':
            self._unless_shut_down(goal_handle.succeed)
        elif ended.status == 'canceled':
            # The run may end before the server has marked the goal as canceling.
            deadline = time.monotonic() + 1.0
            while not goal_handle.is_cancel_requested and time.monotonic() < deadline:
                time.sleep(0.001)
            self._unless_shut_down(goal_handle.canceled)
        else:
            self._unless_shut_down(goal_handle.abort)
        return ended

    def _unless_shut_down(self, publish: Callable[[], None]) -> None:
        """Call ``publish``; once a signal has shut the context down, let it fail quietly."""
        try:
            publish()
        except Exception:
            if self._node.context.ok():
                raise

    def _log_end(self, action: str, ended: Ended) -> None:
        if self._closed:
            return  # shutting down: rosout may be gone, and the exit says so anyway
        # One call site per severity: rclpy refuses a call site whose severity changes.
        # A goal that ends as asked is routine (a policy sends ten a second): DEBUG.
        message = f'{action} goal {ended.status}: {ended.message}'
        if ended.status == 'aborted' and not ended.logged:
            self._logger.warning(message)
        else:
            self._logger.debug(message)


def _trajectory_goal(request: FollowJointTrajectory.Goal):
    """Return the validated goal of a FollowJointTrajectory request, or raise TrajectoryError."""
    if request.multi_dof_trajectory.joint_names or request.multi_dof_trajectory.points:
        raise TrajectoryError(INVALID_JOINTS, 'multi_dof_trajectory given, but this arm has '
                              'only single-axis joints')
    trajectory = request.trajectory
    points = [Point(_seconds(p.time_from_start), p.positions, p.velocities, p.accelerations)
              for p in trajectory.points]
    return validate_trajectory(
        trajectory.joint_names, points, ARM_JOINTS,
        [Tolerance(t.name, t.position, t.velocity) for t in request.path_tolerance],
        [Tolerance(t.name, t.position, t.velocity) for t in request.goal_tolerance],
        _seconds(request.goal_time_tolerance))


def _gripper_message(message, run: GripperRun):
    """Fill a GripperCommand result or feedback from the run's latest state."""
    state = run.state
    message.position = state.position
    message.effort = state.effort
    message.stalled = state.stalled
    message.reached_goal = state.reached_goal
    return message


def _seconds(duration: Duration) -> float:
    return duration.sec + duration.nanosec * 1e-9


def _duration(seconds: float) -> Duration:
    ns = round(seconds * NS)
    return Duration(sec=ns // NS, nanosec=ns % NS)


def _time(seconds: float) -> Time:
    ns = round(seconds * NS)
    return Time(sec=ns // NS, nanosec=ns % NS)
