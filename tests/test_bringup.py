"""The bring-up supervisor and command line, with tiny stand-in processes for the nodes.

The supervisor runs in its own process (as under ``scripts/run``) so that the tests can signal
it, kill it, and give it a terminal.
"""

import fcntl
import json
import os
from pathlib import Path
import pty
import re
import select
import signal
import subprocess
import sys
import termios
import threading
import time

from conftest import wait_for
import pytest

from bringup.graph import GRAPH, UsageError, find_executable, parse_args
from bringup.parameters import Requested, query_declared, unknown_parameters
from bringup.supervisor import describe_exit

ROOT = Path(__file__).resolve().parents[1]

# A stand-in node. argv: PIDFILE MODE [ARG]. It writes its pid (and a grandchild's) when ready.
STUB = r"""
import os, signal, subprocess, sys, time
pidfile, mode, arg = sys.argv[1], sys.argv[2], (sys.argv[3:] or [''])[0]
pids = [os.getpid()]
quit = lambda *_: sys.exit(0)
signal.signal(signal.SIGINT, quit)
if mode == 'exit':
    time.sleep(float(arg))
    sys.exit(3)
if mode == 'fail':  # logs like a ROS node that gives up (rcutils colours errors on a terminal)
    print(f'[INFO] [1.0] [stub]: terminal: {os.isatty(1)} {os.isatty(2)}')
    sys.stderr.write('[ERROR] [1.1] [stub]: a first problem\n'
                     '\x1b[31m[FATAL] [1.2] [stub]: the reason\x1b[0m\n')
    print('[INFO] [1.3] [stub]: giving up')
    time.sleep(float(arg))
    sys.exit(2)
if mode == 'say':
    print('[INFO] [1.0] [stub]: up and running')
if mode == 'kill9':
    time.sleep(float(arg))
    os.kill(os.getpid(), signal.SIGKILL)
if mode == 'stubborn':
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
if mode == 'spawn':  # leaves behind a grandchild that ignores SIGTERM
    pids.append(subprocess.Popen([sys.executable, __file__, pidfile + '.grandchild',
                                  'stubborn']).pid)
if mode == 'tty':  # a foreground process that quits on p
    import tty
    tty.setcbreak(0)  # a byte at a time, Ctrl-C still a signal; before "ready": it flushes
with open(pidfile + '.tmp', 'w') as f:
    f.write(' '.join(map(str, pids)))
os.rename(pidfile + '.tmp', pidfile)
if mode == 'tty':
    while os.read(0, 1) != b'p':
        pass
    sys.exit(0)
while True:
    time.sleep(1)
"""

# Runs a Supervisor over the JSON list of ProcessSpec fields in argv[1], with short deadlines.
DRIVER = """
import json, signal, sys
from bringup.supervisor import ProcessSpec, Supervisor
specs = [ProcessSpec(**spec) for spec in json.loads(sys.argv[1])]
escalation = [(signal.SIGTERM, 1.5), (signal.SIGKILL, 2.0)]
sys.exit(Supervisor(specs, escalation=escalation).run())
"""


