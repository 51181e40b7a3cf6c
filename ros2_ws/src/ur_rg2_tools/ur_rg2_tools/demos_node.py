"""``demos``: record N pick episodes of the running graph, through the topics a person uses.

``ros2 run ur_rg2_tools demos -o FILE.mcap --episodes N [--seed S] [--timeout-s T] [--all]``.
For each episode the ball goes to a random place the arm reaches and the camera sees (the
sim's ``ball_position``), the arm home with the gripper open (``reset``, ``gripper/open``);
once vision sees the ball (``ball/position``) the pick runs (the ``pick_ball`` action, which
marks the episode on ``episode``), then the ball is dropped. ``record`` runs beside it as a
child process and is stopped cleanly at the end: the file is a complete MCAP that
``to_lerobot`` exports. The first Ctrl-C stops after the episode under way, a second one gives
it up at once; either way the episodes done stay in the file and the exit code is 0. The loop
is :mod:`ur_rg2_tools.demos`; this module is the ROS side and ``main``.
"""

from __future__ import annotations

from collections.abc import Sequence
import signal
import sys
import time

from geometry_msgs.msg import PointStamped
from rcl_interfaces.srv import GetParameters, SetParameters
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from sensor_msgs.msg import CameraInfo, JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from ur_rg2_common.action_client import ThreadSafeActionClient
from ur_rg2_common.contract import ARM_JOINTS, EPISODE_QOS, EPISODE_TOPIC, IMAGE_QOS
from ur_rg2_common.self_spinning import SelfSpinningNode
from ur_rg2_interfaces.action import PickBall
from ur_rg2_vision.placement import Camera
from ur_rg2_vision.ros_image import camera_matrix

from ur_rg2_tools.child_recorder import Recorder
from ur_rg2_tools.demos import (
    TOPICS,
    DemosError,
    Scene,
    StopNow,
    Tally,
    check_options,
    parse_args,
    run_episodes,
)

NODE_NAME = 'ur_rg2_demos'
SIM_NODE = 'ur_rg2_sim'
RECORDER_NODE = 'ur_rg2_recorder'
HOME_TOLERANCE_RAD = 0.03
SIGHTINGS = 5  # ball/position messages after the ball was placed: vision sees it
SEE_S = 20.0  # at most this long for them (a ball hidden by the arm is never seen)
GRAPH_HINT = ('is the graph running (scripts/run --headless, or ros2 launch ur_rg2_bringup '
              'graph.launch.py) on this ROS_DOMAIN_ID?')


