"""The README's run command (graph.launch.py, keys in the terminal) with the real nodes."""

import os
from pathlib import Path
import re
import signal
import socket
import subprocess
import termios
import time
import urllib.request

from ament_index_python.packages import get_package_share_directory
from conftest import wait_for
from geometry_msgs.msg import PointStamped
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import Bool
from std_srvs.srv import Trigger
from test_bringup import ROOT, become_terminal_session_leader, open_terminal, running
from ur_rg2_common.contract import LATCHED_QOS
import yaml

# The graph's nodes: launch's process name and the ROS node name; keys beside them.
NODES = {'sim': 'ur_rg2_sim', 'vision': 'ur_rg2_vision', 'motion': 'ur_rg2_motion',
         'viewer': 'ur_rg2_viewer'}
KEYS = 'ur_rg2_teleop'
PARAMS_FILE = ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml'
EXAMPLES = Path(get_package_share_directory('ur_rg2_bringup')) / 'config' / 'examples'
# In the Pick policy's region and the camera's view, off where the ball starts (the sim moves
# the ball only when ball_position changes).
EPISODE_BALL = [0.4, -0.2, 0.03]
_STARTED = re.compile(r'\[INFO\] \[(\w+)-\d+\]: process started with pid \[(\d+)\]')


def nodes_ready(probe: Node, interactive: bool) -> bool:
    """Tell whether every node of the graph is constructed (its parameter services exist).

    Stopping the graph after that tests a running graph, not one still starting.
    """
    services = {name for name, _ in probe.get_service_names_and_types()}
    names = [*NODES.values(), *([KEYS] if interactive else [])]
    return all(f'/{name}/list_parameters' in services for name in names)


def assert_every_node_stopped_cleanly(output: str) -> None:
    """Each node launch started finished cleanly, and none outlived the graph."""
    started = dict(_STARTED.findall(output))
    assert set(started) == set(NODES), output
    for name, pid in started.items():
        assert re.search(rf'\[{name}-\d+\]: process has finished cleanly', output), output
        assert not running(int(pid)), f'{name} outlived the graph'
    assert 'process has died' not in output
    assert 'failed to terminate' not in output
    assert 'Traceback' not in output


def test_headless_graph_takes_options_and_stops_on_sigterm(ros_graph, tmp_path):
    probe = ros_graph.node('probe')
    images: list[Image] = []
    positions: list[PointStamped] = []
    # Reliable, like the sim's publisher: best effort loses most large frames between processes.
    probe.create_subscription(Image, 'camera/color/image_raw', images.append,
                              QoSProfile(depth=5))
    probe.create_subscription(PointStamped, 'ball/position', positions.append,
                              qos_profile_sensor_data)
    save_frame = probe.create_client(Trigger, 'vision/save_frame')
    frames = tmp_path / 'frames'
    # Parameters that are no launch argument: in a copy of the shipped parameters file.
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params['/**/ur_rg2_sim']['ros__parameters'].update(camera_width=320, camera_height=240)
    params['/**/ur_rg2_vision']['ros__parameters']['frames_dir'] = str(frames)
    params_file = tmp_path / 'graph.yaml'
    params_file.write_text(yaml.safe_dump(params))
    log_path = tmp_path / 'run.log'
    with log_path.open('w') as log:
        # No terminal on stdin: headless.
        run = subprocess.Popen(
            [str(ROOT / 'scripts/run'), 'camera_rate:=10.0', 'port:=0',
             f'params_file:={params_file}'],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=ros_graph.env)
    try:
        # The first run of scripts/run in a fresh clone installs the environment first.
        wait_for(lambda: (images and positions) or run.poll() is not None, 180.0,
                 'a camera image and a ball position from the graph')
        assert run.poll() is None, f'the graph ended:\n{log_path.read_text()}'
        assert (images[-1].width, images[-1].height) == (320, 240)

        assert save_frame.wait_for_service(timeout_sec=10.0)
        future = save_frame.call_async(Trigger.Request())
        wait_for(future.done, 10.0, 'vision/save_frame')
        assert future.result().success, future.result().message
        assert str(frames) in future.result().message

        wait_for(lambda: nodes_ready(probe, interactive=False), 30.0, 'all nodes')
        run.send_signal(signal.SIGTERM)
        assert run.wait(timeout=30) == 0, log_path.read_text()
    finally:
        run.kill()
    output = log_path.read_text()
    assert 'no terminal on standard input' in output
    # Every node stopped cleanly on the first SIGINT launch sent it; headless, on the screen.
    assert_every_node_stopped_cleanly(output)


