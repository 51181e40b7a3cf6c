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
from ur_rg2_bringup.launch_defaults import as_argument, file_parameter, next_port
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


SHARE = Path(get_package_share_directory('ur_rg2_bringup'))
EXAMPLES = sorted((ROOT / 'ros2_ws/src/ur_rg2_bringup/config/examples').glob('*.yaml'))


def argument_values(**given: str) -> dict[str, str]:
    """Return every launch argument's value as launch sets it, ``given`` on the command line."""
    context = LaunchContext()
    context.launch_configurations.update(given)
    for argument in launch_arguments().values():
        argument.execute(context)  # the default where not given; the choices checked
    return dict(context.launch_configurations)


def test_the_launch_file_declares_the_contract_arguments_with_descriptions_and_defaults():
    arguments = launch_arguments()
    assert list(arguments) == ['use_sim', 'robot_model', 'gui', 'camera_rate', 'port',
                               'namespace', 'view3d', 'view3d_port', 'detector', 'params_file']
    assert argument_values() == {
        'use_sim': 'true', 'robot_model': 'ur5', 'gui': 'false', 'camera_rate': '30.0',
        'port': '8080', 'namespace': '', 'view3d': 'false', 'view3d_port': '8081',
        'detector': 'color', 'params_file': str(SHARE / 'config' / 'graph.yaml')}
    shipped = perform_substitutions(LaunchContext(), arguments['params_file'].default_value)
    assert Path(shipped).resolve() == ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml'
    for name, argument in arguments.items():
        assert len(argument.description) > 20, name
    assert arguments['robot_model'].choices == ['ur5', 'ur3']
    assert arguments['detector'].choices == ['color', 'learned']
    for name in ('use_sim', 'gui', 'view3d'):
        assert arguments[name].choices == ['true', 'false'], name


def test_the_pages_never_share_a_port_by_default():
    assert argument_values(port='8081')['view3d_port'] == '8082'
    assert argument_values(port='0')['view3d_port'] == '0'  # both any free port
    assert argument_values(port='8081', view3d_port='9000')['view3d_port'] == '9000'
    assert [next_port(port) for port in ('1', '8080', '65535', '0')] == [
        '2', '8081', '0', '0']
    for bad in ('abc', '-1', '65536', ''):
        with pytest.raises(ValueError, match='is no port number'):
            next_port(bad)


def test_an_argument_not_given_takes_the_params_files_value(tmp_path):
    params_file = tmp_path / 'p.yaml'
    params_file.write_text('/**/ur_rg2_sim:\n  ros__parameters:\n    robot_model: ur3\n'
                           '    gui: true\n    camera_rate: 10\n'
                           '/arm1/ur_rg2_viewer:\n  ros__parameters:\n    port: 9000\n'
                           '/**:\n  ros__parameters:\n    detector: learned\n')
    values = argument_values(params_file=str(params_file))
    assert {name: values[name] for name in (
        'robot_model', 'gui', 'camera_rate', 'port', 'view3d_port', 'detector')} == {
        'robot_model': 'ur3', 'gui': 'true', 'camera_rate': '10', 'port': '8080',
        'view3d_port': '8081', 'detector': 'learned'}
    # The viewer's section is for the namespace /arm1 only; an argument given wins.
    values = argument_values(params_file=str(params_file), namespace='/arm1', gui='false')
    assert (values['port'], values['view3d_port'], values['gui']) == ('9000', '9001', 'false')
    assert file_parameter(params_file, '/ur_rg2_vision', 'model_dir') is None
    with pytest.raises(ValueError, match=r'params_file .*missing.yaml: cannot be read: No such'):
        file_parameter(tmp_path / 'missing.yaml', '/ur_rg2_sim', 'gui')
    params_file.write_text('- a list\n')
    with pytest.raises(ValueError, match='not a parameters file'):
        file_parameter(params_file, '/ur_rg2_sim', 'gui')


@pytest.mark.parametrize('example', EXAMPLES, ids=lambda path: path.name)
def test_each_example_params_file_is_installed_and_sets_only_declared_parameters(example):
    installed = SHARE / 'config' / 'examples' / example.name
    assert installed.resolve() == example
    shipped = yaml.safe_load((SHARE / 'config' / 'graph.yaml').read_text())
    declared = {node: set(section['ros__parameters']) for node, section in shipped.items()}
    declared['/**/ur_rg2_vision'].add('detector')
    for node, section in yaml.safe_load(example.read_text()).items():
        assert set(section['ros__parameters']) <= declared[node], (example.name, node)


