"""ROS 2 node ``ur_rg2_teleop``: jog the UR arm and work the RG2 gripper from the keyboard."""

from functools import partial
import math
import os
import sys
import threading
import time

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
import rclpy
from rclpy.client import Client
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from ur_rg2_teleop.display import Console, SettleWatcher, arm_values, format_angles
from ur_rg2_teleop.keymap import (
    JOINT_NAMES,
    MAX_STEP_DEG,
    MIN_STEP_DEG,
    SERVICES,
    CallService,
    Command,
    Jog,
    action_for,
    describe_key,
    help_text,
    larger_step,
    smaller_step,
)
from ur_rg2_teleop.terminal import KeyReader, Stop, raw_mode, signal_pipe

USAGE_ERROR = 2
# How often the key loop looks up from the keyboard to check that ROS is still being spun.
_SPIN_CHECK_PERIOD = 0.5
# Every jog is relative, so none may be dropped: room for a burst of pasted or repeated keys.
_JOG_QUEUE_DEPTH = 100


class KeysNode(Node):
    """Turn key presses into ``joint_jog`` messages and Trigger service calls."""

    def __init__(self, console: Console, **kwargs) -> None:
        super().__init__('ur_rg2_teleop', **kwargs)
        self._console = console
        self.declare_parameter('step_deg', 5.0, ParameterDescriptor(
            description='Degrees one jog key moves its joint; + and - change it',
            floating_point_range=[FloatingPointRange(
                from_value=MIN_STEP_DEG, to_value=MAX_STEP_DEG, step=0.0)],
        ))
        self._jog_publisher = self.create_publisher(JointState, 'joint_jog', _JOG_QUEUE_DEPTH)
        self._trigger_clients: dict[str, Client] = {
            name: self.create_client(Trigger, name) for name in SERVICES}
        self.create_subscription(
            JointState, 'joint_states', self._on_joint_states, qos_profile_sensor_data)
        # Shared by the key loop (moves) and the executor thread (joint states).
        self._lock = threading.Lock()
        self._watcher = SettleWatcher()
        self._angles: list[float] | None = None
        self._watcher.moved(time.monotonic())  # show the pose once at start-up

    @property
    def step_deg(self) -> float:
        """Current jog step in degrees."""
        return self.get_parameter('step_deg').value

    def handle_key(self, key: str) -> bool:
        """Act on one key; return False when it asks to quit."""
        action = action_for(key)
        if isinstance(action, Jog):
            self._jog(action)
        elif isinstance(action, CallService):
            self._call(action.service)
        elif action in (Command.STEP_UP, Command.STEP_DOWN):
            change = larger_step if action is Command.STEP_UP else smaller_step
            self.set_parameters([Parameter('step_deg', value=change(self.step_deg))])
            self._console.line(f'step {self.step_deg:g} deg')
        elif action is Command.HELP:
            self._console.line(help_text(self.step_deg))
        elif action is Command.QUIT:
            return False
        else:
            self._console.line(f'{describe_key(key)} has no function (h: help)')
        return True

    def _jog(self, jog: Jog) -> None:
        message = JointState()
        message.header.stamp = self.get_clock().now().to_msg()
        message.name = [JOINT_NAMES[jog.joint]]
        message.position = [jog.direction * math.radians(self.step_deg)]
        self._jog_publisher.publish(message)
        with self._lock:
            self._watcher.moved(time.monotonic())
            no_states = self._angles is None
        if self._jog_publisher.get_subscription_count() == 0:
            self._console.line(f'{self._jog_publisher.topic_name}: nobody listens '
                               '(is the sim running?)')
        elif no_states:
            self._console.line('no joint_states received yet: angles cannot be shown')

    def _call(self, service: str) -> None:
        client = self._trigger_clients[service]
        name = self.resolve_service_name(service)
        if not client.service_is_ready():
            self._console.line(f'{name}: service not available')
            return
        future = client.call_async(Trigger.Request())
        future.add_done_callback(partial(self._on_response, name, service == 'reset'))

    def _on_response(self, name: str, moves_arm: bool, future: Future) -> None:
        error = future.exception()
        if error is not None:
            self._console.line(f'{name}: call failed: {error}')
            return
        response = future.result()
        outcome = 'done' if response.success else 'FAILED'
        # One line per result, whatever the server put in its message.
        message = ' '.join(response.message.split())
        self._console.line(f'{name}: {outcome}{": " + message if message else ""}')
        if moves_arm and response.success:
            with self._lock:
                self._watcher.moved(time.monotonic())

    def _on_joint_states(self, message: JointState) -> None:
        angles = arm_values(message.name, message.position)
        if angles is None:
            return
        speeds = arm_values(message.name, message.velocity) or []
        with self._lock:
            self._angles = angles
            show = self._watcher.observe(time.monotonic(), speeds)
        if show:
            self._console.line(format_angles(angles, self.step_deg))


def _spin(executor: SingleThreadedExecutor, errors: list[BaseException]) -> None:
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except BaseException as error:  # noqa: BLE001 - handed to the main thread, which raises it
        errors.append(error)


def _key_loop(node: KeysNode, reader: KeyReader, spinner: threading.Thread,
              spin_errors: list[BaseException]) -> None:
    while spinner.is_alive():
        for key in reader.read(timeout=_SPIN_CHECK_PERIOD):
            if not node.handle_key(key):
                return
    raise RuntimeError('the ROS executor stopped') from (spin_errors[0] if spin_errors else None)


def main(args: list[str] | None = None) -> int:
    """Run the teleop in this process's terminal; return the exit code."""
    stdin = 0
    if not os.isatty(stdin):
        print('keys: standard input is not a terminal; keys reads single key presses, so run it '
              'in an interactive terminal (for example: ros2 run ur_rg2_teleop keys)',
              file=sys.stderr)
        return USAGE_ERROR
    console = Console()
    # rclpy's own handlers would shut ROS down under the key loop; signal_pipe ends the loop.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    executor = SingleThreadedExecutor()
    node = None
    spin_errors: list[BaseException] = []
    spinner = threading.Thread(target=_spin, args=(executor, spin_errors), daemon=True)
    try:
        with signal_pipe() as stop_fd:
            node = KeysNode(console)
            executor.add_node(node)
            spinner.start()
            with raw_mode(stdin):
                console.line(help_text(node.step_deg))
                _key_loop(node, KeyReader(stdin, stop_fd), spinner, spin_errors)
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