def free_port_pair() -> int:
    """Return a port P such that P and P + 1 are both free on the loopback now."""
    while True:
        with socket.socket() as first:
            first.bind(('127.0.0.1', 0))
            port = first.getsockname()[1]
            with socket.socket() as second:
                try:
                    second.bind(('127.0.0.1', port + 1))
                except OSError:
                    continue
        return port


def node_parameters(probe: Node, node: str, names: list[str]) -> dict:
    """Return a running node's parameters ``names`` through its parameter services."""
    client = AsyncParameterClient(probe, node)
    assert client.wait_for_services(timeout_sec=30.0), node
    future = client.get_parameters(names)
    wait_for(future.done, 30.0, f"{node}'s parameters")
    return {name: parameter_value_to_python(value)
            for name, value in zip(names, future.result().values, strict=True)}


# Each example as a user passes it (the 3D view beside the learned detector, on ports next to
# each other), and what it sets.
EXAMPLE_RUNS = {
    'white_ball_learned.yaml': (['camera_rate:=5.0', 'view3d:=true'], {
        NODES['sim']: {'ball_color': [1.0, 1.0, 1.0, 1.0], 'camera_rate': 5.0},
        NODES['vision']: {'detector': 'learned'}}),
    'ur3_slow_camera.yaml': (['port:=0'], {
        NODES['sim']: {'robot_model': 'ur3', 'camera_rate': 10.0},
        NODES['vision']: {'detector': 'color'}}),
}


@pytest.mark.parametrize('example', sorted(EXAMPLE_RUNS))
def test_an_example_params_file_works_as_it_is(ros_graph, tmp_path, example):
    """The example's parameters reach the nodes and the ball is found; the pages both serve."""
    arguments, expected = EXAMPLE_RUNS[example]
    view3d = 'view3d:=true' in arguments
    port = free_port_pair()
    if view3d:  # the viewer's port given, the 3D view's by default
        arguments = [*arguments, f'port:={port}']
    probe = ros_graph.node('probe')
    positions: list[PointStamped] = []
    probe.create_subscription(PointStamped, 'ball/position', positions.append,
                              qos_profile_sensor_data)
    log_path = tmp_path / 'run.log'
    with log_path.open('w') as log:
        run = subprocess.Popen(
            [str(ROOT / 'scripts/run'), f'params_file:={EXAMPLES / example}', *arguments],
            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=ros_graph.env)
    try:
        wait_for(lambda: positions or run.poll() is not None, 180.0, 'a ball position')
        assert run.poll() is None, f'the graph ended:\n{log_path.read_text()}'
        for node, values in expected.items():
            assert node_parameters(probe, node, list(values)) == values, node
        if view3d:
            pages = (f'live view of /ball/image at http://127.0.0.1:{port}/',
                     f'3D view at http://127.0.0.1:{port + 1}/')
            wait_for(lambda: all(page in log_path.read_text() for page in pages), 60.0,
                     'both pages served')
            for url in (f'http://127.0.0.1:{port}/', f'http://127.0.0.1:{port + 1}/'):
                with urllib.request.urlopen(url, timeout=10) as page:
                    assert page.status == 200, url
        run.send_signal(signal.SIGTERM)
        assert run.wait(timeout=60) == 0, log_path.read_text()
    finally:
        run.kill()
    assert 'Traceback' not in log_path.read_text()


