"""ROS 2 node ``ur_rg2_teleop``: jog the UR arm and work the RG2 gripper from the keyboard."""

from functools import partial
import math
import os
import sys
import threading
import time

from geometry_msgs.msg import TransformStamped
import rclpy
from rclpy.client import Client
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger
from ur_rg2_common.contract import ARM_JOINTS
from ur_rg2_common.episode import EpisodeMarkers
from ur_rg2_common.parameters import declare_parameters, follow_settings

from ur_rg2_teleop.display import (
    Console,
    SettleWatcher,
    arm_values,
    format_angles,
    outcome_line,
    result_outcome,
)
from ur_rg2_teleop.keymap import (
    SERVICES,
    STEP_LADDER_MM,
    CallService,
    CancelGoal,
    Command,
    Jog,
    Mark,
    Mode,
    SendGoal,
    action_for,
    describe_key,
    describe_step,
    help_text,
    larger_step,
    mark_line,
    mode_line,
    smaller_step,
    tool_step,
)
from ur_rg2_teleop.loops import key_loop, spin
from ur_rg2_teleop.pick_client import PICK_ACTION, PickClient
from ur_rg2_teleop.readiness import Readiness, needs
from ur_rg2_teleop.settings import PARAMETERS, KeysSettings
from ur_rg2_teleop.terminal import KeyReader, Stop, raw_mode, signal_pipe

USAGE_ERROR = 2
# Every jog is relative, so none may be dropped: room for a burst of pasted or repeated keys.
_JOG_QUEUE_DEPTH = 100
# Tool-mode steps are along and about this frame's axes.
TOOL_FRAME = 'base_link'
# Services whose success means the arm moved: the pose is shown once it settles.
_ARM_SERVICES = ('reset',)
# How often keys looks whether the nodes it waits for have come up, s.
_READINESS_PERIOD = 0.2


