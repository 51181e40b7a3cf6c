"""The real ``keys`` executable on a pseudo-terminal, driven key by key against the sim."""

from concurrent.futures import ThreadPoolExecutor
import math
import os
from pathlib import Path
import re
import select
import signal
import subprocess
import sys
import termios
import threading
import time

from conftest import wait_for
from geometry_msgs.msg import TransformStamped
import pytest
from rclpy.action import CancelResponse
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from ur_rg2_common.action_server import WorkerActionServer
from ur_rg2_interfaces.action import PickBall
from ur_rg2_sim.sim_node import SimNode

KEYS = str(Path(sys.executable).with_name('keys'))
BANNER = 'p, Ctrl-C  quit'
ANGLES = re.compile(r'pan +([+-]\d+\.\d) .*\(step [\d.]+\)')
# Discovery between two processes can take a few seconds on a loaded machine.
CONNECT_TIMEOUT = 30.0
MOVE_TIMEOUT = 15.0
TOLERANCE = math.radians(1.0)


class KeysTerminal:
    """``keys`` in a pseudo-terminal whose attributes the test can compare before and after."""

    def __init__(self, env: dict[str, str], *args: str) -> None:
        self.master, self.slave = os.openpty()
        # Unusual starting attributes, so that restoring means restoring these, not defaults.
        attributes = termios.tcgetattr(self.slave)
        attributes[3] &= ~termios.ECHOCTL
        attributes[6][termios.VERASE] = b'\x08'
        termios.tcsetattr(self.slave, termios.TCSANOW, attributes)
        self.initial = termios.tcgetattr(self.slave)
        self.process = subprocess.Popen(
            [KEYS, *args], stdin=self.slave, stdout=self.slave, stderr=self.slave, env=env,
            start_new_session=True)
        self.output = ''
        self._unread = 0

    def attributes(self) -> list:
        """Return the terminal's current attributes."""
        return termios.tcgetattr(self.slave)

    def press(self, keys: str) -> None:
        """Type ``keys`` (each write is one key press)."""
        for key in keys:
            os.write(self.master, key.encode())

    def _read(self, timeout: float) -> None:
        if select.select([self.master], [], [], timeout)[0]:
            self.output += os.read(self.master, 65536).decode(errors='replace')

    def expect(self, pattern: str | re.Pattern, timeout: float = MOVE_TIMEOUT) -> re.Match:
        """Wait for output matching ``pattern`` after the last match; return the match."""
        deadline = time.monotonic() + timeout
        while True:
            match = re.compile(pattern).search(self.output, self._unread)
            if match:
                self._unread = match.end()
                return match
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(f'no {pattern!r} from keys within {timeout} s; output:\n'
                                     + self.output[self._unread:])
            self._read(min(remaining, 0.1))

    def wait(self, timeout: float = 15.0) -> int:
        """Return the exit code, draining the output meanwhile."""
        deadline = time.monotonic() + timeout
        while self.process.poll() is None:
            if time.monotonic() > deadline:
                raise AssertionError(f'keys still running after {timeout} s:\n{self.output}')
            self._read(0.05)
        return self.process.returncode

    def hang_up(self) -> None:
        """Close the terminal's master side, as a terminal window or SSH session closing does."""
        os.close(self.master)
        self.master = None

    def close(self) -> None:
        """Kill ``keys`` if still running and release the terminal."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()
        if self.master is not None:
            os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def keys(ros_graph):
    terminal = KeysTerminal(ros_graph.env)
    try:
        terminal.expect(BANNER, timeout=30.0)
        yield terminal
    finally:
        terminal.close()


class ArmWatch:
    """The latest joint_states of the sim, by joint name."""

    def __init__(self, graph) -> None:
        self.positions: dict[str, float] = {}
        self.speeds: dict[str, float] = {}
        graph.node('arm_watch').create_subscription(
            JointState, 'joint_states', self._on_state, 10)

    def _on_state(self, msg: JointState) -> None:
        self.positions = dict(zip(msg.name, msg.position, strict=True))
        self.speeds = dict(zip(msg.name, msg.velocity, strict=True))

    def wait_near(self, joint: str, target: float, what: str) -> None:
        """Wait until ``joint`` is within TOLERANCE of ``target`` rad."""
        wait_for(lambda: abs(self.positions.get(joint, math.inf) - target) < TOLERANCE,
                 MOVE_TIMEOUT, f'{what} (now {self.positions.get(joint)}, want {target})')

    def wait_still(self) -> None:
        """Wait until the arm has joint states and no arm joint moves."""
        wait_for(lambda: self.speeds and all(
            abs(v) < 0.01 for name, v in self.speeds.items() if not name.startswith('rg2_')),
            MOVE_TIMEOUT, 'the arm at rest')

    def gripper(self) -> list[float]:
        """Return the gripper joint positions, by joint name order."""
        return [v for name, v in sorted(self.positions.items()) if name.startswith('rg2_')]

    def wait_gripper_away_from(self, positions: list[float], what: str) -> list[float]:
        """Wait until a gripper joint is more than 0.01 rad from ``positions``; return them."""
        def away():
            now = self.gripper()
            moved = max(abs(n - p) for n, p in zip(now, positions, strict=True)) > 0.01
            return moved and now
        return wait_for(away, MOVE_TIMEOUT, f'{what} (from {positions})')


def connect_jog(keys: KeysTerminal, arm: ArmWatch) -> None:
    """Press q until the sim moves: jogs sent before discovery completes are lost."""
    deadline = time.monotonic() + CONNECT_TIMEOUT
    while True:
        arm.wait_still()
        before = arm.positions['shoulder_pan_joint']
        keys.press('q')
        moving = time.monotonic() + 2.0
        while time.monotonic() < moving:
            if abs(arm.positions['shoulder_pan_joint'] - before) > math.radians(1.0):
                return
            time.sleep(0.01)
        assert time.monotonic() < deadline, f'the sim never moved on q:\n{keys.output}'


def expect_shown_pan(keys: KeysTerminal, degrees: float) -> None:
    """Wait until keys shows a pan angle of ``degrees`` (earlier lines may be older poses)."""
    deadline = time.monotonic() + MOVE_TIMEOUT
    while abs(float(keys.expect(ANGLES, deadline - time.monotonic()).group(1)) - degrees) > 1.0:
        pass


def call(keys: KeysTerminal, key: str, service: str) -> str:
    """Press ``key`` until ``service`` is available; return the result line's outcome."""
    deadline = time.monotonic() + CONNECT_TIMEOUT
    while True:
        keys.press(key)
        outcome = keys.expect(rf'{service}: (done|FAILED|call failed|service not available)'
                              '|not ready yet')
        if outcome.group(1) not in ('service not available', None):
            return outcome.group(1)
        assert time.monotonic() < deadline, f'{service} never became available'
        time.sleep(0.2)


