"""The node graph that ``scripts/run`` starts, and its command line."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import os
import shutil
import sys

from ament_index_python.packages import PackageNotFoundError, get_package_prefix

from bringup.parameters import ParameterCheck, Requested
from bringup.supervisor import ProcessSpec, Supervisor


@dataclass(frozen=True)
class Node:
    """One node of the graph, as a launch file would name it."""

    name: str
    """Short name: in messages, and as a prefix for parameters meant for this node only."""
    package: str
    executable: str
    node_name: str
    """The ROS node name (for ``NODE:PARAM:=VALUE``)."""
    interactive: bool = False
    """Needs the terminal: runs in the foreground, and only when standard input is one."""


# The graph, in start order. Adding a process is adding a line here.
GRAPH: tuple[Node, ...] = (
    Node('sim', 'ur_rg2_sim', 'sim', 'ur_rg2_sim'),
    Node('vision', 'ur_rg2_vision', 'vision', 'ur_rg2_vision'),
    Node('motion', 'ur_rg2_motion', 'motion', 'ur_rg2_motion'),
    Node('viewer', 'ur_rg2_vision', 'viewer', 'ur_rg2_viewer'),
    Node('keys', 'ur_rg2_teleop', 'keys', 'ur_rg2_teleop', interactive=True),
)

USAGE = """\
usage: scripts/run [--headless] [NAME:=VALUE ...] [NODE:NAME:=VALUE ...] [--ros-args ARGS ...]

Start the UR + RG2 node graph: the simulator (sim), the ball detector (vision), Cartesian
control and the ball pick (motion) and the browser view (viewer: open http://127.0.0.1:8080/)
as separate processes and, when standard input is a terminal, the keyboard teleop (keys) in
the foreground. Quit with p or Ctrl-C in keys; everything stops with it. Without a terminal
(piped, CI, a service manager) sim, vision, motion and viewer run headless until SIGINT or
SIGTERM. If any process dies, the others are stopped
and the exit status is 1; the last line repeats the error it logged last. Nodes are stopped
with SIGTERM, then SIGKILL after 5 s.

parameters:
  NAME:=VALUE       a ROS parameter for every node; each node takes the ones it declares
                    (e.g. robot_model:=ur3 gui:=true camera_rate:=15.0 frames_dir:=/tmp/f);
                    one that no node declares is reported once the nodes are up
  NODE:NAME:=VALUE  a parameter for one node only; NODE is {short} or a ROS node name
                    (e.g. sim:camera_rate:=15.0, ur_rg2_teleop:step_deg:=2.0)
  VALUE is YAML, as for ros2 run: true, 15.0, ur3, "[0.5, 0.0, 0.03]"

options:
  --headless        do not start keys even when standard input is a terminal
  --ros-args ARGS   everything after this goes to every node unchanged
                    (e.g. --ros-args -r __ns:=/arm1 --log-level debug)
  -h, --help        show this help and exit
""".format(short=', '.join(node.name for node in GRAPH))


class UsageError(Exception):
    """A command-line mistake; the message says which."""


@dataclass(frozen=True)
class Options:
    """The parsed command line."""

    headless: bool
    ros_args: list[str]
    help: bool = False
    parameters: tuple[Requested, ...] = ()
    """Every parameter given (``NAME:=VALUE``, ``NODE:NAME:=VALUE``, ``-p`` after --ros-args)."""


def _requested(assignment: str) -> Requested | None:
    """Return the parameter of a ``-p`` argument (``[NODE:]NAME:=VALUE``), None if malformed."""
    name, sep, _ = assignment.partition(':=')
    node, _, param = name.rpartition(':')
    return Requested(node, param) if sep and param else None


def parse_args(argv: Sequence[str], graph: Sequence[Node] = GRAPH) -> Options:
    """Turn ``scripts/run`` arguments into options and ``--ros-args`` for every node."""
    aliases = {node.name: node.node_name for node in graph}
    headless = False
    ros_args: list[str] = []
    parameters: list[Requested] = []
    args = list(argv)
    while args:
        arg = args.pop(0)
        if arg == '--ros-args':
            ros_args += args
            parameters += [requested for flag, value in zip(args, args[1:], strict=False)
                           if flag in ('-p', '--param') and (requested := _requested(value))]
            break
        if arg in ('-h', '--help'):
            return Options(headless=headless, ros_args=ros_args, help=True)
        if arg == '--headless':
            headless = True
        elif ':=' in arg and not arg.startswith('-'):
            name, value = arg.split(':=', 1)
            node, sep, param = name.rpartition(':')
            if not param or (sep and not node):
                raise UsageError(f'{arg!r}: expected NAME:=VALUE or NODE:NAME:=VALUE')
            # rcl applies "node:param:=value" to that node only; translate the short names.
            target = aliases.get(node, node) if sep else ''
            ros_args += ['-p', f'{target}{sep}{param}:={value}']
            parameters.append(Requested(target, param))
        else:
            raise UsageError(f'unknown argument {arg!r}')
    return Options(headless=headless, ros_args=ros_args, parameters=tuple(parameters))


def find_executable(package: str, executable: str) -> str:
    """Locate a node's executable like ``ros2 run``: the ament index first, then PATH.

    A colcon install (Docker, a ROS workspace) has it in ``<prefix>/lib/<package>/``; the
    project's venv installs it as a console script on PATH.
    """
    try:
        path = os.path.join(get_package_prefix(package), 'lib', package, executable)
    except PackageNotFoundError:
        path = ''
    if os.access(path, os.X_OK):
        return path
    found = shutil.which(executable)
    if found is None:
        raise LookupError(f'executable {executable!r} of package {package!r} not found: run '
                          'scripts/bootstrap, or source the workspace install/setup.bash')
    return found


def main(argv: Sequence[str] | None = None) -> int:
    """Run the graph; return the process exit status."""
    try:
        options = parse_args(sys.argv[1:] if argv is None else argv)
    except UsageError as exc:
        print(f'bringup: {exc}\n(scripts/run --help shows the usage)', file=sys.stderr)
        return 2
    if options.help:
        print(USAGE, end='')
        return 0
    interactive = not options.headless and sys.stdin.isatty()
    nodes = [node for node in GRAPH if interactive or not node.interactive]
    try:
        specs = [
            ProcessSpec(
                node.name,
                [find_executable(node.package, node.executable)]
                + (['--ros-args', *options.ros_args] if options.ros_args else []),
                foreground=node.interactive)
            for node in nodes
        ]
    except LookupError as exc:
        print(f'bringup: {exc}', file=sys.stderr)
        return 1
    if not interactive:
        why = '--headless' if options.headless else 'no terminal on standard input'
        print(f'bringup: {why}: running {", ".join(n.name for n in nodes)} headless; '
              'stop with Ctrl-C or SIGTERM', file=sys.stderr, flush=True)
    check = None
    if options.parameters:
        check = ParameterCheck(options.parameters, [node.node_name for node in nodes],
                               options.ros_args, _report)
    try:
        return Supervisor(specs, on_started=check and check.start,
                          on_stopping=check and check.stop).run()
    finally:
        if check is not None:
            check.join()


def _report(message: str) -> None:
    print(f'bringup: {message}', file=sys.stderr, flush=True)
