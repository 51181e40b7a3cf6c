"""Run a set of processes as one unit, the way a launch file does: start, watch, stop them all.

Every background process gets its own session: its own process group and no controlling
terminal. Terminal signals (Ctrl-C, a closed terminal) therefore reach only the supervisor
and the one foreground process, so the supervisor alone decides how the rest stop, and a whole
group (a node and anything it spawned) can be signalled at once. The foreground process stays
in the supervisor's process group so that it can read the terminal.

Stopping escalates: SIGTERM, then SIGKILL after a deadline. A running ROS node (rclpy,
rclcpp) shuts down on SIGTERM exactly as on SIGINT, but a Python node that is still importing
would turn SIGINT into a KeyboardInterrupt traceback, which SIGTERM does not. A second stop
signal while stopping skips to SIGKILL at once. Should the supervisor itself be killed
outright, the kernel sends its children SIGTERM (``PR_SET_PDEATHSIG``), so no node outlives it.

The output of background processes passes through the supervisor, which copies it to its own
standard output and error as it comes and remembers each process's last ERROR/FATAL log line:
when a process dies, the closing summary repeats why, below everything the others printed
while they stopped. Where the supervisor's output is a terminal the process writes to a
pseudo-terminal, so it buffers and colours its output exactly as on the terminal itself.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import ctypes
from dataclasses import dataclass
import os
import pty
import re
import signal
import subprocess
import sys
import threading
import time
import tty

# How often the supervisor looks at its children; bounds how late it notices a death.
POLL_INTERVAL_S = 0.05

# Signals that ask the supervisor to stop everything: Ctrl-C, a service manager, a closed
# terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

# (signal, seconds to wait for the process to exit after it) in order. The nodes promise a
# clean exit within 2 s of SIGINT/SIGTERM; the margin covers a loaded machine.
DEFAULT_ESCALATION: tuple[tuple[signal.Signals, float], ...] = (
    (signal.SIGTERM, 5.0),
    (signal.SIGKILL, 2.0),
)

_PR_SET_PDEATHSIG = 1

# An error in a ROS log line, as rcutils prints it ("[ERROR] [stamp] [node]: ...") and
# whatever the output format, once colour codes are removed.
_ERROR_LINE = re.compile(r'\[(ERROR|FATAL)\]')
_COLOR_CODE = re.compile(rb'\x1b\[[0-9;]*m')
_MAX_LINE = 64 * 1024  # a longer "line" is not a log line: forget it rather than grow
# How long a dead process's last output may take to arrive before the summary is printed.
_OUTPUT_DRAIN_S = 1.0


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the graph.

    ``foreground``: the process shares the supervisor's terminal (standard input, Ctrl-C) and
    its exiting with code 0 is a normal way to end the whole graph (the user quit). Background
    processes get no standard input.
    """

    name: str
    argv: Sequence[str]
    foreground: bool = False


def describe_exit(returncode: int) -> str:
    """Say how a process ended, from a ``Popen.returncode``."""
    if returncode >= 0:
        return f'exited with code {returncode}'
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        name = 'unknown signal'
    return f'was killed by signal {-returncode} ({name})'


def _log(message: str) -> None:
    print(f'bringup: {message}', file=sys.stderr, flush=True)


def _die_with(parent_pid: int) -> Callable[[], None] | None:
    """Return a pre-exec hook that makes the child get SIGTERM when ``parent_pid`` dies."""
    if not sys.platform.startswith('linux'):
        return None
    libc = ctypes.CDLL(None, use_errno=True)

    def hook() -> None:
        libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGTERM))
        if os.getppid() != parent_pid:  # the parent died before the request took effect
            os._exit(1)

    return hook


