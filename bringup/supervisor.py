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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import ctypes
from dataclasses import dataclass
import os
import signal
import subprocess
import sys
import time

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


class _Child:
    """A started process and how to signal it."""

    def __init__(self, spec: ProcessSpec, env: dict[str, str] | None) -> None:
        self.spec = spec
        self.name = spec.name
        self.popen = subprocess.Popen(
            list(spec.argv),
            stdin=None if spec.foreground else subprocess.DEVNULL,
            env=env,
            start_new_session=not spec.foreground,
            preexec_fn=_die_with(os.getpid()),
        )
        self.pid = self.popen.pid

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


class Supervisor:
    """Start processes, stop all of them when one ends or a stop signal arrives."""

    def __init__(self, specs: Sequence[ProcessSpec], env: dict[str, str] | None = None,
                 escalation: Sequence[tuple[signal.Signals, float]] = DEFAULT_ESCALATION,
                 ) -> None:
        if sum(spec.foreground for spec in specs) > 1:
            raise ValueError('at most one process can have the terminal')
        self._specs = list(specs)
        self._env = env
        self._escalation = list(escalation)
        self._children: list[_Child] = []
        self._signals: list[int] = []

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
                _log(f'cannot start {spec.name} ({spec.argv[0]}): {exc.strerror or exc}'
                     + self._stopping())
                self._stop_all()
                return 1
        _log('started ' + ', '.join(f'{c.name} (pid {c.pid})' for c in self._children))
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
                return 1
            time.sleep(POLL_INTERVAL_S)

    def _stopping(self) -> str:
        names = ', '.join(c.name for c in self._children if c.running())
        return f': stopping {names}' if names else ''

    def _stop_all(self) -> None:
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
        if self._children and not stuck:
            _log('all stopped')
