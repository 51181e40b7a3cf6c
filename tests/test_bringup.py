"""ur_rg2_bringup without running nodes: the launch file's arguments, the command line."""

import fcntl
import logging
import os
from pathlib import Path
import pty
import re
import subprocess
import sys
import termios

from ament_index_python.packages import get_package_share_directory
from launch import LaunchContext
from launch.launch_description_sources import get_launch_description_from_python_launch_file
from launch.utilities import perform_substitutions
import pytest
from ur_rg2_bringup.graph import describe_exit
from ur_rg2_bringup.launch_graph import graph_launch_file, warnings_and_errors
from ur_rg2_bringup.run import UsageError, parse_args
import yaml

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


def launch_arguments() -> dict:
    description = get_launch_description_from_python_launch_file(graph_launch_file())
    return {argument.name: argument for argument in description.get_launch_arguments()}


def test_the_launch_file_declares_the_contract_arguments_with_descriptions_and_defaults():
    arguments = launch_arguments()
    assert list(arguments) == ['use_sim', 'robot_model', 'gui', 'camera_rate', 'port',
                               'namespace', 'view3d', 'params_file']
    context = LaunchContext()
    defaults = {name: perform_substitutions(context, argument.default_value)
                for name, argument in arguments.items()}
    assert defaults == {
        'use_sim': 'true', 'robot_model': 'ur5', 'gui': 'false', 'camera_rate': '30.0',
        'port': '8080', 'namespace': '', 'view3d': 'false',
        'params_file': str(Path(get_package_share_directory('ur_rg2_bringup'))
                           / 'config' / 'graph.yaml')}
    assert Path(defaults['params_file']).resolve() == (
        ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml')
    for name, argument in arguments.items():
        assert len(argument.description) > 20, name
    assert arguments['robot_model'].choices == ['ur5', 'ur3']
    for name in ('use_sim', 'gui', 'view3d'):
        assert arguments[name].choices == ['true', 'false'], name


def test_show_args_shows_every_argument_with_its_default():
    shown = subprocess.run(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py',
                            '--show-args'], capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    for name, default in (('use_sim', 'true'), ('robot_model', 'ur5'), ('gui', 'false'),
                          ('camera_rate', '30.0'), ('port', '8080'), ('view3d', 'false')):
        assert re.search(rf"'{name}':\n .*\n +\(default: '{re.escape(default)}'\)",
                         shown.stdout), (name, shown.stdout)
    assert "FindPackageShare(pkg='ur_rg2_bringup')" in shown.stdout


def test_the_params_file_has_a_section_per_node_of_the_graph():
    params = yaml.safe_load((ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml').read_text())
    assert list(params) == ['/**/ur_rg2_sim', '/**/ur_rg2_vision', '/**/ur_rg2_motion',
                            '/**/ur_rg2_viewer', '/**/ur_rg2_view3d']
    assert params['/**/ur_rg2_sim']['ros__parameters']['camera_rate'] == 30.0
    assert params['/**/ur_rg2_viewer']['ros__parameters']['port'] == 8080
    assert params['/**/ur_rg2_view3d']['ros__parameters']['port'] == 8081


KNOWN = ['use_sim', 'robot_model', 'gui', 'camera_rate', 'port', 'namespace', 'view3d',
         'params_file']


def test_the_command_line_splits_launch_arguments_from_keys_arguments():
    options = parse_args(['robot_model:=ur3', 'camera_rate:=15.0', 'namespace:=/arm1',
                          'params_file:=/tmp/p.yaml', '--headless', '--ros-args', '-p',
                          'step_deg:=2.0', '--log-level', 'debug'], KNOWN)
    assert options.headless and not options.help
    assert options.launch_arguments == (
        ('robot_model', 'ur3'), ('camera_rate', '15.0'), ('namespace', '/arm1'),
        ('params_file', '/tmp/p.yaml'))
    assert options.keys_arguments == ('-r', '__ns:=/arm1', '-p', 'step_deg:=2.0',
                                      '--log-level', 'debug')
    assert parse_args(['gui:=true', '--help'], KNOWN).help


def test_a_parameter_that_is_no_launch_argument_is_refused_with_a_suggestion():
    with pytest.raises(UsageError, match=r"'camera_rte' is not an argument of graph.launch.py "
                                         r'\(did you mean camera_rate\?\); .*params_file'):
        parse_args(['camera_rte:=15'], KNOWN)
    with pytest.raises(UsageError, match="'frames_dir' is not an argument"):
        parse_args(['frames_dir:=/tmp/f'], KNOWN)


@pytest.mark.parametrize('arg', ['--gui', 'robot_model', ':=3', 'sim:gui:=3'])
def test_bad_arguments_are_refused(arg):
    with pytest.raises(UsageError, match='argument'):
        parse_args([arg], KNOWN)


def test_the_screen_filter_keeps_warnings_errors_and_raw_output():
    def record(name, level, message):
        return logging.LogRecord(name, level, __file__, 1, message, None, None)

    assert not warnings_and_errors(record('sim-1-stderr', logging.INFO,
                                          '[sim-1] [INFO] [1.0] [ur_rg2_sim]: simulating'))
    assert not warnings_and_errors(record('motion-3-stdout', logging.INFO,
                                          '[motion-3] [DEBUG] [1.0] [ur_rg2_motion]: x'))
    assert not warnings_and_errors(record('sim-1-stderr', logging.INFO,
                                          '[sim-1] pybullet build time: Jan 29 2025 23:17:20'))
    assert warnings_and_errors(record('sim-1-stderr', logging.INFO,
                                      '[sim-1] [WARN] [1.0] [ur_rg2_sim]: protective stop'))
    assert warnings_and_errors(record('sim-1-stderr', logging.INFO,
                                      '[sim-1] [ERROR] [1.0] [ur_rg2_sim]: failed'))
    assert warnings_and_errors(record('sim-1-stderr', logging.INFO,
                                      '[sim-1] Traceback (most recent call last):'))
    assert not warnings_and_errors(record('launch', logging.INFO, 'process started'))
    assert not warnings_and_errors(record('launch', logging.WARNING,
                                          'user interrupted with ctrl-c (SIGINT)'))
    assert warnings_and_errors(record('launch', logging.ERROR, 'process has died'))
    assert warnings_and_errors(record('graph.launch.py', logging.ERROR, 'sim exited'))


def test_run_help_and_bad_arguments():
    shown = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', '--help'],
                           capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0
    assert shown.stdout.startswith('usage: scripts/run')
    assert 'params_file:=YOUR_FILE' in shown.stdout
    refused = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', 'robot_model=ur3'],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2
    assert "unknown argument 'robot_model=ur3'" in refused.stderr
    refused = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', 'ball_radius:=0.05'],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2
    assert "'ball_radius' is not an argument of graph.launch.py" in refused.stderr


# A launch whose one action sends the process a SIGINT, then goes on working in Python.
_INTERRUPTED_ACTION = """
import os, signal, time
from launch import LaunchDescription, LaunchService
from launch.actions import ExecuteProcess, OpaqueFunction, RegisterEventHandler
from launch.event_handlers import OnProcessStart, OnShutdown
from ur_rg2_bringup.launch_graph import run_service

def interrupted(_context):
    os.kill(os.getpid(), signal.SIGINT)
    end = time.monotonic() + 0.3
    while time.monotonic() < end:
        pass
    print('the action finished', flush=True)

sleeper = ExecuteProcess(cmd=['sleep', '60'])
service = LaunchService(noninteractive=True)
service.include_launch_description(LaunchDescription([
    RegisterEventHandler(OnShutdown(on_shutdown=lambda event, _: print(event.reason))),
    sleeper,
    RegisterEventHandler(OnProcessStart(target_action=sleeper,
                                        on_start=[OpaqueFunction(function=interrupted)])),
]))
print('exit', run_service(service), flush=True)
"""


def test_a_sigint_stops_launch_without_breaking_the_action_it_came_in():
    ran = subprocess.run([sys.executable, '-c', _INTERRUPTED_ACTION], capture_output=True,
                         text=True, timeout=60)
    assert ran.returncode == 0, ran.stderr
    printed = [line for line in ran.stdout.splitlines() if not line.startswith('[')]  # ours
    assert printed == ['the action finished', 'ctrl-c (SIGINT)', 'exit 0'], ran.stdout + ran.stderr
    assert 'Traceback' not in ran.stderr, ran.stderr