class _Output:
    """Copies what a process writes to one of our file descriptors, watching for errors."""

    def __init__(self, target_fd: int) -> None:
        self.target_fd = target_fd
        self.read_fd, self.write_fd = _terminal() if os.isatty(target_fd) else os.pipe()
        self.last_error: str | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Close our copy of the writing end (the process has its own) and start copying."""
        os.close(self.write_fd)
        self._thread = threading.Thread(target=self._copy, daemon=True)
        self._thread.start()

    def join(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for the output to end (the process and its children gone)."""
        if self._thread is not None:
            self._thread.join(timeout)

    def _copy(self) -> None:
        pending = b''
        writable = True
        while True:
            try:
                chunk = os.read(self.read_fd, 65536)
            except OSError:  # EIO: a pseudo-terminal whose other end is closed
                chunk = b''
            if not chunk:
                break
            if writable:
                writable = _write_all(self.target_fd, chunk)
            # Read on even when our output is gone: a process must never block on a full pipe.
            *lines, pending = (pending + chunk).split(b'\n')
            pending = pending[-_MAX_LINE:]
            self._watch(lines)
        self._watch([pending])
        os.close(self.read_fd)

    def _watch(self, lines: list[bytes]) -> None:
        for raw in lines:
            line = _COLOR_CODE.sub(b'', raw).decode(errors='replace').strip()
            if _ERROR_LINE.search(line):
                self.last_error = line


def _terminal() -> tuple[int, int]:
    """Return (reading, writing) ends of a new pseudo-terminal, or of a pipe if there is none."""
    try:
        reader, writer = pty.openpty()
    except OSError:  # all in use: the output still passes, only as through a pipe
        return os.pipe()
    tty.setraw(writer)  # bytes through unchanged: no newline translation
    return reader, writer


def _write_all(fd: int, data: bytes) -> bool:
    """Write ``data`` to ``fd``; False once ``fd`` cannot be written any more."""
    try:
        while data:
            data = data[os.write(fd, data):]
    except OSError:
        return False
    return True


