"""The docs' code, run as a user runs it: every runnable block of every page, against a graph.

Every ``python``, ``sh`` and ``bash`` block of README.md and docs/*.md is run here, page by
page, each page with one graph of its own (``ros2 launch ur_rg2_bringup graph.launch.py`` on
a domain of its own); or the page marks the block, on the line
before it, with ``<!-- docs test: not run, REASON -->``, REASON one of ``MARKS``.

A shell block runs command by command, as typed in a terminal where ``source scripts/env.sh``
was done: a command that ends by itself has to exit 0; one that runs until Ctrl-C (a launch,
a node, ``ros2 topic echo``) has to show that it works (``READY``), then stop cleanly on
SIGINT. Three things differ from a user's terminal: ``scripts/run`` is the command it runs once
the set-up is done (``python -m ur_rg2_bringup.run``: the suite's own set-up has run), a
viewer port is ``port:=0`` (any free port), so that a graph of the test never meets another
one's, and the page's graph draws its camera at 10 Hz (the suite runs beside other tests).
Where a page shows what a command prints, the output is checked for that shape.
"""

from dataclasses import dataclass
import math
import os
from pathlib import Path
import re
import select
import shlex
import signal
import subprocess
import sys
import tempfile
import time

from conftest import next_domain_id, start_sim
import pytest
from sensor_msgs.msg import JointState

ROOT = Path(__file__).parents[1]
PAGES = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md'))]
LISTENER = ROOT / 'docs' / 'examples' / 'joint_listener.py'
TOOL_COMMAND = ROOT / 'docs' / 'examples' / 'tool_command.py'
PAN = re.compile(r'^shoulder_pan +([+-]\d+\.\d) .*wrist_3 +[+-]\d+\.\d$')

RUNNABLE = ('python', 'sh', 'bash')
# Why a block may stay unrun; the page says which, and what it needs, after the reason.
MARKS = ('needs a display', 'needs a robot', 'long training', 'a long run', 'needs a ROS install',
         'needs Docker', 'the set-up itself')
_MARK = re.compile(r'^<!-- docs test: not run, (.+?) -->$')
_FENCE = re.compile(r'^```(\S*)\s*$')
# What runs beside a page's graph, for the page's blocks that talk to it.
BESIDE_GRAPH = {'docs/learning.md': ('policy',)}
# Commands that run until Ctrl-C, and the output that shows each works (any line for the rest).
_GRAPH = re.compile(r'^(ros2 launch ur_rg2_bringup graph\.launch\.py|'
                    r'python -m ur_rg2_bringup\.run)(?!.*--(show-args|help))')
_STREAMING = re.compile(r'^(ros2 (run|topic echo(?!.*--once)|topic hz)|policy|vision|sim)\b')
# ros2 run's commands that are no nodes, and end by themselves.
_ENDS_BY_ITSELF = re.compile(r'^ros2 run ur_rg2_tools (recover|info)\b|\s--help\b')
_SIM = re.compile(r'^(ros2 run ur_rg2_sim sim|sim)\b')
READY = ((_GRAPH, r'ur_rg2_sim\]: simulating'),
         (_SIM, r'ur_rg2_sim\]: simulating'),
         (re.compile(r'^ros2 topic echo'), r'^---$'),
         (re.compile(r'^ros2 topic hz'), r'average rate'),
         (re.compile(r'^ros2 run ur_rg2_teleop keys'), r'p, Ctrl-C +quit'),
         (re.compile(r'^(ros2 run ur_rg2_learning )?policy\b'), r'policy/run'))
_GRAPH_READY = (r'ur_rg2_sim\]: simulating', r'ur_rg2_motion\]: ready',
                r'ur_rg2_vision\]: looking for the ball', r'ur_rg2_viewer\]: live view')
GRAPH_NODES = ('ur_rg2_sim', 'ur_rg2_vision', 'ur_rg2_motion', 'ur_rg2_viewer')
PAGE_GRAPH = 'camera_rate:=10.0'  # the launch arguments of each page's own graph
START_TIMEOUT = 90.0  # s: a graph or a node coming up on a loaded machine
RUN_TIMEOUT = 120.0  # s: a command that ends by itself
STOP_TIMEOUT = 60.0  # s: Ctrl-C to exit