def test_show_args_shows_every_argument_with_its_default():
    shown = subprocess.run(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py',
                            '--show-args'], capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    for name, default in (('use_sim', "'true'"),
                          ('robot_model', "ur_rg2_sim's robot_model in params_file, else 'ur5'"),
                          ('gui', "ur_rg2_sim's gui in params_file, else 'false'"),
                          ('camera_rate', "ur_rg2_sim's camera_rate in params_file, else '30.0'"),
                          ('port', "ur_rg2_viewer's port in params_file, else '8080'"),
                          ('view3d', "'false'"),
                          ('view3d_port', "ur_rg2_view3d's port in params_file, else "
                                          "LaunchConfig('port') + 1 (0: any free port)"),
                          ('detector', "ur_rg2_vision's detector in params_file, else 'color'")):
        assert re.search(rf"'{name}':\n .*\n +\(default: {re.escape(default)}\)",
                         shown.stdout), (name, shown.stdout)
    assert "FindPackageShare(pkg='ur_rg2_bringup')" in shown.stdout


def test_the_params_file_has_a_section_per_node_of_the_graph():
    params = yaml.safe_load((ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml').read_text())
    assert list(params) == ['/**/ur_rg2_sim', '/**/ur_rg2_vision', '/**/ur_rg2_motion',
                            '/**/ur_rg2_viewer', '/**/ur_rg2_view3d']
    assert params['/**/ur_rg2_sim']['ros__parameters']['camera_rate'] == 30.0
    assert params['/**/ur_rg2_viewer']['ros__parameters']['port'] == 8080
    # The launch file's: the 3D view's port follows the viewer's, DEFAULT_DETECTOR.
    assert 'port' not in params['/**/ur_rg2_view3d']['ros__parameters']
    assert 'detector' not in params['/**/ur_rg2_vision']['ros__parameters']



def code_defaults() -> dict[str, dict]:
    """Return each graph node's parameter defaults as its package's settings module has them."""
    from ur_rg2_motion.settings import PARAMETERS as MOTION
    from ur_rg2_sim.settings import PARAMETERS as SIM
    from ur_rg2_tools.settings import VIEW3D_PARAMETERS
    from ur_rg2_vision.settings import PARAMETERS as VISION
    from ur_rg2_vision.settings import VIEWER_PARAMETERS
    return {node: {spec.name: spec.default for spec in specs}
            for node, specs in (('ur_rg2_sim', SIM), ('ur_rg2_vision', VISION),
                                ('ur_rg2_motion', MOTION), ('ur_rg2_viewer', VIEWER_PARAMETERS),
                                ('ur_rg2_view3d', VIEW3D_PARAMETERS))}


def test_the_params_file_holds_the_defaults_written_in_the_code():
    """graph.yaml is data people copy: each value is the default of the node's settings module."""
    params = yaml.safe_load((ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml').read_text())
    for node, defaults in code_defaults().items():
        # The launch file's, not the file's: the detector, and the 3D view's port.
        expected = {name: value for name, value in defaults.items()
                    if (node, name) not in (('ur_rg2_vision', 'detector'),
                                            ('ur_rg2_view3d', 'port'))}
        assert params[f'/**/{node}']['ros__parameters'] == expected, node


def test_launch_arguments_not_in_the_params_file_take_the_nodes_defaults(tmp_path):
    empty = tmp_path / 'empty.yaml'
    empty.write_text('{}\n')
    values = argument_values(params_file=str(empty))
    defaults = code_defaults()
    for argument, node in (('robot_model', 'ur_rg2_sim'), ('gui', 'ur_rg2_sim'),
                           ('camera_rate', 'ur_rg2_sim'), ('port', 'ur_rg2_viewer'),
                           ('detector', 'ur_rg2_vision')):
        assert values[argument] == as_argument(defaults[node][argument]), argument

KNOWN = {'use_sim': ['true', 'false'], 'robot_model': ['ur5', 'ur3'], 'gui': ['true', 'false'],
         'camera_rate': None, 'port': None, 'namespace': None, 'view3d': ['true', 'false'],
         'view3d_port': None, 'detector': ['color', 'learned'], 'params_file': None}


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


def test_a_value_that_is_none_of_the_choices_is_refused_once():
    with pytest.raises(UsageError, match=r'^robot_model:=ur10 is none of its choices: ur5, ur3$'):
        parse_args(['robot_model:=ur10'], KNOWN)
    with pytest.raises(UsageError, match='detector:=yolo is none of its choices: color, learned'):
        parse_args(['detector:=yolo'], KNOWN)


def test_a_bad_value_launch_reads_stops_it_with_one_error_line():
    ran = subprocess.run([sys.executable, '-m', 'ur_rg2_bringup.run', 'port:=abc'],
                         stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, timeout=120)
    assert ran.returncode == 1, ran.stdout
    assert ran.stdout.count('port:=abc is no port number (0-65535)') == 1, ran.stdout
    assert 'Traceback' not in ran.stdout


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