def pick(controller: int, log_path: Path, positions: list) -> int:
    """Press g until a pick succeeds; return the number of screen lines before that press.

    A pick asked before the motion node has the sim's frames is refused at once (a warning
    on the screen), and g before keys has found motion's action is refused by keys ('not
    ready yet: waiting for motion'); it is asked again once the next ball position has come.
    """
    answers = ('/pick_ball: ', 'not ready yet: ')
    deadline = time.monotonic() + 180.0
    while True:
        before = len(log_path.read_text().splitlines())
        os.write(controller, b'g')
        wait_for(lambda before=before: any(line.startswith(answers) for line in
                                           log_path.read_text().splitlines()[before:]),
                 120.0, "the pick's outcome line")
        added = log_path.read_text().splitlines()[before:]
        outcome = next(line for line in added if line.startswith(answers))
        if outcome.startswith('/pick_ball: done') or time.monotonic() > deadline:
            return before
        seen = len(positions)
        wait_for(lambda seen=seen: len(positions) > seen, 30.0, 'the next ball position')


def place_ball(probe: Node, position: list[float]) -> None:
    """Move the ball to ``position`` (world frame) through the sim's ``ball_position``."""
    sim = AsyncParameterClient(probe, NODES['sim'])
    assert sim.wait_for_services(timeout_sec=30.0)
    future = sim.set_parameters([Parameter('ball_position', value=position)])
    wait_for(future.done, 30.0, 'ball_position set')
    assert all(result.successful for result in future.result().results), future.result()


