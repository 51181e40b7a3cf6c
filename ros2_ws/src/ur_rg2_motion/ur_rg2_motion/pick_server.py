"""The ``pick_ball`` action (ur_rg2_interfaces/action/PickBall) over the motion node's pick.

:class:`PickActionServer` runs each goal's pick through the node's ``run`` on a worker thread
(ur_rg2_common.action_server), publishes feedback (the phase and the distance to go,
ur_rg2_motion.pick_action) when a phase starts and every FEEDBACK_PERIOD s meanwhile, accepts
a cancel (the pick sees it at its next check and cancels the controller goal under way, so the
arm and the RG2 hold), and ends the goal succeeded, canceled or aborted with the outcome's
fields as its result.
"""

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
import math

from geometry_msgs.msg import Point
import numpy as np
from rclpy.action import CancelResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.node import Node
from ur_rg2_common.action_server import WorkerActionServer
from ur_rg2_interfaces.action import PickBall

from ur_rg2_motion.pick import Progress
from ur_rg2_motion.pick_action import PickOutcome, PickProgress

ACTION = 'pick_ball'
FEEDBACK_PERIOD = 0.2  # s between two feedback messages while a phase goes on


class PickActionServer:
    """The pick as an action: ``run(progress, canceled)`` picks; ``tcp()`` is the TCP or None."""

    def __init__(self, node: Node, run: Callable[[Progress, Callable[[], bool]], PickOutcome],
                 tcp: Callable[[], np.ndarray | None]) -> None:
        self._run, self._tcp = run, tcp
        self._goal: tuple[ServerGoalHandle, PickProgress] | None = None  # the one under way
        # Two: a goal that comes while a pick runs is answered (refused) at once.
        WorkerActionServer(node, PickBall, ACTION, self._execute,
                           workers=ThreadPoolExecutor(2, thread_name_prefix='pick'),
                           cancel_callback=lambda _goal: CancelResponse.ACCEPT)
        node.create_timer(FEEDBACK_PERIOD, self._send_feedback)

    def _execute(self, goal: ServerGoalHandle) -> PickBall.Result:
        progress = PickProgress()

        def report(phase: str, waypoints) -> None:
            progress(phase, waypoints)
            self._goal = (goal, progress)  # from the pick's start: not a goal refused
            self._send_feedback(goal, progress)  # at once: a phase may be shorter than a period
        try:
            outcome = self._run(report, lambda: goal.is_cancel_requested)
        finally:
            if self._goal is not None and self._goal[0] is goal:
                self._goal = None
        if outcome.success:
            goal.succeed()
        elif goal.is_cancel_requested:
            goal.canceled()
        else:
            goal.abort()
        ball = outcome.ball if outcome.ball is not None else (math.nan,) * 3
        return PickBall.Result(success=outcome.success, message=outcome.message,
                               ball_position=Point(x=ball[0], y=ball[1], z=ball[2]),
                               time_taken=outcome.seconds)

    def _send_feedback(self, goal: ServerGoalHandle | None = None,
                       progress: PickProgress | None = None) -> None:
        if goal is None:
            running = self._goal
            if running is None:
                return
            goal, progress = running
        phase, distance = progress.feedback(self._tcp())
        goal.publish_feedback(PickBall.Feedback(phase=phase, distance_to_go=distance))