class _Child:
    """A started process, how to signal it, and its output."""

    def __init__(self, spec: ProcessSpec, env: dict[str, str] | None) -> None:
        self.spec = spec
        self.name = spec.name
        # The foreground process keeps the terminal to itself, as with no supervisor.
        self.outputs = [] if spec.foreground else [_Output(1), _Output(2)]
        try:
            self.popen = subprocess.Popen(
                list(spec.argv),
                stdin=None if spec.foreground else subprocess.DEVNULL,
                stdout=self.outputs[0].write_fd if self.outputs else None,
                stderr=self.outputs[1].write_fd if self.outputs else None,
                env=env if spec.foreground else _captured_env(env),
                start_new_session=not spec.foreground,
                preexec_fn=_die_with(os.getpid()),
            )
        except OSError:
            for output in self.outputs:
                os.close(output.read_fd)
                os.close(output.write_fd)
            raise
        self.pid = self.popen.pid

    def start_copying(self) -> None:
        """Start passing the process's output on."""
        for output in self.outputs:
            output.start()

    def wait_output(self, deadline: float) -> None:
        """Wait until the output has ended or ``deadline`` (``time.monotonic``) has passed."""
        for output in self.outputs:
            output.join(max(0.0, deadline - time.monotonic()))

    @property
    def last_error(self) -> str | None:
        """The last ERROR/FATAL line the process wrote, if any."""
        errors = [output.last_error for output in self.outputs if output.last_error]
        return errors[-1] if errors else None

    def running(self) -> bool:
        return self.popen.poll() is None

    def send(self, sig: signal.Signals) -> None:
        """Signal the process (a background one: its whole process group)."""
        try:
            if self.spec.foreground:
                self.popen.send_signal(sig)  # a no-op once it has been reaped
            elif self.running():
                os.killpg(self.pid, sig)
        except ProcessLookupError:
            pass

    def kill_leftovers(self) -> bool:
        """SIGKILL whatever is left in a background process's group; True if anything was."""
        if self.spec.foreground:
            return False
        try:
            os.killpg(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            return False
        return True


def _captured_env(env: dict[str, str] | None) -> dict[str, str]:
    """Return the environment of a process whose output passes through the supervisor."""
    env = dict(os.environ if env is None else env)
    # Written line by line as on a terminal, not held back in a pipe's block buffer: Python's
    # own output, and ROS log lines (rcutils: 1 is line buffered).
    env.setdefault('PYTHONUNBUFFERED', '1')
    env.setdefault('RCUTILS_LOGGING_BUFFERED_STREAM', '1')
    return env


class Supervisor:
    """Start processes, stop all of them when one ends or a stop signal arrives."""

    def __init__(self, specs: Sequence[ProcessSpec], env: dict[str, str] | None = None,
                 escalation: Sequence[tuple[signal.Signals, float]] = DEFAULT_ESCALATION,
                 on_started: Callable[[], None] | None = None,
                 on_stopping: Callable[[], None] | None = None) -> None:
        """Prepare to run ``specs``.

        ``on_started`` is called once all have been started, ``on_stopping`` when the
        supervisor begins to stop them.
        """
        if sum(spec.foreground for spec in specs) > 1:
            raise ValueError('at most one process can have the terminal')
        self._specs = list(specs)
        self._env = env
        self._escalation = list(escalation)
        self._children: list[_Child] = []
        self._signals: list[int] = []
        self._on_started = on_started
        self._on_stopping = on_stopping

    def run(self) -> int:
        """Run until the graph ends; return 0 for a requested stop, 1 for a failure."""
        previous = {sig: signal.signal(sig, self._on_signal) for sig in STOP_SIGNALS}
        try:
            return self._run()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)

    def _on_signal(self, signum: int, _frame: object) -> None:
        self._signals.append(signum)

    def _run(self) -> int:
        for spec in self._specs:
            try:
                self._children.append(_Child(spec, self._env))
            except OSError as exc:
                for child in self._children:
                    child.start_copying()
                _log(f'cannot start {spec.name} ({spec.argv[0]}): {exc.strerror or exc}'
                     + self._stopping())
                self._stop_all()
                return 1
        # Only now: a process started while copying threads run would fork a threaded process.
        for child in self._children:
            child.start_copying()
        _log('started ' + ', '.join(f'{c.name} (pid {c.pid})' for c in self._children))
        if self._on_started is not None:
            self._on_started()
        while True:
            if self._signals:
                trigger = self._signals[0]
                _log(f'{signal.Signals(trigger).name} received' + self._stopping())
                self._stop_all()
                return 0
            for child in self._children:
                code = child.popen.poll()
                if code is None:
                    continue
                # The user quitting the foreground process (p, Ctrl-C) ends the graph normally.
                if child.spec.foreground and code == 0:
                    _log(f'{child.name} exited' + self._stopping())
                    self._stop_all()
                    return 0
                _log(f'{child.name} {describe_exit(code)}' + self._stopping())
                self._stop_all()
                # Why it died, again: its own line has scrolled away above the others' output.
                if child.last_error is not None:
                    _log(f'{child.name} {describe_exit(code)}: {child.last_error}')
                return 1
            time.sleep(POLL_INTERVAL_S)

    def _stopping(self) -> str:
        names = ', '.join(c.name for c in self._children if c.running())
        return f': stopping {names}' if names else ''

    def _stop_all(self) -> None:
        if self._on_stopping is not None:
            self._on_stopping()
        previous: signal.Signals | None = None
        for sig, timeout in self._escalation:
            alive = [c for c in self._children if c.running()]
            if not alive:
                break
            if previous is not None:
                names = ', '.join(c.name for c in alive)
                _log(f'{names} still running after {previous.name}: sending {sig.name}')
            for child in alive:
                child.send(sig)
            signals_seen = len(self._signals)
            deadline = time.monotonic() + timeout
            while (any(c.running() for c in alive) and time.monotonic() < deadline
                   and len(self._signals) == signals_seen):
                time.sleep(POLL_INTERVAL_S)
            previous = sig
        stuck = [c for c in self._children if c.running()]
        for child in self._children:
            if child in stuck:
                _log(f'{child.name} (pid {child.pid}) could not be stopped')
            elif child.kill_leftovers():
                _log(f'killed processes left behind in the process group of {child.name}')
        # Their last words (and the last error lines) before ours.
        deadline = time.monotonic() + _OUTPUT_DRAIN_S
        for child in self._children:
            child.wait_output(deadline)
        if self._children and not stuck:
            _log('all stopped')
