"""The ``pick_ball`` action from keys: ``g`` sends the goal, ``k`` cancels it.

Each phase the pick reports is one line as it starts (``/pick_ball ... descending, 0.25 m to
go``), the outcome one line as a service's (``/pick_ball: done: ...``, ``FAILED``, or
``canceled``). Nothing here blocks the key loop: the answers come on the executor's thread.
"""

from collections.abc import Callable
import math
import threading

from action_msgs.msg import GoalStatus
from rclpy.action.client import ClientGoalHandle
from rclpy.node import Node
from rclpy.task import Future
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_interfaces.action import PickBall

from ur_rg2_teleop.display import Console, outcome_line

PICK_ACTION = 'pick_ball'


def phase_line(name: str, phase: str, distance_to_go: float) -> str:
    """Return the line of a phase that starts, e.g. ``/pick_ball ... lifting, 0.15 m to go``."""
    to_go = f', {distance_to_go:.2f} m to go' if math.isfinite(distance_to_go) else ''
    return f'{name} ... {phase}{to_go}'


def goal_outcome_line(name: str, status: int, message: str) -> str:
    """Return the outcome line of a goal that ended with ``status`` (action_msgs/GoalStatus)."""
    if status == GoalStatus.STATUS_CANCELED:
        return f"{name}: canceled: {' '.join(message.split())}"
    return outcome_line(name, status == GoalStatus.STATUS_SUCCEEDED, message)


class PickClient:
    """keys' one pick at a time through the action; ``on_success`` when the ball is up."""

    def __init__(self, node: Node, console: Console, on_success: Callable[[], None]) -> None:
        self._client = ThreadSafeActionClient(node, PickBall, PICK_ACTION)
        self._name = node.resolve_service_name(PICK_ACTION)
        self._console, self._on_success = console, on_success
        self._lock = threading.Lock()
        self._sent = False  # a goal of these keys is pending or running
        self._goal: ClientGoalHandle | None = None  # once accepted
        self._cancel_asked = False
        self._phase: str | None = None

    def server_is_ready(self) -> bool:
        """Whether the motion node's action server is there."""
        return self._client.server_is_ready()

    def send(self) -> None:
        """Start a pick, unless the server is missing or a pick of these keys runs."""
        if not self._client.server_is_ready():
            self._console.line(f'{self._name}: action not available')
            return
        with self._lock:
            busy = self._sent
            if not busy:
                self._sent, self._goal, self._cancel_asked, self._phase = True, None, False, None
        if busy:
            self._console.line(f'{self._name}: a pick is running (k cancels it)')
            return
        self._client.send_goal_async(PickBall.Goal(), feedback_callback=self._on_feedback
                                     ).add_done_callback(self._on_answer)

    def cancel(self) -> None:
        """Cancel the pick of these keys: the arm stops where it is."""
        with self._lock:
            sent, goal = self._sent, self._goal
            self._cancel_asked = sent
        if not sent:
            self._console.line(f'{self._name}: no pick running (g starts one)')
        elif goal is not None:
            goal.cancel_goal_async()  # else once the goal is accepted

    def _on_answer(self, future: Future) -> None:
        error = future.exception()
        goal = None if error is not None else future.result()
        if goal is None or not goal.accepted:
            with self._lock:
                self._sent = False
            why = f'call failed: {error}' if error is not None else 'FAILED: goal rejected'
            self._console.line(f'{self._name}: {why}')
            return
        with self._lock:
            self._goal, cancel = goal, self._cancel_asked
        goal.get_result_async().add_done_callback(self._on_result)
        if cancel:
            goal.cancel_goal_async()

    def _on_feedback(self, message) -> None:
        feedback = message.feedback
        with self._lock:
            new, self._phase = feedback.phase != self._phase, feedback.phase
        if new:
            self._console.line(phase_line(self._name, feedback.phase, feedback.distance_to_go))

    def _on_result(self, future: Future) -> None:
        with self._lock:
            self._sent, self._goal = False, None
        error = future.exception()
        if error is not None:
            self._console.line(f'{self._name}: call failed: {error}')
            return
        answer = future.result()
        self._console.line(goal_outcome_line(self._name, answer.status, answer.result.message))
        if answer.status == GoalStatus.STATUS_SUCCEEDED:
            self._on_success()