class KeysNode(Node):
    """Turn key presses into ``joint_jog`` messages and Trigger service calls."""

    def __init__(self, console: Console, **kwargs) -> None:
        super().__init__('ur_rg2_teleop', **kwargs)
        self._console = console
        self.settings = KeysSettings.from_values(declare_parameters(self, PARAMETERS))
        follow_settings(self, PARAMETERS, KeysSettings.from_values,
                        lambda settings: setattr(self, 'settings', settings))
        self._mode = Mode.JOINT
        self._jog_publisher = self.create_publisher(JointState, 'joint_jog', _JOG_QUEUE_DEPTH)
        self._tool_jog_publisher = self.create_publisher(
            TransformStamped, 'tool_jog', _JOG_QUEUE_DEPTH)
        self._episodes = EpisodeMarkers(self)  # b, n, j: a person's episodes
        self._trigger_clients: dict[str, Client] = {
            name: self.create_client(Trigger, name) for name in SERVICES}
        self._pick = PickClient(self, console, self._arm_moved)
        self.create_subscription(
            JointState, 'joint_states', self._on_joint_states, qos_profile_sensor_data)
        # Volatile: the episodes that end while keys runs, not one latched before it started.
        self.create_subscription(String, 'policy/result', self._on_policy_result, 10)
        # Shared by the key loop (moves) and the executor thread (joint states).
        self._lock = threading.Lock()
        self._watcher = SettleWatcher()
        self._angles: list[float] | None = None
        self._watcher.moved(time.monotonic())  # show the pose once at start-up
        self._readiness: Readiness | None = None  # set by watch_readiness

    @property
    def mode(self) -> Mode:
        """What the jog keys move."""
        return self._mode

    def handle_key(self, key: str) -> bool:
        """Act on one key; return False when it asks to quit."""
        action = action_for(key)
        refusal = self._readiness and self._readiness.refusal(needs(action, self._mode))
        if refusal:
            self._console.line(refusal)
        elif isinstance(action, Jog) and self._mode is Mode.TOOL:
            self._tool_jog(action)
        elif isinstance(action, Jog):
            self._jog(action)
        elif isinstance(action, CallService):
            self._call(action.service)
        elif isinstance(action, SendGoal):
            self._pick.send()
        elif isinstance(action, CancelGoal):
            self._pick.cancel()
        elif isinstance(action, Mark):
            self._episodes.mark(action.marker)
            self._console.line(mark_line(action.marker))
        elif action in (Command.STEP_UP, Command.STEP_DOWN):
            change = larger_step if action is Command.STEP_UP else smaller_step
            if self._mode is Mode.TOOL:
                self.set_parameters([Parameter('step_mm', value=change(self.settings.step_mm,
                                                                       STEP_LADDER_MM))])
                self._console.line(describe_step(self.settings.step_mm, 'mm', STEP_LADDER_MM))
            else:
                self.set_parameters([Parameter('step_deg', value=change(self.settings.step_deg))])
                self._console.line(describe_step(self.settings.step_deg))
        elif action is Command.MODE:
            self._mode = Mode.TOOL if self._mode is Mode.JOINT else Mode.JOINT
            self._console.line(mode_line(self._mode, self.settings.step_deg,
                                         self.settings.step_mm))
        elif action is Command.HELP:
            self._console.line(help_text(self.settings.step_deg, self._mode,
                                         self.settings.step_mm))
        elif action is Command.QUIT:
            return False
        else:
            self._console.line(f'{describe_key(key)} has no function (h: help)')
        return True

    def watch_readiness(self) -> str:
        """Refuse the keys of the nodes not up yet, showing each that comes; return the status.

        The status line (``starting: waiting for sim, vision, motion``) is the caller's to
        show, so that it goes out with the key table in one write.
        """
        self._readiness = Readiness()
        self._readiness_timer = self.create_timer(_READINESS_PERIOD, self._check_readiness)
        return self._readiness.status()

    def _check_readiness(self) -> None:
        publishers = {'joint_jog': self._jog_publisher, 'tool_jog': self._tool_jog_publisher}

        def available(name: str) -> bool:
            if name in publishers:
                return publishers[name].get_subscription_count() > 0
            if name == PICK_ACTION:
                return self._pick.server_is_ready()
            return self._trigger_clients[name].service_is_ready()  # as _call finds it

        status = self._readiness.update(available)
        if status is not None:
            self._console.line(status)
        if self._readiness.ready:
            self._readiness_timer.cancel()

    def _jog(self, jog: Jog) -> None:
        message = JointState()
        message.header.stamp = self.get_clock().now().to_msg()
        message.name = [ARM_JOINTS[jog.joint]]
        message.position = [jog.direction * math.radians(self.settings.step_deg)]
        self._jog_publisher.publish(message)
        with self._lock:
            self._watcher.moved(time.monotonic())
            no_states = self._angles is None
        if self._jog_publisher.get_subscription_count() == 0:
            self._console.line(f'{self._jog_publisher.topic_name}: nobody listens '
                               '(is the sim running?)')
        elif no_states:
            self._console.line('no joint_states received yet: angles cannot be shown')

    def _tool_jog(self, jog: Jog) -> None:
        translation, rotation = tool_step(jog, self.settings.step_mm, self.settings.step_deg)
        message = TransformStamped()
        message.header.stamp = self.get_clock().now().to_msg()
        message.header.frame_id = TOOL_FRAME
        message.child_frame_id = TOOL_FRAME
        t, r = message.transform.translation, message.transform.rotation
        t.x, t.y, t.z = translation
        r.x, r.y, r.z, r.w = rotation
        self._tool_jog_publisher.publish(message)
        with self._lock:
            self._watcher.moved(time.monotonic())
        if self._tool_jog_publisher.get_subscription_count() == 0:
            self._console.line(f'{self._tool_jog_publisher.topic_name}: nobody listens '
                               '(is the motion node running?)')

    def _call(self, service: str) -> None:
        client = self._trigger_clients[service]
        name = self.resolve_service_name(service)
        if not client.service_is_ready():
            self._console.line(f'{name}: service not available')
            return
        future = client.call_async(Trigger.Request())
        future.add_done_callback(partial(self._on_response, name, service in _ARM_SERVICES))

    def _on_response(self, name: str, moves_arm: bool, future: Future) -> None:
        error = future.exception()
        if error is not None:
            self._console.line(f'{name}: call failed: {error}')
            return
        response = future.result()
        self._console.line(outcome_line(name, response.success, response.message))
        if moves_arm and response.success:
            with self._lock:
                self._watcher.moved(time.monotonic())

    def _arm_moved(self) -> None:
        with self._lock:
            self._watcher.moved(time.monotonic())

    def _on_policy_result(self, message: String) -> None:
        self._console.line(outcome_line('policy episode', *result_outcome(message.data)))

    def _on_joint_states(self, message: JointState) -> None:
        angles = arm_values(message.name, message.position)
        if angles is None:
            return
        speeds = arm_values(message.name, message.velocity) or []
        with self._lock:
            self._angles = angles
            show = self._watcher.observe(time.monotonic(), speeds)
        if show:
            self._console.line(f'{self._mode.value} mode | '
                               f'{format_angles(angles, self.settings.step_deg)}')


def main(args: list[str] | None = None) -> int:
    """Run the teleop in this process's terminal; return the exit code."""
    stdin = 0
    if not os.isatty(stdin):
        print('keys: standard input is not a terminal; keys reads single key presses, so run it '
              'in an interactive terminal (for example: scripts/run, or keys after source '
              'scripts/env.sh; ros2 run ur_rg2_teleop keys in a ROS install)',
              file=sys.stderr)
        return USAGE_ERROR
    console = Console()
    # rclpy's own handlers would shut ROS down under the key loop; signal_pipe ends the loop.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor()
    node = None
    spin_errors: list[BaseException] = []
    spinner = threading.Thread(target=spin, args=(executor, spin_errors), daemon=True)
    try:
        with signal_pipe() as stop_fd:
            node = KeysNode(console)
            executor.add_node(node)
            spinner.start()
            with raw_mode(stdin):
                settings = node.settings
                console.line(f'{help_text(settings.step_deg, node.mode, settings.step_mm)}\n'
                             f'{node.watch_readiness()}')
                key_loop(node.handle_key, KeyReader(stdin, stop_fd), spinner, spin_errors)
    except (Stop, EOFError):
        pass
    except (InvalidParameterTypeException, InvalidParameterValueException) as error:
        print(f'keys: {error}', file=sys.stderr)
        return USAGE_ERROR
    finally:
        # Executor first: its guard condition ends the spinner's wait cleanly. Shutting the
        # context down under a waiting spinner thread could crash it (SIGSEGV seen on quit).
        executor.shutdown()
        if spinner.is_alive():
            spinner.join(timeout=5.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