def policy_episode(probe: Node, env: dict[str, str], log_path: Path) -> None:
    """Run one episode of the shipped Pick policy from a policy node beside the graph."""
    driving: list[bool] = []
    probe.create_subscription(Bool, 'policy/driving', lambda message: driving.append(
        message.data), LATCHED_QOS)
    run_episode = probe.create_client(Trigger, 'policy/run')
    with log_path.open('w') as log:
        policy = subprocess.Popen(
            ['ros2', 'run', 'ur_rg2_learning', 'policy', '--ros-args', '-p', 'policy_dir:=pick'],
            stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    try:
        wait_for(lambda: run_episode.service_is_ready() or policy.poll() is not None, 60.0,
                 'the policy node')
        assert policy.poll() is None, log_path.read_text()
        future = run_episode.call_async(Trigger.Request())
        wait_for(future.done, 30.0, 'policy/run')
        assert future.result().success, future.result().message
        wait_for(lambda: True in driving and driving[-1] is False, 120.0, 'the episode ended')
    finally:
        # Ctrl-C in its terminal: ros2 run and the node both get SIGINT.
        os.killpg(policy.pid, signal.SIGINT)
        try:
            policy.wait(timeout=30)
        finally:
            policy.kill()


@pytest.mark.parametrize('quit_key', [b'p', b'\x03'], ids=['pick-then-p', 'ctrl-c'])
def test_in_a_terminal_keys_runs_in_the_foreground_and_quitting_stops_all(
        ros_graph, tmp_path, quit_key):
    """The terminal shows keys' lines only; with p, after a pick (g) and a policy episode.

    Their goals end quietly: the nodes' routine lines go to the log file; the episode's
    outcome is one line of keys'.
    """
    probe = ros_graph.node('probe')
    positions: list[PointStamped] = []
    probe.create_subscription(PointStamped, 'ball/position', positions.append,
                              qos_profile_sensor_data)
    controller, terminal = open_terminal()
    before = termios.tcgetattr(terminal)
    log_path = tmp_path / 'run.log'
    try:
        with log_path.open('w') as log:
            run = subprocess.Popen(
                [str(ROOT / 'scripts/run'), 'port:=0', 'camera_rate:=10.0'], stdin=terminal,
                stdout=log, stderr=subprocess.STDOUT, env=ros_graph.env,
                preexec_fn=become_terminal_session_leader)
        try:
            wait_for(lambda: nodes_ready(probe, interactive=True) or run.poll() is not None,
                     180.0, 'all nodes, keys too')
            assert run.poll() is None, log_path.read_text()
            wait_for(lambda: 'keyboard teleop' in log_path.read_text(), 10.0, 'the key table')
            if quit_key == b'p':
                wait_for(lambda: positions, 60.0, 'the ball seen')
                # The motion node's frames come from the sim's latched topics, the ball from
                # vision: the one may reach it later than the other arrives here.
                log_file = Path(re.search(r'the log of every node is in (\S+)',
                                          log_path.read_text()).group(1))
                wait_for(lambda: 'ur_rg2_motion]: ready:' in log_file.read_text(), 60.0,
                         'the motion node ready')
                picked = pick(controller, log_path, positions)
                # The arm home (l), the ball back where it started, in view.
                os.write(controller, b'l')
                wait_for(lambda: '/reset: done' in log_path.read_text(), 60.0, 'the reset')
                place_ball(probe, EPISODE_BALL)
                seen = len(positions)  # frames from before the move may still come
                wait_for(lambda: len(positions) > seen + 6, 30.0, 'the ball seen at its place')
                before_episode = len(log_path.read_text().splitlines())
                policy_episode(probe, ros_graph.env, tmp_path / 'policy.log')
                wait_for(lambda: 'policy episode: ' in log_path.read_text(), 10.0,
                         "the episode's outcome in the keys terminal")
            os.write(controller, quit_key)
            assert run.wait(timeout=20) == 0, log_path.read_text()
        finally:
            run.kill()
        assert termios.tcgetattr(terminal) == before
    finally:
        os.close(controller)
        os.close(terminal)
    screen = log_path.read_text()
    assert 'keyboard teleop' in screen
    # keys' screen: keys' own lines, the log's path at start and on exit, nothing routine.
    log_files = re.findall(r'^bringup: the log of every node is in (\S+)$', screen, re.MULTILINE)
    assert len(log_files) == 1, screen
    assert f'bringup: graph stopped; its log: {log_files[0]}' in screen
    for routine in ('[INFO]', 'ctrl-c (SIGINT)', 'process started', 'Traceback'):
        assert routine not in screen, screen
    if quit_key == b'p':
        # From the key press that picked the ball on: keys' outcome line, angles, the exit.
        after = screen.splitlines()[picked:]
        assert any(line.startswith('/pick_ball: done: picked the ball') for line in after), (
            screen)
        assert all(line.startswith(('/pick_ball: ', '/pick_ball ... ', '/reset: done',
                                    'joint mode | ', 'policy episode: ', 'ready',
                                    'bringup: graph stopped'))
                   for line in after), screen
        # The policy episode, driven from outside the keys terminal, adds its outcome line
        # (policy/result), none of the policy node's or the controllers' own lines.
        during = screen.splitlines()[before_episode:]
        assert all(line.startswith(('joint mode | ', 'policy episode: ', 'bringup: graph stopped'))
                   for line in during), screen
        outcomes = [line for line in during if line.startswith('policy episode: ')]
        assert len(outcomes) == 1 and re.match(r'policy episode: (done|FAILED): .*\(\d+\.\d s\)$',
                                               outcomes[0]), screen
    else:
        assert not re.search(r'^\[(sim|vision|motion|viewer)-\d+\]', screen, re.MULTILINE), (
            screen)
    assert_every_node_stopped_cleanly(Path(log_files[0]).read_text())


def test_a_node_that_dies_is_named_with_its_error_on_the_last_line(ros_graph, tmp_path):
    log_path = tmp_path / 'run.log'
    with log_path.open('w') as log:
        run = subprocess.Popen([str(ROOT / 'scripts/run'), 'camera_rate:=fast', 'port:=0'],
                               stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                               env=ros_graph.env)
    try:
        assert run.wait(timeout=180) == 1, log_path.read_text()
    finally:
        run.kill()
    output = log_path.read_text()
    # The sim's own FATAL line, launch's stop reason, the others stopping, then the summary.
    assert re.search(r"\[sim-\d+\] \[FATAL\] .*\[ur_rg2_sim\]: invalid parameter: "
                     r".*'camera_rate'.*'fast'", output), output
    assert '[ERROR] [graph.launch.py]: sim exited with code 2; stopping the graph' in output
    assert output.splitlines()[-1] == 'bringup: sim exited with code 2', output
    assert 'Traceback' not in output