def pick_stand_in(node: Node, picks: list, hold: threading.Event | None = None) -> None:
    """Serve ``pick_ball`` as the motion node would: one phase, held until ``hold`` is set.

    A cancel ends the held pick canceled; otherwise it succeeds, or fails after MOVE_TIMEOUT.
    """
    def execute(goal) -> PickBall.Result:
        picks.append(time.monotonic())
        goal.publish_feedback(PickBall.Feedback(phase='approaching', distance_to_go=0.52))
        deadline = time.monotonic() + MOVE_TIMEOUT
        while hold is not None and not (hold.wait(0.01) or goal.is_cancel_requested):
            if time.monotonic() > deadline:
                goal.abort()
                return PickBall.Result(message='the test never let the pick go on')
        if goal.is_cancel_requested:
            goal.canceled()
            return PickBall.Result(message="canceled by the action's client; the arm holds")
        goal.succeed()
        return PickBall.Result(success=True, message='picked the ball at (0.400, -0.300, -0.090) '
                                                     'm in base_link in 5.0 s')
    WorkerActionServer(node, PickBall, 'pick_ball', execute,
                       workers=ThreadPoolExecutor(2, thread_name_prefix='pick_stand_in'),
                       cancel_callback=lambda _goal: CancelResponse.ACCEPT)