@dataclass(frozen=True)
class Block:
    """A fenced code block of a page."""

    page: str
    line: int
    language: str
    code: str
    mark: str | None

    def __str__(self) -> str:
        return f'{self.page}:{self.line}'


def blocks(path: Path) -> list[Block]:
    """Return the page's fenced blocks, each with the mark on the line before it, if any."""
    found, lines = [], path.read_text().splitlines()
    start = None
    for number, line in enumerate(lines):
        match = _FENCE.match(line)
        if not match:
            continue
        if start is None:
            start, language = number, match.group(1)
            continue
        mark = _MARK.match(lines[start - 1].strip()) if start else None
        found.append(Block(str(path.relative_to(ROOT)), start + 1, language,
                           '\n'.join(lines[start + 1:number]) + '\n',
                           mark.group(1) if mark else None))
        start = None
    return found


def commands(code: str) -> list[str]:
    """Return a shell block's commands: continuation lines joined, comments left out."""
    joined = re.sub(r'\s*\\\n\s*', ' ', code)
    found = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        if words:
            found.append(line.split(' #')[0].strip() if ' #' in line else line.strip())
    return found


def as_run(command: str) -> str:
    """Return the command as the test runs it: scripts/run after its set-up, any free port."""
    command = re.sub(r'^scripts/run\b', 'python -m ur_rg2_bringup.run', command)
    command = re.sub(r'\bport:=\d+', 'port:=0', command)
    if _GRAPH.match(command) and 'port:=' not in command:
        head, _, rest = command.partition('.py' if command.startswith('ros2') else '.run')
        command = f'{head}{_}{" port:=0"}{rest}'
    return command


class Process:
    """A command run from bash, its output (stdout and stderr, or a pseudo-terminal) collected."""

    def __init__(self, command: str, env: dict[str, str], terminal: bool = False) -> None:
        self.command = command
        self.output = ''
        if terminal:
            self._read_fd, slave = os.openpty()
            streams = {'stdin': slave, 'stdout': slave, 'stderr': slave}
        else:
            streams = {'stdin': subprocess.DEVNULL, 'stdout': subprocess.PIPE,
                       'stderr': subprocess.STDOUT}
        self.process = subprocess.Popen(['bash', '-c', command], cwd=ROOT, env=env,
                                        start_new_session=True, **streams)
        if terminal:
            os.close(slave)
        else:
            self._read_fd = self.process.stdout.fileno()

    def read(self, timeout: float) -> bool:
        """Collect what came within ``timeout`` s; False once the output has ended."""
        if select.select([self._read_fd], [], [], timeout)[0]:
            try:
                chunk = os.read(self._read_fd, 65536)
            except OSError:  # a pseudo-terminal whose last writer exited
                chunk = b''
            self.output += chunk.decode(errors='replace')
            return bool(chunk)
        return True

    def wait_for(self, patterns, timeout: float, may_end: bool = False) -> None:
        """Read until every regex of ``patterns`` matched a line; fail if it exits first.

        With ``may_end``, an end of the command is fine too (the caller checks its exit code).
        """
        deadline = time.monotonic() + timeout
        while not all(re.search(p, self.output, re.MULTILINE) for p in patterns):
            if may_end and self.process.poll() is not None:
                return
            assert self.process.poll() is None, f'{self.command!r} exited ' \
                f'{self.process.returncode} before it was ready:\n{self.output[-3000:]}'
            assert time.monotonic() < deadline, f'{self.command!r} not ready within ' \
                f'{timeout:.0f} s (waiting for {patterns}):\n{self.output[-3000:]}'
            self.read(0.2)

    def finish(self, timeout: float) -> int:
        """Read to the end of the output and the process; return its exit code."""
        deadline = time.monotonic() + timeout
        while self.process.poll() is None or self.read(0.05):
            assert time.monotonic() < deadline, \
                f'{self.command!r} still running after {timeout:.0f} s:\n{self.output[-3000:]}'
            self.read(0.2)
        return self.process.returncode

    def interrupt(self) -> int:
        """Ctrl-C, as a terminal sends it: SIGINT to the process group; return the exit code."""
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGINT)
        return self.finish(STOP_TIMEOUT)

    def kill(self) -> None:
        """Make sure nothing of the command is left (after a failure)."""
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=10)
        if self.process.stdout is None:
            os.close(self._read_fd)