def alive(pid: int) -> bool:
    """Tell whether ``pid`` runs (a zombie that nobody reaped yet counts as dead)."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(')', 1)[1].split()[0] not in ('Z', 'X')


def processes_mentioning(text: str) -> list[int]:
    """Return the pids of live processes whose command line contains ``text``."""
    pids = []
    for cmdline in Path('/proc').glob('[0-9]*/cmdline'):
        try:
            if text in cmdline.read_bytes().decode(errors='replace'):
                pids.append(int(cmdline.parent.name))
        except OSError:  # it ended while we looked
            continue
    return [pid for pid in pids if alive(pid)]


class Graph:
    """A supervisor process over stand-in processes, and what they wrote."""

    def __init__(self, tmp_path: Path, modes: dict[str, str], foreground: str = '',
                 **popen_kwargs) -> None:
        self.tmp = tmp_path
        stub = tmp_path / 'stub.py'
        stub.write_text(STUB)
        specs = [{'name': name,
                  'argv': [sys.executable, str(stub), str(tmp_path / name), *mode.split()],
                  'foreground': name == foreground}
                 for name, mode in modes.items()]
        self.proc = subprocess.Popen([sys.executable, '-c', DRIVER, json.dumps(specs)],
                                     cwd=ROOT, text=True,
                                     **{'stderr': subprocess.PIPE, **popen_kwargs})

    def pids(self, name: str) -> list[int]:
        """Wait until stand-in ``name`` is ready; return its pid (and its grandchild's)."""
        path = self.tmp / name
        wait_for(path.exists, 20.0, f'{name} to start')
        return [int(pid) for pid in path.read_text().split()]

    def finish(self, timeout: float = 20.0) -> tuple[int, str]:
        """Wait for the supervisor to exit; return its status and what it printed."""
        try:
            self.out, err = self.proc.communicate(timeout=timeout)
        finally:
            self.proc.kill()
        return self.proc.returncode, err


def assert_all_gone(pids: list[int], tmp_path: Path) -> None:
    """Check that the processes and anything else started from ``tmp_path`` have ended."""
    wait_for(lambda: not any(alive(pid) for pid in pids), 5.0, f'{pids} to end')
    assert not processes_mentioning(str(tmp_path))


def test_a_dying_process_stops_the_others_and_says_why(tmp_path):
    graph = Graph(tmp_path, {'sim': 'run', 'vision': 'exit 0.5', 'viewer': 'run'})
    pids = graph.pids('sim') + graph.pids('viewer')
    code, err = graph.finish()
    assert code == 1, err
    assert 'vision exited with code 3: stopping sim, viewer' in err
    assert_all_gone(pids, tmp_path)


def test_the_summary_repeats_the_last_error_line_of_the_process_that_died(tmp_path):
    graph = Graph(tmp_path, {'sim': 'fail 0.5', 'vision': 'run'}, stdout=subprocess.PIPE)
    pids = graph.pids('vision')
    code, err = graph.finish()
    assert code == 1, err
    # Its output passes through unchanged, each stream to the same stream of the supervisor.
    assert '[INFO] [1.0] [stub]: terminal: False False\n' in graph.out
    assert '[INFO] [1.3] [stub]: giving up\n' in graph.out
    assert '[ERROR] [1.1] [stub]: a first problem\n\x1b[31m[FATAL] [1.2]' in err
    assert 'sim exited with code 2: stopping vision' in err
    assert err.splitlines()[-1] == (
        'bringup: sim exited with code 2: [FATAL] [1.2] [stub]: the reason')
    assert_all_gone(pids, tmp_path)


def test_output_passes_through_as_it_comes(tmp_path):
    graph = Graph(tmp_path, {'sim': 'say'}, stdout=subprocess.PIPE)
    pids = graph.pids('sim')
    ready, _, _ = select.select([graph.proc.stdout], [], [], 20.0)
    assert ready and graph.proc.stdout.readline() == '[INFO] [1.0] [stub]: up and running\n'
    assert alive(pids[0])  # not held back until it ends
    graph.proc.send_signal(signal.SIGTERM)
    code, err = graph.finish()
    assert code == 0, err
    assert 'stub' not in err  # no error line, no summary of one
    assert_all_gone(pids, tmp_path)


def test_on_a_terminal_processes_still_write_to_a_terminal(tmp_path):
    # One terminal per stream: two streams copied to one terminal interleave at any byte.
    out_controller, out_terminal = open_terminal()
    err_controller, err_terminal = open_terminal()
    try:
        graph = Graph(tmp_path, {'sim': 'fail 0.5', 'vision': 'run'}, stdout=out_terminal,
                      stderr=err_terminal)
        graph.proc.wait(timeout=30)
        os.close(out_terminal)
        os.close(err_terminal)
        out = read_terminal(out_controller)
        err = read_terminal(err_controller)
    finally:
        os.close(out_controller)
        os.close(err_controller)
        graph.proc.kill()
    assert graph.proc.returncode == 1, out + err
    assert '[INFO] [1.0] [stub]: terminal: True True\n' in out
    assert '\x1b[31m[FATAL] [1.2] [stub]: the reason\x1b[0m\n' in err  # colours kept
    assert err.splitlines()[-1] == (
        'bringup: sim exited with code 2: [FATAL] [1.2] [stub]: the reason')


def test_a_process_killed_by_a_signal_is_reported_with_the_signal(tmp_path):
    graph = Graph(tmp_path, {'sim': 'kill9 0.5', 'vision': 'run'})
    pids = graph.pids('vision')
    code, err = graph.finish()
    assert code == 1, err
    assert 'sim was killed by signal 9 (SIGKILL): stopping vision' in err
    assert_all_gone(pids, tmp_path)


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_a_stop_signal_stops_everything_cleanly(tmp_path, sig):
    graph = Graph(tmp_path, {'sim': 'run', 'vision': 'run'})
    pids = graph.pids('sim') + graph.pids('vision')
    graph.proc.send_signal(sig)
    code, err = graph.finish()
    assert code == 0, err
    assert f'{sig.name} received: stopping sim, vision' in err
    assert 'still running' not in err  # both stopped at the first, gentle step
    assert_all_gone(pids, tmp_path)


def test_stopping_escalates_to_sigkill(tmp_path):
    graph = Graph(tmp_path, {'sim': 'stubborn', 'vision': 'run'})
    pids = graph.pids('sim') + graph.pids('vision')
    graph.proc.send_signal(signal.SIGINT)
    code, err = graph.finish()
    assert code == 0, err
    assert 'sim still running after SIGTERM: sending SIGKILL' in err
    assert 'all stopped' in err
    assert_all_gone(pids, tmp_path)


def test_a_second_stop_signal_skips_the_wait(tmp_path):
    graph = Graph(tmp_path, {'sim': 'stubborn'})
    pids = graph.pids('sim')
    graph.proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    graph.proc.send_signal(signal.SIGINT)
    started = time.monotonic()
    code, err = graph.finish()
    assert code == 0, err
    assert 'sim still running after SIGTERM: sending SIGKILL' in err
    assert time.monotonic() - started < 1.2  # not the 1.5 s SIGTERM deadline
    assert_all_gone(pids, tmp_path)


def test_processes_left_behind_in_a_group_are_killed(tmp_path):
    graph = Graph(tmp_path, {'sim': 'spawn'})
    pids = graph.pids('sim')
    assert len(pids) == 2
    wait_for((tmp_path / 'sim.grandchild').exists, 20.0, 'the grandchild to start')
    graph.proc.send_signal(signal.SIGTERM)
    code, err = graph.finish()
    assert code == 0, err
    assert 'killed processes left behind in the process group of sim' in err
    assert_all_gone(pids, tmp_path)


def test_children_die_with_a_killed_supervisor(tmp_path):
    graph = Graph(tmp_path, {'sim': 'run', 'vision': 'run'})
    pids = graph.pids('sim') + graph.pids('vision')
    graph.proc.kill()
    graph.finish()
    assert_all_gone(pids, tmp_path)


def test_a_process_that_cannot_start_stops_the_ones_already_started(tmp_path):
    stub = tmp_path / 'stub.py'
    stub.write_text(STUB)
    specs = [{'name': 'sim', 'argv': [sys.executable, str(stub), str(tmp_path / 'sim'), 'run']},
             {'name': 'vision', 'argv': [str(tmp_path / 'missing')]}]
    proc = subprocess.run([sys.executable, '-c', DRIVER, json.dumps(specs)], cwd=ROOT,
                          capture_output=True, text=True, timeout=30)
    assert proc.returncode == 1, proc.stderr
    assert (f'cannot start vision ({tmp_path / "missing"}): No such file or directory: '
            'stopping sim') in proc.stderr
    assert_all_gone([], tmp_path)


def open_terminal() -> tuple[int, int]:
    """Return (controller, terminal) file descriptors of a new pseudo-terminal."""
    controller, terminal = pty.openpty()
    attrs = termios.tcgetattr(terminal)
    attrs[3] &= ~termios.ECHO  # keep the test's keystrokes out of the output
    termios.tcsetattr(terminal, termios.TCSANOW, attrs)
    return controller, terminal


def read_terminal(controller: int) -> str:
    """Return what was written to a terminal whose other end is closed, with plain newlines."""
    data = b''
    while True:
        try:
            chunk = os.read(controller, 65536)
        except OSError:  # EIO: everything has been read
            break
        if not chunk:
            break
        data += chunk
    return data.decode(errors='replace').replace('\r\n', '\n')


def become_terminal_session_leader() -> None:
    """Pre-exec: a new session with stdin as its terminal, like a login shell's job."""
    os.setsid()
    fcntl.ioctl(0, termios.TIOCSCTTY, 0)


def test_quitting_the_foreground_process_stops_the_graph(tmp_path):
    controller, terminal = open_terminal()
    try:
        graph = Graph(tmp_path, {'sim': 'run', 'keys': 'tty'}, foreground='keys',
                      stdin=terminal)
        pids = graph.pids('sim') + graph.pids('keys')
        os.write(controller, b'xp')
        code, err = graph.finish()
    finally:
        os.close(controller)
        os.close(terminal)
    assert code == 0, err
    assert 'keys exited: stopping sim' in err
    assert_all_gone(pids, tmp_path)


def test_ctrl_c_on_the_terminal_stops_the_graph(tmp_path):
    controller, terminal = open_terminal()
    try:
        graph = Graph(tmp_path, {'sim': 'run', 'keys': 'tty'}, foreground='keys',
                      stdin=terminal, preexec_fn=become_terminal_session_leader)
        pids = graph.pids('sim') + graph.pids('keys')
        os.write(controller, b'\x03')  # the terminal sends SIGINT to its foreground group
        code, err = graph.finish()
    finally:
        os.close(controller)
        os.close(terminal)
    assert code == 0, err
    # keys got the same SIGINT from the terminal and may already be gone.
    assert re.search(r'SIGINT received: stopping sim(, keys)?\n', err), err
    assert 'still running' not in err
    assert_all_gone(pids, tmp_path)


def test_describe_exit():
    assert describe_exit(0) == 'exited with code 0'
    assert describe_exit(2) == 'exited with code 2'
    assert describe_exit(-11) == 'was killed by signal 11 (SIGSEGV)'


def test_parameters_go_to_every_node_or_to_the_one_named():
    options = parse_args(['robot_model:=ur3', 'sim:camera_rate:=15.0',
                          'ur_rg2_teleop:step_deg:=2.0', 'ball_position:=[0.5, 0.0, 0.03]',
                          '--headless', '--ros-args', '-r', '__ns:=/arm1', 'x:=y'])
    assert options.headless
    assert not options.help
    assert options.ros_args == [
        '-p', 'robot_model:=ur3', '-p', 'ur_rg2_sim:camera_rate:=15.0',
        '-p', 'ur_rg2_teleop:step_deg:=2.0', '-p', 'ball_position:=[0.5, 0.0, 0.03]',
        '-r', '__ns:=/arm1', 'x:=y']
    assert options.parameters == (
        Requested('', 'robot_model'), Requested('ur_rg2_sim', 'camera_rate'),
        Requested('ur_rg2_teleop', 'step_deg'), Requested('', 'ball_position'))
    tail = parse_args(['--ros-args', '-p', 'gui:=true', '--param', 'ur_rg2_sim:rate:=1',
                       '-r', 'a:=b', '-p'])
    assert tail.parameters == (Requested('', 'gui'), Requested('ur_rg2_sim', 'rate'))
    assert parse_args(['gui:=true', '--help']).help


@pytest.mark.parametrize('arg', ['--gui', 'robot_model', ':=3', 'sim::=3', ':x:=3'])
def test_bad_arguments_are_refused(arg):
    with pytest.raises(UsageError, match='argument|expected'):
        parse_args([arg])


def test_the_graph_has_sim_and_vision_in_the_background_and_keys_in_the_foreground():
    by_name = {node.name: node for node in GRAPH}
    assert (by_name['sim'].package, by_name['sim'].executable) == ('ur_rg2_sim', 'sim')
    assert (by_name['vision'].package, by_name['vision'].node_name) == (
        'ur_rg2_vision', 'ur_rg2_vision')
    assert [node.name for node in GRAPH if node.interactive] == ['keys']


def test_executables_are_found_in_the_ament_index_before_path(tmp_path, monkeypatch):
    (tmp_path / 'share/ament_index/resource_index/packages').mkdir(parents=True)
    (tmp_path / 'share/ament_index/resource_index/packages/ur_rg2_sim').touch()
    installed = tmp_path / 'lib/ur_rg2_sim/sim'
    installed.parent.mkdir(parents=True)
    installed.write_text('#!/bin/sh\n')
    installed.chmod(0o755)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path))
    assert find_executable('ur_rg2_sim', 'sim') == str(installed)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(tmp_path / 'elsewhere'))
    monkeypatch.setenv('PATH', str(installed.parent))
    assert find_executable('ur_rg2_vision', 'sim') == str(installed)
    with pytest.raises(LookupError, match="'vision' of package 'ur_rg2_vision' not found"):
        find_executable('ur_rg2_vision', 'vision')