def send_pick(keys: KeysTerminal) -> None:
    """Press g until the pick's first phase is shown (the action may not be discovered yet)."""
    deadline = time.monotonic() + CONNECT_TIMEOUT
    while True:
        keys.press('g')
        shown = keys.expect(r'/pick_ball \.\.\. (approaching), 0\.52 m to go'
                            r'|not ready yet|action not available')
        if shown.group(1):
            return
        assert time.monotonic() < deadline, 'pick_ball never became available'
        time.sleep(0.2)


def test_keys_drive_the_sim_and_p_quits_restoring_the_terminal(ros_graph, keys):
    ros_graph.add(SimNode(context=ros_graph.context, parameter_overrides=[
        Parameter('real_time_factor', value=1.0), Parameter('camera_rate', value=0.0)]))
    arm = ArmWatch(ros_graph)
    assert keys.attributes() != keys.initial, 'keys did not switch the terminal to raw mode'

    connect_jog(keys, arm)
    arm.wait_still()
    start = arm.positions['shoulder_pan_joint']
    keys.press('qqq')
    arm.wait_near('shoulder_pan_joint', start + math.radians(15.0), 'pan +15 deg')
    expect_shown_pan(keys, math.degrees(start) + 15.0)

    arm.wait_still()
    elbow = arm.positions['elbow_joint']
    keys.press('x')
    arm.wait_near('elbow_joint', elbow - math.radians(5.0), 'elbow -5 deg')

    # Joint states reach this process a little after the service answers: wait for them.
    opened = arm.gripper()
    assert call(keys, 't', '/gripper/close') == 'done'
    closed = arm.wait_gripper_away_from(opened, 'the gripper closing')
    assert call(keys, 'y', '/gripper/open') == 'done'
    arm.wait_gripper_away_from(closed, 'the gripper opening')

    assert call(keys, 'l', '/reset') == 'done'
    for joint in ('shoulder_pan_joint', 'elbow_joint'):
        arm.wait_near(joint, 0.0, f'{joint} home')
    expect_shown_pan(keys, 0.0)

    keys.press('p')
    assert keys.wait() == 0
    assert keys.attributes() == keys.initial


def test_arrow_key_is_one_unknown_key_not_a_jog(keys):
    keys.press('\x1b[A')
    keys.expect('Up has no function')
    keys.press('\x03')
    assert keys.wait() == 0
    assert 'nobody listens' not in keys.output, 'the arrow key jogged'


@pytest.mark.parametrize('key', ['\x03', 'P'])
def test_quit_keys_exit_0_restoring_the_terminal(keys, key):
    keys.press(key)
    assert keys.wait() == 0
    assert keys.attributes() == keys.initial


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_signals_exit_0_restoring_the_terminal(keys, signum):
    keys.process.send_signal(signum)
    assert keys.wait() == 0
    assert keys.attributes() == keys.initial


@pytest.mark.parametrize('value', ['90.0', 'fast'])
def test_bad_step_parameter_is_a_clear_error(ros_graph, value):
    terminal = KeysTerminal(ros_graph.env, '--ros-args', '-p', f'step_deg:={value}')
    try:
        assert terminal.wait() == 2
        assert re.search(r'^keys: .*step_deg', terminal.output, re.MULTILINE), terminal.output
        assert 'Traceback' not in terminal.output
        assert terminal.attributes() == terminal.initial
    finally:
        terminal.close()


def test_closed_terminal_ends_keys_cleanly(keys):
    keys.hang_up()
    assert keys.process.wait(timeout=15.0) == 0


