"""``ros2 run ur_rg2_bringup graph`` (``scripts/run``): graph.launch.py, keys in this terminal.

The launch file does the work of a launch file: it starts, watches and stops the nodes. What is
left here is what a launch file cannot do, in a parent process of launch:

- keys needs the terminal itself (raw input, its own screen), so it runs beside launch as a
  plain child in the foreground, and when it quits the graph stops with it; the other nodes'
  routine lines go to launch's log file, not to keys' screen;
- launch stops its nodes in order on SIGINT only (on SIGTERM it exits at once and leaves them
  running), so a SIGTERM or SIGHUP from a service manager or a closed terminal reaches launch
  as SIGINT; a second stop signal kills launch and its nodes at once, as does a launch still
  running long after the first (launch can miss a SIGINT); and launch, in a session
  of its own, gets SIGINT should this process be killed outright, so no node outlives it;
- the exit status: 1 when a node died, the last line saying which and how (launch_graph).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import ctypes
from dataclasses import dataclass
import difflib
import os
import signal
import subprocess
import sys
import time

from ament_index_python.packages import get_package_prefix
from launch.launch_description_sources import get_launch_description_from_python_launch_file

from ur_rg2_bringup.graph import KEYS, describe_exit
from ur_rg2_bringup.launch_graph import graph_launch_file

USAGE = """\
usage: scripts/run [--headless] [ARGUMENT:=VALUE ...] [--ros-args ARGS ...]
       (in a ROS install: ros2 run ur_rg2_bringup graph ...)

Start the UR + RG2 node graph with ROS 2's launch (the launch file graph.launch.py of
ur_rg2_bringup: sim, vision, motion, viewer: open http://127.0.0.1:8080/) and, when standard
input is a terminal, the keyboard teleop (keys) in the foreground. Quit with p or Ctrl-C in
keys; everything stops with it. keys' terminal shows keys' own lines and the other nodes'
warnings and errors; all their lines go to a log file whose path is printed at start and on
exit. Without a terminal (piped, CI, a service manager) the graph runs headless, every line on
the screen, until SIGINT or SIGTERM. If a node dies, the others are stopped, the last line says
which node and how, and the exit status is 1. Nodes are stopped with SIGINT, then SIGTERM after
5 s, then SIGKILL.

arguments:
  ARGUMENT:=VALUE   an argument of graph.launch.py: use_sim, robot_model, gui, camera_rate,
                    port, namespace, view3d, view3d_port, detector, params_file (e.g.
                    robot_model:=ur3 gui:=true camera_rate:=15.0 detector:=learned);
                    ros2 launch ur_rg2_bringup graph.launch.py --show-args describes them.
                    Any other parameter of the graph's nodes goes in a parameters file: copy
                    the package's config/graph.yaml (ros2 pkg prefix ur_rg2_bringup, then
                    share/ur_rg2_bringup/config/) and pass params_file:=YOUR_FILE; ready-made
                    ones are in config/examples/ there (a white ball with the learned
                    detector, a UR3 with a slower camera).

options:
  --headless        do not start keys even when standard input is a terminal
  --ros-args ARGS   everything after this goes to keys (e.g. --ros-args -p step_deg:=2.0)
  -h, --help        show this help and exit
