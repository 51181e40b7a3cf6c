"""Benchmark of the trajectory controller: tracking error while trajectories execute.

The sim runs as its own process with its defaults (real-time factor 1, camera on); this process
sends trajectories through random configurations across the workspace to
``joint_trajectory_controller/follow_joint_trajectory`` as a MoveIt-style client would, and
reads the controller's feedback (desired and actual positions, at least 10 Hz) until each goal
ends. Run alone: python -m bench.controllers_bench
"""

import threading
import time

from builtin_interfaces.msg import Duration
from control_msgs.action import FollowJointTrajectory
import numpy as np
from rclpy.action import ActionClient
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from trajectory_msgs.msg import JointTrajectoryPoint

from bench.processes import node_process, percentile

DOMAIN_ID = 213
READY = 'simulating'
TRAJECTORIES = 6
POINTS = 3
SEED = 7
# Configurations drawn from these ranges (rad), per joint in ARM_JOINTS order: the reachable
# workspace in front of and around the arm, elbow not fully folded.
RANGES = [(-2.5, 2.5), (-2.4, -0.4), (-2.4, 2.4), (-2.5, 1.0), (-2.0, 2.0), (-3.0, 3.0)]
# Segment times keep the spline's peak below this speed (a cubic from rest peaks at 1.5x its
# mean speed).
PEAK_SPEED = 2.0  # rad/s
JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
          'wrist_2_joint', 'wrist_3_joint']


def _goals() -> list[FollowJointTrajectory.Goal]:
    rng = np.random.default_rng(SEED)
    lows, highs = np.array(RANGES).T
    previous = np.zeros(len(JOINTS))
    goals = []
    for _ in range(TRAJECTORIES):
        goal = FollowJointTrajectory.Goal()
        goal.trajectory.joint_names = JOINTS
        t = 0.0
        for _ in range(POINTS):
            point = rng.uniform(lows, highs)
            t += max(1.0, 1.5 * np.abs(point - previous).max() / PEAK_SPEED)
            ns = round(t * 1e9)
            goal.trajectory.points.append(JointTrajectoryPoint(
                positions=point.tolist(), time_from_start=Duration(sec=ns // 10 ** 9,
                                                                   nanosec=ns % 10 ** 9)))
            previous = point
        goals.append(goal)
    return goals


class _Client:
    """An action client in a node of its own, spun on a background thread."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        self.context.init(domain_id=domain_id)
        self.node = Node('controllers_bench', context=self.context)
        self.client = ActionClient(self.node, FollowJointTrajectory,
                                   'joint_trajectory_controller/follow_joint_trajectory')
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def run(self, goal: FollowJointTrajectory.Goal, timeout: float = 60.0):
        """Send ``goal``; return its result and the (wall time, feedback) received."""
        feedback = []
        sent = self.client.send_goal_async(
            goal, feedback_callback=lambda m: feedback.append((time.monotonic(), m.feedback)))
        handle = _wait(sent, timeout, 'goal response')
        if not handle.accepted:
            raise RuntimeError('benchmark: the trajectory goal was rejected')
        return _wait(handle.get_result_async(), timeout, 'goal result'), feedback

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=5)
        self.thread.join(timeout=5)
        self.node.destroy_node()
        self.context.try_shutdown()


def _wait(future, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise RuntimeError(f'benchmark: no {what} within {timeout:.0f} s')
        time.sleep(0.01)
    return future.result()


def run() -> list[tuple[str, str, str]]:
    """Measure trajectory tracking; return (metric, measured, target) rows."""
    client = _Client(DOMAIN_ID)
    errors, rates, succeeded, seconds = [], [], 0, 0.0
    goals = _goals()
    try:
        with node_process('sim', {}, DOMAIN_ID, ready=READY):
            if not client.client.wait_for_server(timeout_sec=60):
                raise RuntimeError('benchmark: no follow_joint_trajectory server')
            for goal in goals:
                response, feedback = client.run(goal)
                succeeded += response.result.error_code == 0
                end = seconds_of(goal.trajectory.points[-1].time_from_start)
                seconds += end
                times = [t for t, _ in feedback]
                if len(times) > 1:
                    rates.append((len(times) - 1) / (times[-1] - times[0]))
                # During execution: up to the last point's time (after it, the goal waits
                # for the arm to settle within tolerance).
                errors += [np.abs(np.array(f.error.positions)).max() for _, f in feedback
                           if seconds_of(f.desired.time_from_start) <= end]
    finally:
        client.close()
    degrees = np.degrees(errors)
    return [
        ('controllers: trajectory tracking error during execution, p50 / p99 (worst joint)',
         f'{percentile(degrees, 50):.2f} / {percentile(degrees, 99):.2f} deg '
         f'({len(degrees)} feedback samples, {len(goals)} trajectories, {seconds:.0f} s)',
         'p99 <= 1 deg'),
        ('controllers: trajectory feedback rate (slowest goal)', f'{min(rates):.1f} Hz',
         '>= 10 Hz'),
        ('controllers: trajectory goals SUCCESSFUL', f'{succeeded} of {len(goals)}', 'all'),
    ]


def seconds_of(duration: Duration) -> float:
    """Return a Duration in seconds."""
    return duration.sec + duration.nanosec * 1e-9


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