def stopped_cleanly(process: Process) -> None:
    """Ctrl-C ends ``process`` with exit 0 and no traceback.

    Or 130, bash's own exit on Ctrl-C; or 2 from a ``ros2`` verb: ros2cli exits with the
    signal's number on a KeyboardInterrupt (``ros2 topic echo`` and the like).
    """
    code = process.interrupt()
    ros2cli = (signal.SIGINT,) if process.command.startswith('ros2 ') else ()
    assert code in (0, 130, -signal.SIGINT, *ros2cli), \
        f'{process.command!r} exited {code} on Ctrl-C:\n{process.output[-3000:]}'
    assert 'Traceback' not in process.output, process.output[-3000:]


def shape(example: str) -> str:
    """Return a regex for output like ``example``: the text, any numbers in its numbers' places."""
    return re.sub(r'\\-?\d+(\\\.\d+)?|-?\d+(\\\.\d+)?', r'-?\\d+(\\.\\d+)?',
                  re.escape(' '.join(example.split())))


def pick_example(page: str) -> str:
    """Return the pick outcome the page shows keys print: ``picked the ball at (...) ... mm)``."""
    text = ' '.join((ROOT / page).read_text().split())
    return re.search(r'`/pick_ball: done: (picked the ball at .*? mm\))`', text).group(1)


# What a command or block prints, where the page shows it: the block's (or command's) text,
# and regexes its output must match.
def expected(block: Block, text: str) -> list[str]:
    """Return the regexes ``text`` (a command or a Python block) of ``block`` must print."""
    if text.startswith('ros2 service call /pick_ball'):
        return [shape(pick_example(block.page))]
    if block.page == 'docs/from-v-rep.md' and 'GripperCommand' in text:
        return [r'^0 reached the last point within goal_tolerance after \d+\.\d{3} s$',
                shape('0.000 False True')]
    if block.page == 'docs/from-v-rep.md':
        return [shape('closed: nothing grasped (0.0 mm)')]
    if block.page == 'docs/learning.md' and 'policy/run' in text:
        return [shape('episode started: ball top at (0.400, -0.300, -0.140) m in base_link')]
    if text.startswith('evaluate_policy'):
        return [shape('success rate 1.00 over 10 episodes')]
    return []


def page_blocks(page: Path) -> list[Block]:
    return [block for block in blocks(page) if block.language in RUNNABLE]


def test_every_runnable_block_is_run_here_or_marked_with_a_known_reason():
    unknown = [f'{block}: {block.mark!r}' for page in PAGES for block in page_blocks(page)
               if block.mark and not block.mark.startswith(MARKS)]
    assert not unknown, f'marks with no known reason ({MARKS}):\n' + '\n'.join(unknown)


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


def run_command(block: Block, command: str, env: dict[str, str]) -> None:
    """Run one shell command of ``block`` as the test runs it; check how it ends."""
    command = as_run(command)
    if command == 'source scripts/env.sh':
        return  # the test's environment is that shell's
    if _GRAPH.match(command) or _SIM.match(command):
        env = dict(env, ROS_DOMAIN_ID=str(next_domain_id()))  # beside the page's graph, alone
    ready = next((pattern for match, pattern in READY if match.match(command)), r'\S')
    keys = command.startswith('ros2 run ur_rg2_teleop keys')
    process = Process(command, env, terminal=keys)
    streaming = (_GRAPH.match(command) or _STREAMING.match(command)) and not (
        _ENDS_BY_ITSELF.search(command))
    try:
        if streaming:  # until it is ready, or ends (then it has to end well)
            process.wait_for([ready], START_TIMEOUT, may_end=True)
        if streaming and process.process.poll() is None:
            stopped_cleanly(process)
        else:
            code = process.finish(RUN_TIMEOUT)
            assert code == 0, f'{block}: {command!r} exited {code}:\n{process.output[-3000:]}'
        for pattern in expected(block, command):
            assert re.search(pattern, process.output, re.MULTILINE), \
                f'{block}: {command!r} printed no line like {pattern!r}:\n{process.output}'
    finally:
        process.kill()