class GraphDriver(SelfSpinningNode):
    """Drives the graph for the episode loop; waits by spinning itself (one thread)."""

    error = DemosError

    def __init__(self, timeout: float) -> None:
        super().__init__(NODE_NAME, timeout)
        self.stops = 0  # Ctrl-Cs so far: 1 stops after the episode, 2 at once
        self._get = self.create_client(GetParameters, f'{SIM_NODE}/get_parameters')
        self._set = self.create_client(SetParameters, f'{SIM_NODE}/set_parameters')
        self._reset = self.create_client(Trigger, 'reset')
        self._open = self.create_client(Trigger, 'gripper/open')
        self._pick = ThreadSafeActionClient(self, PickBall, 'pick_ball')
        self.sightings = 0
        self.joints: JointState | None = None
        self.info: CameraInfo | None = None
        self.markers: list[str] = []
        self.create_subscription(PointStamped, 'ball/position', self._on_ball,
                                 qos_profile_sensor_data)
        self.create_subscription(JointState, 'joint_states', self._on_joints,
                                 qos_profile_sensor_data)
        self.create_subscription(CameraInfo, 'camera/color/camera_info', self._on_info,
                                 IMAGE_QOS)
        self.create_subscription(String, EPISODE_TOPIC, lambda m: self.markers.append(m.data),
                                 EPISODE_QOS)
        self.home_position: list[float] = [0.0] * len(ARM_JOINTS)

    def _on_ball(self, _msg: PointStamped) -> None:
        self.sightings += 1

    def _on_joints(self, msg: JointState) -> None:
        self.joints = msg

    def _on_info(self, msg: CameraInfo) -> None:
        self.info = msg

    def check_stop(self) -> None:
        """Raise StopNow after the second Ctrl-C."""
        if self.stops >= 2:
            raise StopNow()

    def wait_for_graph(self) -> Scene:
        """Wait for the sim, motion and the camera; return what placements need."""
        for ready, what in ((self._get.service_is_ready, f'the sim ({SIM_NODE} parameters)'),
                            (self._set.service_is_ready, f'the sim ({SIM_NODE} parameters)'),
                            (self._reset.service_is_ready, 'the sim (reset)'),
                            (self._open.service_is_ready, 'the sim (gripper/open)'),
                            (self._pick.server_is_ready, 'the motion node (pick_ball)'),
                            (lambda: self.info is not None, 'camera/color/camera_info'),
                            (lambda: self.joints is not None, 'joint_states')):
            try:
                self.spin_until(ready, what)
            except DemosError:
                raise DemosError(f'no graph: {what} did not answer within {self.timeout:g} s: '
                                 f'{GRAPH_HINT}') from None
        values = self.get_parameters(('robot_model', 'ball_radius', 'camera_position',
                                      'camera_look_at', 'home_position'))
        self.home_position = [float(v) for v in values['home_position']]
        camera = Camera(tuple(values['camera_position']), tuple(values['camera_look_at']),
                        camera_matrix(self.info), self.info.width, self.info.height)
        return Scene(camera, float(values['ball_radius']), str(values['robot_model']))

    def get_parameters(self, names: Sequence[str]) -> dict[str, object]:
        """Return the sim's values of parameters ``names``."""
        return self.parameters_of(self._get, names)

    def place_ball(self, position: tuple[float, float, float]) -> None:
        """Set the sim's ``ball_position`` (as ``ros2 param set`` does)."""
        request = SetParameters.Request(
            parameters=[Parameter('ball_position', value=list(position)).to_parameter_msg()])
        result = self.call(self._set, request, 'the sim to set ball_position').results[0]
        if not result.successful:
            raise DemosError(f'the sim refused ball_position {position}: {result.reason}')

    def _trigger(self, client, what: str) -> None:
        response = self.call(client, Trigger.Request(), what)
        if not response.success:
            raise DemosError(f'{what} failed: {response.message}')

    def _at_home(self) -> bool:
        if self.joints is None:
            return False
        positions = dict(zip(self.joints.name, self.joints.position))
        return all(abs(positions.get(joint, float('inf')) - home) <= HOME_TOLERANCE_RAD
                   for joint, home in zip(ARM_JOINTS, self.home_position))

    def home(self) -> None:
        """Open the gripper, send the arm home and wait until it is there."""
        self._trigger(self._open, 'gripper/open')
        self._trigger(self._reset, 'reset')
        self.joints = None
        self.spin_until(self._at_home, 'the arm to reach home_position (joint_states)')

    def drop(self) -> None:
        """Open the gripper (the ball, if held, falls)."""
        self._trigger(self._open, 'gripper/open')

    def see_ball(self) -> bool:
        """Return whether SIGHTINGS ball/positions come after now within SEE_S."""
        seen = self.sightings
        try:
            self.spin_until(lambda: self.sightings - seen >= SIGHTINGS, 'ball/position',
                            min(SEE_S, self.timeout))
        except DemosError:
            return False
        return True

    def pick(self) -> tuple[bool, str]:
        """Run the pick action; return (success, message). A stop now cancels it."""
        goal = self._pick.send_goal_async(PickBall.Goal())
        self.spin_until(goal.done, 'the pick_ball action to take the goal')
        handle = goal.result()
        if not handle.accepted:
            return False, 'the motion node refused the pick'
        result = handle.get_result_async()
        try:
            self.spin_until(result.done, 'the pick to end')
        except (DemosError, StopNow) as error:
            handle.cancel_goal_async()
            stops, self.stops = self.stops, 0  # let the cancel through
            try:
                self.spin_until(result.done, 'the cancelled pick to end', 10.0)
            finally:
                self.stops = stops
            if isinstance(error, StopNow):
                raise
            return False, f'{error}: cancelled'
        outcome = result.result().result
        return bool(outcome.success), outcome.message

    def settle(self, seconds: float) -> None:
        """Spin for ``seconds`` (the last marker reaches the recorder)."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._executor.spin_once(timeout_sec=0.02)

    def recorder_ready(self, topics: Sequence[str]) -> bool:
        """Tell whether the recorder subscribes to every topic of ``topics``."""
        return all(any(info.node_name == RECORDER_NODE for info in
                       self.get_subscriptions_info_by_topic(self.resolve_topic_name(topic)))
                   for topic in topics)


def say(line: str) -> None:
    """Print a progress line."""
    print(f'demos: {line}', flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``demos`` command; return its exit code."""
    argv = list(sys.argv if argv is None else argv)
    options = parse_args(remove_ros_args(argv)[1:])
    try:
        check_options(options)
    except DemosError as error:
        print(f'demos: {error}', file=sys.stderr)
        return 1
    stops: list[int] = []
    driver: GraphDriver | None = None

    def on_signal(signum, _frame) -> None:
        stops.append(signum)
        count = 2 if signum == signal.SIGTERM else len(stops)
        if driver is not None:
            driver.stops = max(driver.stops, count)
        if count == 1:
            print('\ndemos: stopping after this episode (Ctrl-C again: at once)', flush=True)

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    driver = GraphDriver(options.timeout_s)
    driver.stops = 2 if signal.SIGTERM in stops else len(stops)
    recorder: Recorder | None = None
    failure: str | None = None
    tally = Tally(options.episodes)
    started = False
    try:
        scene = driver.wait_for_graph()
        recorder = Recorder(options.output, None if options.all else TOPICS, options.timeout_s)
        driver.spin_until(lambda: driver.recorder_ready(TOPICS) or not recorder.alive(),
                          'the recorder to subscribe to ' + ', '.join(TOPICS))
        if not recorder.alive():
            raise DemosError(f'the recorder ended at start:\n{recorder.output()}')
        say(f'recording to {options.output}; {options.episodes} episodes, seed {options.seed} '
            '(Ctrl-C stops after the episode under way)')
        started = True
        run_episodes(driver, scene, options, lambda: driver.stops > 0, say, tally)
        driver.settle(1.0)
    except StopNow:
        driver.stops = 0
        driver.settle(1.0)  # the given-up pick's failure marker reaches the recorder
        say('stopped')
    except DemosError as error:
        failure = str(error)
    finally:
        if recorder is not None:
            problem = recorder.stop()
            failure = failure or problem
        driver.destroy_node()
        rclpy.try_shutdown()
    if started:
        say(f'{tally.summary()}; wrote {options.output}')
    if failure is not None:
        print(f'demos: {failure}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