def test_without_a_terminal_keys_exits_at_once_non_zero(ros_graph):
    started = time.monotonic()
    result = subprocess.run([KEYS], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                            env=ros_graph.env, timeout=30.0)
    assert result.returncode != 0
    assert 'not a terminal' in result.stderr
    assert time.monotonic() - started < 10.0


def test_m_switches_to_tool_mode_and_g_picks(ros_graph, keys):
    """m: the jog keys send tool_jog steps (and back); g picks, its phase and outcome shown.

    k cancels the pick under way.
    """
    node = ros_graph.node('motion_stand_in')
    jogs: list[TransformStamped] = []
    node.create_subscription(TransformStamped, 'tool_jog', jogs.append, 10)
    picks = []
    hold = threading.Event()
    pick_stand_in(node, picks, hold)
    keys.press('m')
    keys.expect(r'tool mode: q/w a/s z/x move the TCP \+/- 10 mm along base_link x/y/z')
    keys.press('h')
    keys.expect(r'teleop, tool mode')
    # Jogs sent before discovery completes are lost: press until one arrives.
    deadline = time.monotonic() + CONNECT_TIMEOUT
    while not jogs:
        assert time.monotonic() < deadline, f'no tool_jog on z:\n{keys.output}'
        keys.press('z')
        pressed = time.monotonic()
        while not jogs and time.monotonic() - pressed < 2.0:
            time.sleep(0.01)
    assert jogs[-1].transform.translation.z == pytest.approx(0.01)
    jogs.clear()
    keys.press('c')
    wait_for(lambda: jogs, MOVE_TIMEOUT, 'the tool_jog of c')
    step = jogs[-1]
    assert step.header.frame_id == 'base_link'
    assert (step.transform.translation.x, step.transform.translation.z) == (0.0, 0.0)
    assert step.transform.rotation.z == pytest.approx(math.sin(math.radians(5.0) / 2))
    keys.press('m')
    keys.expect(r'joint mode')
    send_pick(keys)
    hold.set()
    keys.expect(r'/pick_ball: done: picked the ball at \(0\.400, -0\.300, -0\.090\) m in '
                'base_link')
    hold.clear()
    send_pick(keys)
    keys.press('g')  # while one runs
    keys.expect(r'/pick_ball: a pick is running \(k cancels it\)')
    keys.press('k')
    keys.expect(r"/pick_ball: canceled: canceled by the action's client; the arm holds")
    keys.press('k')
    keys.expect(r'/pick_ball: no pick running \(g starts one\)')
    assert len(picks) == 2
    keys.press('p')
    assert keys.wait() == 0


def test_keys_wait_for_the_graph_refusing_its_keys_until_it_is_up(ros_graph, keys):
    """The screen names what is missing; g at once is refused with why, a later g picks."""
    keys.expect(r'starting: waiting for sim, vision, motion')
    keys.press('g')
    keys.expect(r'not ready yet: waiting for motion')
    keys.press('h')  # keys that need no node work meanwhile
    keys.expect(BANNER)

    graph = ros_graph.node('graph_stand_in')
    picks = []

    def serve(name, _request, response):
        response.success, response.message = True, f'{name} stand-in'
        return response

    for name in ('gripper/close', 'gripper/open', 'reset', 'vision/save_frame'):
        graph.create_service(Trigger, name, lambda req, resp, name=name: serve(name, req, resp))
    pick_stand_in(graph, picks)
    graph.create_subscription(JointState, 'joint_jog', lambda _m: None, 10)
    graph.create_subscription(TransformStamped, 'tool_jog', lambda _m: None, 10)
    keys.expect(r'(?m)^ready\r?$', timeout=CONNECT_TIMEOUT)
    keys.press('g')
    keys.expect(r'/pick_ball: done: picked the ball')
    assert len(picks) == 1
    assert 'service not available' not in keys.output
    keys.press('p')
    assert keys.wait() == 0
