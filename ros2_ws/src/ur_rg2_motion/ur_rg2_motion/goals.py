"""The pick's robot (ur_rg2_motion.pick.Arm) over the motion node's action clients and state.

:class:`ControllerArm` sends trajectory and gripper goals through the node's action clients
and waits for them from a worker thread (other executor threads complete the futures), giving
a goal up, cancelled so that the arm or the RG2 holds, when it overruns or ``watch`` raises
meanwhile.
A trajectory overruns after 3 x its duration + 10 s; when the real driver's speed slider
(``speed_scaling_state_broadcaster/speed_scaling``) is below full, the error says so.
"""

from collections.abc import Callable
import threading
import time

from action_msgs.msg import GoalStatus
import numpy as np
from rclpy.action import ActionClient

from ur_rg2_motion.messages import gripper_goal, trajectory_goal
from ur_rg2_motion.pick import GripResult, PickCancelledError, PickError
from ur_rg2_motion.planning import Trajectory
from ur_rg2_motion.robot_state import RobotState

GOAL_ANSWER_TIMEOUT = 15.0  # s: a loaded machine may answer a goal seconds late
GRIPPER_TIMEOUT = 10.0  # s
# A move is given up after MOTION_FACTOR x its duration + MOTION_SLACK: simulation time may run
# slower than the wall clock (a loaded machine), a real arm slower than planned (the slider).
MOTION_FACTOR = 3.0
MOTION_SLACK = 10.0  # s
CHECK_PERIOD = 0.05  # s between two ``check`` calls while waiting
# Why a trajectory controller refuses a goal, most often: for the user to check first.
REFUSED_HINT = ('is the controller active? On a real UR: the External Control program '
                'running on the teach pendant, or the driver in headless_mode')


class ControllerArm:
    """The arm and the RG2 through their controllers: the pick's Arm.

    ``state``: the node's robot state. ``check`` (may raise) runs before each goal is sent,
    under ``send_lock``, and after it ends; ``watch`` (may raise, as ``check`` does) while
    waiting; ``speed_scaling`` returns the driver's slider (percent) or None.
    """

    def __init__(self, trajectory: ActionClient, gripper: ActionClient, state: RobotState,
                 send_lock: threading.Lock, check: Callable[[], None],
                 watch: Callable[[], None], vision_done: Callable[[], None],
                 speed_scaling: Callable[[], float | None]) -> None:
        self._trajectory, self._gripper, self._state = trajectory, gripper, state
        self._send_lock, self._check, self._watch = send_lock, check, watch
        self._speed_scaling = speed_scaling
        self.vision_done = vision_done

    @property
    def velocity_limits(self) -> np.ndarray | None:
        """The six arm joints' velocity limits (rad/s) from robot_description."""
        return self._state.velocity_limits

    def joints(self) -> np.ndarray:
        """Return the arm joints now (rad); NotReceivedError before the first joint_states."""
        return self._state.joints()

    def speed(self) -> float:
        """Return the fastest arm joint's speed now (rad/s)."""
        return self._state.speed()

    def opening(self) -> float | None:
        """Return the RG2's opening now (m), None when unknown."""
        return self._state.opening()

    def check(self) -> None:
        """Raise when the pick is to stop."""
        self._check()

    def move(self, trajectory: Trajectory, what: str) -> None:
        """Run ``trajectory`` through the trajectory controller to its end."""
        with self._send_lock:
            self._check()
            future = self._trajectory.send_goal_async(
                trajectory_goal(trajectory.times, trajectory.positions))
        handle = self.wait(future, GOAL_ANSWER_TIMEOUT, what)
        if not handle.accepted:
            raise PickError(f'{what}: the trajectory controller refused the move '
                            f'({REFUSED_HINT})')
        timeout = MOTION_FACTOR * trajectory.duration + MOTION_SLACK
        try:
            response = self.wait(handle.get_result_async(), timeout, what, handle)
        except PickError as error:
            scaling = self._speed_scaling()
            if 'no answer' in str(error) and scaling is not None and scaling < 100.0:
                raise PickError(
                    f'{error} ({MOTION_FACTOR:g} x its {trajectory.duration:.1f} s + '
                    f'{MOTION_SLACK:g} s): the speed slider is at {scaling:.0f} %, the move '
                    'was stopped; raise the slider on the teach pendant') from None
            raise
        self._check()
        if response.status != GoalStatus.STATUS_SUCCEEDED:
            raise PickError(f'{what}: the move ended early: {response.result.error_string}')

    def send(self, trajectory: Trajectory, on_end: Callable[[bool, str | None], None]) -> None:
        """Send ``trajectory`` without waiting (a tool move).

        ``on_end(refused, why)`` once it ends: ``why`` None when it succeeded.
        """
        def answered(future) -> None:
            handle = future.result()
            if not handle.accepted:
                on_end(True, f'the trajectory controller refused the move ({REFUSED_HINT})')
                return
            handle.get_result_async().add_done_callback(lambda done: on_end(False, None if (
                done.result().status == GoalStatus.STATUS_SUCCEEDED) else
                f'the move ended early: {done.result().result.error_string}'))
        self._trajectory.send_goal_async(
            trajectory_goal(trajectory.times, trajectory.positions)).add_done_callback(answered)

    def start_grip(self, opening: float) -> object:
        """Send the gripper toward ``opening`` (m) at full force; return the goal's future."""
        with self._send_lock:
            self._check()
            return self._gripper.send_goal_async(gripper_goal(opening))

    def finish_grip(self, future, what: str) -> GripResult:
        """Wait for the gripper goal of ``future`` to end."""
        handle = self.wait(future, GOAL_ANSWER_TIMEOUT, what)
        if not handle.accepted:
            raise PickError(f'{what}: the gripper controller refused the goal')
        response = self.wait(handle.get_result_async(), GRIPPER_TIMEOUT, what, handle)
        self._check()
        if response.status != GoalStatus.STATUS_SUCCEEDED:
            raise PickError(f'{what}: the gripper goal ended early')
        return GripResult(response.result.position, response.result.stalled)

    def wait(self, future, timeout: float, what: str, handle=None):
        """Wait for an action future; return its result.

        Given up (its goal cancelled: the arm or the RG2 holds) after ``timeout`` s or when
        ``watch`` raises meanwhile.
        ``handle``: the goal's, when ``future`` is its result.
        """
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        deadline = time.monotonic() + timeout
        while not done.wait(max(0.0, min(CHECK_PERIOD, deadline - time.monotonic()))):
            try:
                if time.monotonic() >= deadline:
                    raise PickError(f'{what}: no answer from the controller within '
                                    f'{timeout:.0f} s')
                self._watch()
            except (PickError, PickCancelledError):
                cancel_goal(future, handle)
                raise
        return future.result()


def cancel_goal(future, handle) -> None:
    """Cancel the goal of ``handle``, or else the goal ``future`` answers once it is accepted."""
    if handle is not None:
        handle.cancel_goal_async()
        return

    def cancel(answered) -> None:
        if answered.result().accepted:
            answered.result().cancel_goal_async()
    future.add_done_callback(cancel)
