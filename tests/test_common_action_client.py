"""Goals sent from worker threads while the executor spins all get their answers.

rclpy 7.1.6's ActionClient can drop a goal's response taken between the request and the
record of its sequence number (ros2/rclpy#1123): the goal's future then never completes, as a
pick's gripper goal once did in the suite. ThreadSafeActionClient takes rclpy's later lock.
"""

from concurrent.futures import ThreadPoolExecutor
import threading
import time

from conftest import wait_for
from control_msgs.action import GripperCommand
from rclpy.action import ActionServer
from ur_rg2_common.action_client import ThreadSafeActionClient

WORKERS = 4
GOALS_EACH = 5
ANSWER_TIMEOUT = 30.0  # s, for one goal's acceptance and result on a loaded machine
RECORD_DELAY_S = 0.05  # s between a request going out and rclpy recording it


def _finish(goal_handle) -> GripperCommand.Result:
    goal_handle.succeed()
    return GripperCommand.Result(position=goal_handle.request.command.position, reached_goal=True)


def _done(future, what: str) -> object:
    answered = threading.Event()
    future.add_done_callback(lambda _: answered.set())
    assert answered.wait(ANSWER_TIMEOUT), f'no answer within {ANSWER_TIMEOUT:g} s to {what}'
    return future.result()


class _SlowToRecord:
    """An action client handle that waits after sending a request, before rclpy records it.

    The window of ros2/rclpy#1123 made wide: the answer is back and taken meanwhile.
    """

    def __init__(self, handle) -> None:
        self._handle = handle

    def __getattr__(self, name: str):
        attribute = getattr(self._handle, name)
        if not name.startswith('send_'):
            return attribute

        def send_then_wait(*args):
            sequence = attribute(*args)
            time.sleep(RECORD_DELAY_S)
            return sequence
        return send_then_wait

    def __enter__(self):
        return self._handle.__enter__()

    def __exit__(self, *args):
        return self._handle.__exit__(*args)


def test_goals_sent_from_many_threads_all_get_accepted_and_their_results(ros_graph):
    ActionServer(ros_graph.node('gripper_server'), GripperCommand, 'gripper', _finish)
    client = ThreadSafeActionClient(ros_graph.node('gripper_client'), GripperCommand, 'gripper')
    client._client_handle = _SlowToRecord(client._client_handle)
    wait_for(client.server_is_ready, 10, 'the action server')

    def send(worker: int) -> list[float]:
        positions = []
        for n in range(GOALS_EACH):
            goal = GripperCommand.Goal()
            goal.command.position = worker + n / 100
            handle = _done(client.send_goal_async(goal), f'goal {n} of worker {worker}')
            assert handle.accepted
            result = _done(handle.get_result_async(), f'the result of goal {n}')
            positions.append(result.result.position)
        return positions

    with ThreadPoolExecutor(WORKERS) as pool:
        answered = list(pool.map(send, range(WORKERS)))
    assert answered == [[w + n / 100 for n in range(GOALS_EACH)] for w in range(WORKERS)]
