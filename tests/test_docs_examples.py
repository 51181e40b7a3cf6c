"""The docs' example programs: the listener run as a user runs it, against a running sim."""

import math
import os
from pathlib import Path
import re
import select
import signal
import subprocess
import sys
import time

from conftest import start_sim
from sensor_msgs.msg import JointState

ROOT = Path(__file__).parents[1]
LISTENER = ROOT / 'docs' / 'examples' / 'joint_listener.py'
TOOL_COMMAND = ROOT / 'docs' / 'examples' / 'tool_command.py'
PAN = re.compile(r'^shoulder_pan +([+-]\d+\.\d) .*wrist_3 +[+-]\d+\.\d$')


class Lines:
    """A process's standard output, line by line."""

    def __init__(self, process: subprocess.Popen) -> None:
        self._process = process
        self._buffer = b''
        self.lines: list[str] = []

    def next(self, timeout: float) -> str:
        """Return the next line; fail after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while b'\n' not in self._buffer:
            remaining = deadline - time.monotonic()
            assert remaining > 0, f'no line within {timeout} s: {self.lines}'
            if select.select([self._process.stdout], [], [], min(remaining, 0.2))[0]:
                chunk = os.read(self._process.stdout.fileno(), 4096)
                assert chunk, f'the listener exited: {self._process.stderr.read()!r}'
                self._buffer += chunk
        line, self._buffer = self._buffer.split(b'\n', 1)
        self.lines.append(line.decode())
        return self.lines[-1]


def test_listener_prints_degrees_twice_a_second_and_ends_cleanly_on_ctrl_c(ros_graph):
    start_sim(ros_graph, camera_rate=0.0)
    commander = ros_graph.node('commander').create_publisher(JointState, 'joint_command', 10)
    target = JointState(name=['shoulder_pan_joint'], position=[math.radians(30.0)])
    listener = subprocess.Popen([sys.executable, str(LISTENER)], env=ros_graph.env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        lines = Lines(listener)
        deadline = time.monotonic() + 60.0
        while True:  # the command is repeated: the first may go out before discovery
            commander.publish(target)
            match = PAN.match(lines.next(timeout=30.0))
            assert match, lines.lines[-1]
            if abs(float(match.group(1)) - 30.0) <= 0.2:
                break
            assert time.monotonic() < deadline, f'the pan never showed 30 degrees: {lines.lines}'
        started = time.monotonic()
        shown = [lines.next(timeout=10.0) for _ in range(4)]
        took = time.monotonic() - started
        assert all(PAN.match(line) for line in shown), shown
        assert 1.2 < took < 6.0, f'4 lines in {took:.2f} s: not about two a second'
    finally:
        listener.send_signal(signal.SIGINT)
        out, err = listener.communicate(timeout=15)
    assert listener.returncode == 0, err.decode()
    assert 'Traceback' not in (out + err).decode()


def test_docs_show_the_listener_example_as_it_is():
    page = (ROOT / 'docs' / 'running.md').read_text()
    assert f'```python\n{LISTENER.read_text()}```\n' in page


def test_docs_show_the_tool_command_example_as_it_is():
    page = (ROOT / 'docs' / 'cartesian-and-pick.md').read_text()
    assert f'```python\n{TOOL_COMMAND.read_text()}```\n' in page