def test_run_help_and_bad_arguments():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    shown = subprocess.run([sys.executable, '-m', 'bringup', '--help'], env=env,
                           capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0
    assert shown.stdout.startswith('usage: scripts/run')
    assert 'NODE:NAME:=VALUE' in shown.stdout
    refused = subprocess.run([sys.executable, '-m', 'bringup', 'robot_model=ur3'], env=env,
                             capture_output=True, text=True, timeout=30)
    assert refused.returncode == 2
    assert "unknown argument 'robot_model=ur3'" in refused.stderr


SIM = frozenset({'use_sim_time', 'camera_rate', 'camera_width', 'robot_model'})
VISION = frozenset({'use_sim_time', 'frames_dir', 'save_every_n'})


def test_parameters_no_node_declares_are_named_with_a_suggestion():
    declared = {'ur_rg2_sim': SIM, 'ur_rg2_vision': VISION}
    requested = [Requested('', 'camera_rte'), Requested('', 'frames_dir'),
                 Requested('', 'camera_rte'), Requested('ur_rg2_vision', 'camera_rate'),
                 Requested('ur_rg2_sim', 'camera_rate'), Requested('', 'zzz'),
                 Requested('ur_rg2_sm', 'camera_rate')]
    assert unknown_parameters(requested, declared) == [
        "no node declares parameter 'camera_rte' (did you mean camera_rate?)",
        "ur_rg2_vision does not declare parameter 'camera_rate'",
        "no node declares parameter 'zzz'",
        "no node 'ur_rg2_sm' runs for 'ur_rg2_sm:camera_rate' (did you mean ur_rg2_sim?)",
    ]


def test_nothing_is_said_about_what_a_silent_node_might_take():
    declared = {'ur_rg2_sim': SIM, 'ur_rg2_vision': None}
    requested = [Requested('', 'camera_rte'), Requested('ur_rg2_vision', 'camera_rate'),
                 Requested('ur_rg2_sim', 'frames_dir')]
    assert unknown_parameters(requested, declared) == [
        "ur_rg2_sim does not declare parameter 'frames_dir'"]


def test_declared_parameters_are_asked_for_and_a_silent_node_does_not_hang(
        ros_graph, monkeypatch):
    from rclpy.node import Node

    answering = ros_graph.node('answering', namespace='arm1')
    answering.declare_parameter('camera_rate', 30.0)
    # Its parameter services exist, but nothing ever spins it: requests go unanswered.
    silent = Node('silent', namespace='arm1', context=ros_graph.context)
    try:
        monkeypatch.setenv('ROS_DOMAIN_ID', str(ros_graph.domain_id))
        started = time.monotonic()
        declared = query_declared(['answering', 'silent', 'absent'], ['-r', '__ns:=/arm1'],
                                  threading.Event(), timeout=3.0)
        assert time.monotonic() - started < 10.0
    finally:
        silent.destroy_node()
    assert {'camera_rate', 'use_sim_time'} <= declared['answering']
    assert declared['silent'] is None and declared['absent'] is None


def test_the_parameter_check_stops_when_asked(ros_graph, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(ros_graph.domain_id))
    stop = threading.Event()
    threading.Timer(0.5, stop.set).start()
    started = time.monotonic()
    assert query_declared(['absent'], [], stop, timeout=60.0) == {'absent': None}
    assert time.monotonic() - started < 10.0