"""


class UsageError(Exception):
    """A command-line mistake; the message says which."""


@dataclass(frozen=True)
class Options:
    """The parsed command line."""

    headless: bool = False
    help: bool = False
    launch_arguments: tuple[tuple[str, str], ...] = ()
    keys_arguments: tuple[str, ...] = ()
    """ROS arguments for keys (the graph's namespace, then everything after ``--ros-args``)."""


def launch_arguments() -> dict[str, list[str] | None]:
    """Return graph.launch.py's arguments and their choices, as its DeclareLaunchArguments say."""
    description = get_launch_description_from_python_launch_file(graph_launch_file())
    return {argument.name: argument.choices for argument in description.get_launch_arguments()}


def parse_args(argv: Sequence[str], known: Mapping[str, Sequence[str] | None]) -> Options:
    """Turn ``scripts/run`` arguments into launch arguments and keys' ROS arguments.

    ``known`` maps the launch file's argument names to their choices (None: any value); any
    other NAME:=VALUE is refused, and so is a value that is none of its argument's choices
    (here, once, rather than by launch, which says it twice).
    """
    headless = False
    launch_arguments: list[tuple[str, str]] = []
    keys_arguments: list[str] = []
    args = list(argv)
    while args:
        arg = args.pop(0)
        if arg == '--ros-args':
            keys_arguments += args
            break
        if arg in ('-h', '--help'):
            return Options(help=True)
        if arg == '--headless':
            headless = True
        elif ':=' in arg and not arg.startswith('-'):
            name, value = arg.split(':=', 1)
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                raise UsageError(
                    f'{name!r} is not an argument of graph.launch.py'
                    + (f' (did you mean {close[0]}?)' if close else '')
                    + '; set other parameters in a file given as params_file:=FILE')
            if known[name] is not None and value not in known[name]:
                raise UsageError(f'{name}:={value} is none of its choices: '
                                 + ', '.join(known[name]))
            launch_arguments.append((name, value))
            if name == 'namespace' and value:
                keys_arguments[:0] = ['-r', f'__ns:={value}']
        else:
            raise UsageError(f'unknown argument {arg!r}')
    return Options(headless=headless, launch_arguments=tuple(launch_arguments),
                   keys_arguments=tuple(keys_arguments))


def keys_executable() -> str:
    """Return the path of the keys executable, found as ``ros2 run`` finds it."""
    return os.path.join(get_package_prefix(KEYS.package), 'lib', KEYS.package, KEYS.executable)


# Signals that ask the graph to stop: Ctrl-C, a service manager, a closed terminal.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_PR_SET_PDEATHSIG = 1
# How often the loop looks at keys and launch, s.
_POLL_S = 0.1
# Launch stops its nodes within about 10 s of a SIGINT (SIGTERM, then SIGKILL, 5 s apart); a
# launch that is still there after this long missed the signal (ros2/launch#495), s.
_STOP_GRACE_S = 30.0


def _prepare_launch_child() -> None:
    """In the launch child before exec: SIGINT stops it, and comes when this process dies.

    SIGINT may be ignored here (a shell's background job); launch's nodes inherit that.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGINT))
    except (OSError, AttributeError):
        pass


class _Graph:
    """The launch child and, with a terminal, keys; stop signals relayed to launch."""

    def __init__(self, options: Options, interactive: bool) -> None:
        self._stop_requests = 0
        self._stop_deadline = 0.0
        # Its own session: terminal signals reach this process (and keys), which alone
        # decides how launch stops.
        self._launch = subprocess.Popen(
            [sys.executable, '-m', 'ur_rg2_bringup.launch_graph',
             *(['--quiet'] if interactive else []),
             *(f'{name}:={value}' for name, value in options.launch_arguments)],
            start_new_session=True, preexec_fn=_prepare_launch_child)
        self._keys: subprocess.Popen | None = None
        if interactive:
            self._keys = subprocess.Popen([keys_executable(), '--ros-args',
                                           *options.keys_arguments])

    def _on_stop_signal(self, _signum, _frame) -> None:
        self._stop_requests += 1
        if self._stop_requests == 1:
            self._stop_deadline = time.monotonic() + _STOP_GRACE_S
            self._launch.send_signal(signal.SIGINT)
        else:
            os.killpg(self._launch.pid, signal.SIGKILL)

    def _kill_if_stuck(self) -> None:
        """Kill launch and its nodes if they outlived a stop request by the grace period."""
        if self._stop_requests == 1 and time.monotonic() > self._stop_deadline:
            print(f'bringup: launch did not stop within {_STOP_GRACE_S:.0f} s of the stop '
                  'signal; killing the graph', file=sys.stderr, flush=True)
            self._on_stop_signal(signal.SIGINT, None)

    def run(self) -> int:
        for signum in STOP_SIGNALS:
            signal.signal(signum, self._on_stop_signal)
        keys_failure = None
        while True:
            try:
                returncode = self._launch.wait(timeout=_POLL_S)
                break
            except subprocess.TimeoutExpired:
                pass
            self._kill_if_stuck()
            if self._keys is not None and self._keys.poll() is not None:
                if self._keys.returncode != 0:
                    keys_failure = f'keys {describe_exit(self._keys.returncode)}'
                self._keys = None
                if not self._stop_requests:
                    self._on_stop_signal(signal.SIGINT, None)
        self._stop_keys()
        if keys_failure is not None:
            print(f'bringup: {keys_failure}', file=sys.stderr, flush=True)
            return 1
        return 1 if returncode < 0 else returncode

    def _stop_keys(self) -> None:
        if self._keys is None or self._keys.poll() is not None:
            return
        self._keys.terminate()  # keys restores the terminal on SIGTERM
        try:
            self._keys.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._keys.kill()
            self._keys.wait()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the graph; return the process exit status."""
    try:
        options = parse_args(sys.argv[1:] if argv is None else argv, launch_arguments())
    except UsageError as exc:
        print(f'bringup: {exc}\n(scripts/run --help shows the usage)', file=sys.stderr)
        return 2
    if options.help:
        print(USAGE, end='')
        return 0
    interactive = not options.headless and sys.stdin.isatty()
    if not interactive:
        why = '--headless' if options.headless else 'no terminal on standard input'
        print(f'bringup: {why}: running the graph headless; stop with Ctrl-C or SIGTERM',
              file=sys.stderr, flush=True)
    return _Graph(options, interactive).run()


if __name__ == '__main__':
    sys.exit(main())