def run_python(block: Block, env: dict[str, str]) -> None:
    """Run a Python block as a script; one that runs until Ctrl-C has to print, then stop."""
    with tempfile.NamedTemporaryFile('w', suffix='.py') as script:
        script.write(block.code)
        script.flush()
        process = Process(f'{sys.executable} {script.name}', env)
        try:
            if 'while rclpy.ok()' in block.code or 'rclpy.spin(' in block.code:
                process.wait_for([r'\S'], START_TIMEOUT)
                stopped_cleanly(process)
            else:
                code = process.finish(RUN_TIMEOUT)
                assert code == 0, f'{block} exited {code}:\n{process.output[-3000:]}'
            for pattern in expected(block, block.code):
                assert re.search(pattern, process.output, re.MULTILINE), \
                    f'{block} printed no line like {pattern!r}:\n{process.output}'
        finally:
            process.kill()


def daemon_sees_the_graph(env: dict[str, str]) -> None:
    """Start the ros2 daemon and wait until it lists the graph's nodes and joint_states.

    A user types the page's commands into a shell whose daemon has watched the graph for a
    while; a daemon started by the first command may not have discovered it yet
    (docs/troubleshooting.md, python -m bench discovery).
    """
    subprocess.run(['ros2', 'daemon', 'start'], env=env, capture_output=True,
                   timeout=RUN_TIMEOUT, check=False)
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        nodes, topics = (subprocess.run(['ros2', verb, 'list'], env=env, capture_output=True,
                                        text=True, timeout=RUN_TIMEOUT,
                                        check=False).stdout.split()
                         for verb in ('node', 'topic'))
        if '/joint_states' in topics and {f'/{name}' for name in GRAPH_NODES} <= set(nodes):
            return
        assert time.monotonic() < deadline, f'the ros2 daemon saw {nodes} and {topics}'
        time.sleep(0.5)


@pytest.mark.parametrize('page', [page for page in PAGES if any(
    not block.mark for block in page_blocks(page))], ids=lambda page: page.name)
def test_the_page_s_blocks_run_as_shown(page):
    name = str(page.relative_to(ROOT))
    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    background = []
    try:
        graph = Process(f'ros2 launch ur_rg2_bringup graph.launch.py port:=0 {PAGE_GRAPH}', env)
        background.append(graph)
        graph.wait_for(_GRAPH_READY, START_TIMEOUT)
        for command in BESIDE_GRAPH.get(name, ()):
            background.append(Process(command, env))
            background[-1].wait_for([r'policy/run'], START_TIMEOUT)
        daemon_sees_the_graph(env)
        for block in page_blocks(page):
            if block.mark:
                continue
            if block.language == 'python':
                run_python(block, env)
            else:
                for command in commands(block.code):
                    run_command(block, command, env)
        for process in reversed(background):
            stopped_cleanly(process)
    finally:
        for process in background:
            process.kill()
        subprocess.run(['ros2', 'daemon', 'stop'], env=env, capture_output=True,
                       timeout=RUN_TIMEOUT, check=False)


def test_the_helpers_read_blocks_and_commands_as_a_shell_does():
    assert commands('source scripts/env.sh\nros2 a \\\n  b   # c\n# d\n\nx "#y" # z\n') == [
        'source scripts/env.sh', 'ros2 a b', 'x "#y"']
    assert as_run('scripts/run --headless port:=8081 --ros-args -r __ns:=/a') == (
        'python -m ur_rg2_bringup.run --headless port:=0 --ros-args -r __ns:=/a')
    assert as_run('scripts/run robot_model:=ur3') == (
        'python -m ur_rg2_bringup.run port:=0 robot_model:=ur3')
    assert as_run('ros2 launch ur_rg2_bringup graph.launch.py camera_rate:=15.0') == (
        'ros2 launch ur_rg2_bringup graph.launch.py port:=0 camera_rate:=15.0')
    assert as_run('scripts/run --help') == 'python -m ur_rg2_bringup.run --help'
    example = 'done: picked the ball at (0.400, -0.300, -0.170) m in base_link in 4.5 s'
    assert re.fullmatch(shape(example), example.replace('4.5', '12.25').replace('-0.3', '0.3'))
    assert not re.fullmatch(shape(example), example.replace('base_link', 'world'))


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
