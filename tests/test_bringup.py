"""ur_rg2_bringup without running nodes: launch arguments, their routing, the command line."""

import fcntl
import os
from pathlib import Path
import pty
import subprocess
import sys
import termios

import pytest
from ur_rg2_bringup.graph import (
    NODES,
    PARAMETER_ARGUMENTS,
    describe_exit,
    graph_nodes,
    route_parameters,
)
from ur_rg2_bringup.run import UsageError, parse_args

ROOT = Path(__file__).resolve().parents[1]


def open_terminal() -> tuple[int, int]:
    """Return (controller, terminal) file descriptors of a new pseudo-terminal."""
    controller, terminal = pty.openpty()
    attrs = termios.tcgetattr(terminal)
    attrs[3] &= ~termios.ECHO  # keep the test's keystrokes out of the output
    termios.tcsetattr(terminal, termios.TCSANOW, attrs)
    return controller, terminal


def become_terminal_session_leader() -> None:
    """Pre-exec: a new session with stdin as its terminal, like a login shell's job."""
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def running(pid: int) -> bool:
    """Tell whether process ``pid`` is alive (not gone, not a zombie)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state not in ('Z', 'X')


def test_describe_exit():
    assert describe_exit(0) == 'exited with code 0'
    assert describe_exit(2) == 'exited with code 2'
    assert describe_exit(-11) == 'was killed by signal 11 (SIGSEGV)'


def test_the_launch_file_starts_sim_vision_motion_and_viewer():
    assert [(node.package, node.executable, node.node_name) for node in NODES] == [
        ('ur_rg2_sim', 'sim', 'ur_rg2_sim'), ('ur_rg2_vision', 'vision', 'ur_rg2_vision'),
        ('ur_rg2_motion', 'motion', 'ur_rg2_motion'), ('ur_rg2_vision', 'viewer', 'ur_rg2_viewer')]


def test_use_sim_false_leaves_the_sim_out_and_its_parameters_unrouted():
    assert graph_nodes('True') == NODES
    nodes = graph_nodes('false')
    assert [node.name for node in nodes] == ['vision', 'motion', 'viewer']
    routed, unknown = route_parameters({'camera_rate': '15', 'ball_radius': '0.05',
                                        'use_sim': 'false'}, nodes)
    assert routed['vision'] == ['-p', 'ball_radius:=0.05']
    assert unknown == ["parameter 'camera_rate' is for sim, which is not started"]
    with pytest.raises(ValueError, match='expected true or false'):
        graph_nodes('maybe')


def test_arguments_go_to_the_nodes_that_declare_them_or_to_the_one_named():
    routed, unknown = route_parameters({
        'robot_model': 'ur3', 'ball_radius': '0.05', 'port': '8081',
        'sim:camera_rate': '15.0', 'ur_rg2_vision:frames_dir': '/tmp/f',
        'use_sim_time': 'true', 'namespace': '/arm1', 'ros_args': '--log-level debug'})
    assert unknown == []
    assert routed['sim'] == ['-p', 'robot_model:=ur3', '-p', 'ball_radius:=0.05',
                             '-p', 'camera_rate:=15.0', '-p', 'use_sim_time:=true']
    assert routed['vision'] == ['-p', 'ball_radius:=0.05', '-p', 'frames_dir:=/tmp/f',
                                '-p', 'use_sim_time:=true']
    assert routed['viewer'] == ['-p', 'port:=8081', '-p', 'use_sim_time:=true']
    assert routed['motion'] == ['-p', 'use_sim_time:=true']


def test_what_no_node_declares_is_named_with_a_suggestion():
    routed, unknown = route_parameters({
        'camera_rte': '15', 'vision:camera_rate': '5', 'sm:gui': 'true',
        'keys:step_deg': '2', 'zzz': '1'})
    assert all(arguments == [] for arguments in routed.values())
    assert unknown == [
        "no node declares parameter 'camera_rte' (did you mean camera_rate?)",
        "ur_rg2_vision does not declare parameter 'camera_rate'",
        "no node 'sm' in the graph for sm:gui:=... (did you mean sim?)",
        "no node 'keys' in the graph for keys:step_deg:=...",
        "no node declares parameter 'zzz'"]


def test_every_argument_has_a_description_and_a_node():
    names = [argument.name for argument in PARAMETER_ARGUMENTS]
    assert len(names) == len(set(names))
    short = {node.name for node in NODES}
    for argument in PARAMETER_ARGUMENTS:
        assert argument.description and set(argument.nodes) <= short, argument


def test_the_command_line_splits_keys_parameters_from_launch_arguments():
    options = parse_args(['robot_model:=ur3', 'sim:camera_rate:=15.0', 'step_deg:=2.0',
                          'ur_rg2_teleop:step_mm:=5.0', 'ball_position:=[0.5, 0.0, 0.03]',
                          '--headless', '--ros-args', '-r', '__ns:=/arm1', '--log-level',
                          'debug'])
    assert options.headless and not options.help
    assert options.launch_arguments == (
        ('robot_model', 'ur3'), ('sim:camera_rate', '15.0'),
        ('ball_position', '[0.5, 0.0, 0.03]'), ('ros_args', '-r __ns:=/arm1 --log-level debug'))
    assert options.keys_arguments == ('-p', 'step_deg:=2.0', '-p', 'step_mm:=5.0',
                                      '-r', '__ns:=/arm1', '--log-level', 'debug')
    assert parse_args(['gui:=true', '--help']).help


@pytest.mark.parametrize('arg', ['--gui', 'robot_model', ':=3', 'sim::=3', ':x:=3'])
def test_bad_arguments_are_refused(arg):
    with pytest.raises(UsageError, match='argument|expected'):
        parse_args([arg])


def test_run_help_and_bad_arguments():
    shown = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', '--help'],
                           capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0
    assert shown.stdout.startswith('usage: scripts/run')
    assert 'NODE:NAME:=VALUE' in shown.stdout
    refused = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', 'robot_model=ur3'],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2
    assert "unknown argument 'robot_model=ur3'" in refused.stderr
