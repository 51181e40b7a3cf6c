"""ROS 2's own tools against the graph: ros2 launch, ros2 run, ros2 topic|param|service|action.

What a ROS user types in their first five minutes, on the pip path. One graph for the module,
started with ``ros2 launch`` in a session of its own (as from a terminal) on a private domain,
with the ``ros2`` daemon running for that domain as it does for users.
"""

from collections.abc import Iterator
import os
import re
import signal
import subprocess
import time

from conftest import next_domain_id, wait_for
import pytest
from test_bringup import ROOT, argument_values
import yaml

ARM_JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint']
# Parameters rclpy declares on every node by itself.
_ROS_OWN = re.compile(r'use_sim_time|start_type_description_service|qos_overrides\..*')
CLI_TIMEOUT_S = 60.0
# The graph's nodes: launch's process name and the ROS node name.
NODES = {'sim': 'ur_rg2_sim', 'vision': 'ur_rg2_vision', 'motion': 'ur_rg2_motion',
         'viewer': 'ur_rg2_viewer'}
PARAMS_FILE = ROOT / 'ros2_ws/src/ur_rg2_bringup/config/graph.yaml'


class Launched:
    """A ``ros2 launch`` (or ``ros2 run``) process, its output collected in a file."""

    def __init__(self, argv: list[str], env: dict[str, str], log_path) -> None:
        self.log_path = log_path
        with log_path.open('w') as log:
            # A session of its own, like a terminal's job: Ctrl-C is SIGINT to the group.
            self.process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log,
                                            stderr=subprocess.STDOUT, env=env,
                                            start_new_session=True)

    @property
    def output(self) -> str:
        return self.log_path.read_text()

    def ctrl_c(self, times: int = 1) -> None:
        """SIGINT to the whole process group, as a terminal sends it on Ctrl-C.

        Several times 0.2 s apart, as a user presses it again: a spacing, not a wait.
        """
        for press in range(times):
            if press:
                time.sleep(0.2)
            os.killpg(self.process.pid, signal.SIGINT)

    def wait(self, timeout: float) -> int:
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            raise AssertionError(f'still running after {timeout} s:\n{self.output}') from None

    def kill(self) -> None:
        try:
            os.killpg(self.process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.process.wait()


def ros2(env: dict[str, str], *args: str, timeout: float = CLI_TIMEOUT_S) -> str:
    """Run one ``ros2`` command; return its output, failing the test on a non-zero exit."""
    done = subprocess.run(['ros2', *args], env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, f'ros2 {" ".join(args)}:\n{done.stdout}{done.stderr}'
    return done.stdout


@pytest.fixture(scope='module')
def env() -> Iterator[dict[str, str]]:
    """Environment of a private domain, with the ros2 daemon for it."""
    environment = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
                       ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    ros2(environment, 'daemon', 'start')
    try:
        yield environment
    finally:
        subprocess.run(['ros2', 'daemon', 'stop'], env=environment, capture_output=True,
                       timeout=CLI_TIMEOUT_S)


@pytest.fixture(scope='module')
def graph(env, tmp_path_factory) -> Iterator[Launched]:
    """``ros2 launch ur_rg2_bringup graph.launch.py camera_rate:=15.0``, all four nodes up.

    With a copy of the shipped parameters file: frames elsewhere, a lower lift.
    """
    params = yaml.safe_load(PARAMS_FILE.read_text())
    params['/**/ur_rg2_vision']['ros__parameters']['frames_dir'] = str(
        tmp_path_factory.mktemp('frames'))
    params['/**/ur_rg2_motion']['ros__parameters']['lift_height'] = 0.12
    params_file = tmp_path_factory.mktemp('params') / 'graph.yaml'
    params_file.write_text(yaml.safe_dump(params))
    launched = Launched(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py',
                         'camera_rate:=15.0', 'port:=0', f'params_file:={params_file}'],
                        env, tmp_path_factory.mktemp('launch') / 'launch.log')
    launched.params = params
    try:
        expected = {f'/{name}' for name in NODES.values()}

        def all_nodes() -> bool:
            assert launched.process.poll() is None, launched.output
            return expected <= set(ros2(env, 'node', 'list').split())

        wait_for(all_nodes, 180.0, f'ros2 node list to show {sorted(expected)}', interval=1.0)
        yield launched
    finally:
        launched.kill()


def test_ros2_node_list_shows_the_four_nodes(graph, env):
    assert {'/ur_rg2_sim', '/ur_rg2_vision', '/ur_rg2_motion', '/ur_rg2_viewer'} <= set(
        ros2(env, 'node', 'list').split())


def test_topic_echo_once_joint_states(graph, env):
    message = ros2(env, 'topic', 'echo', '--once', '/joint_states')
    names = re.search(r'name:\n((?:- .*\n)+)', message).group(1)
    assert [line[2:] for line in names.splitlines()][:6] == ARM_JOINTS


def test_topic_hz_joint_states(graph, env):
    hz = subprocess.Popen(['ros2', 'topic', 'hz', '/joint_states'], env=env,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + CLI_TIMEOUT_S
        rate = None
        while rate is None and time.monotonic() < deadline:
            line = hz.stdout.readline()
            found = re.search(r'average rate: ([\d.]+)', line)
            rate = float(found.group(1)) if found else None
    finally:
        hz.send_signal(signal.SIGINT)
        hz.wait(timeout=CLI_TIMEOUT_S)
    # 100 Hz of simulation time; the benchmark measures it, a loaded machine slows the sim.
    assert rate is not None and rate > 10.0


def test_every_node_runs_with_the_params_file_and_the_launch_arguments_over_it(graph, env):
    """Each node declares exactly the parameters of its section, at the file's values.

    Before a test changes a parameter.
    """
    for name in NODES.values():
        dumped = yaml.safe_load(ros2(env, 'param', 'dump', f'/{name}'))
        running = {key: value for key, value in dumped[f'/{name}']['ros__parameters'].items()
                   if not _ROS_OWN.fullmatch(key)}
        expected = dict(graph.params[f'/**/{name}']['ros__parameters'])
        # The launch arguments given, and the detector, which the launch file sets.
        expected.update({'ur_rg2_sim': {'camera_rate': 15.0},
                         'ur_rg2_vision': {'detector': argument_values()['detector']},
                         'ur_rg2_viewer': {'port': 0}}.get(name, {}))
        assert running == expected, name
    assert 'Double value is: 0.12' in ros2(env, 'param', 'get', '/ur_rg2_motion', 'lift_height')


def test_param_get_and_set_with_an_integer(graph, env):
    # The launch argument reached the sim.
    assert 'Double value is: 15.0' in ros2(env, 'param', 'get', '/ur_rg2_sim', 'camera_rate')
    assert 'Set parameter successful' in ros2(env, 'param', 'set', '/ur_rg2_sim',
                                               'camera_rate', '20')
    assert 'Double value is: 20.0' in ros2(env, 'param', 'get', '/ur_rg2_sim', 'camera_rate')


def test_service_call_gripper_close(graph, env):
    response = ros2(env, 'service', 'call', '/gripper/close', 'std_srvs/srv/Trigger')
    assert 'success=True' in response, response


def test_action_send_goal_trajectory_and_gripper(graph, env):
    goal = ('{trajectory: {joint_names: [shoulder_pan_joint, elbow_joint], points: '
            '[{positions: [0.3, -0.2], time_from_start: {sec: 2}}]}}')
    result = ros2(env, 'action', 'send_goal',
                  '/joint_trajectory_controller/follow_joint_trajectory',
                  'control_msgs/action/FollowJointTrajectory', goal)
    assert 'Goal finished with status: SUCCEEDED' in result, result
    result = ros2(env, 'action', 'send_goal', '/gripper_controller/gripper_cmd',
                  'control_msgs/action/GripperCommand',
                  '{command: {position: 0.05, max_effort: 20.0}}')
    assert 'Goal finished with status: SUCCEEDED' in result, result
    assert 'reached_goal: true' in result, result


def test_interface_show_of_the_built_message_packages(env):
    shown = ros2(env, 'interface', 'show', 'control_msgs/action/GripperCommand')
    assert 'float64 max_effort' in shown
    assert 'ur_rg2_bringup graph' in ros2(env, 'pkg', 'executables', 'ur_rg2_bringup')


def test_ctrl_c_stops_the_launched_graph_cleanly(graph):
    graph.ctrl_c()  # SIGINT to launch and every node at once, as a terminal sends it
    assert graph.wait(timeout=60) == 0
    output = graph.output
    for name in NODES:
        assert re.search(rf'\[{name}-\d+\]: process has finished cleanly', output), output
    assert '[ERROR]' not in output
    # launch's own clock: a node still running 5 s after SIGINT would be escalated.
    assert 'failed to terminate' not in output
    assert 'process has died' not in output
    assert 'Traceback' not in output


@pytest.mark.parametrize('stop', ['ctrl-c', 'ctrl-c twice', 'sigterm'])
def test_ros2_run_sim_exits_0_without_a_traceback(stop, tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    run = Launched(['ros2', 'run', 'ur_rg2_sim', 'sim', '--ros-args', '-p', 'camera_rate:=0.0'],
                   env, tmp_path / 'run.log')
    try:
        wait_for(lambda: 'simulating' in run.output or run.process.poll() is not None, 120.0,
                 'the sim to start')
        assert run.process.poll() is None, run.output
        if stop == 'sigterm':  # as launch escalates, or a service manager stops it
            sim = subprocess.run(['pgrep', '-P', str(run.process.pid)], capture_output=True,
                                 text=True, check=True).stdout.split()
            os.kill(int(sim[0]), signal.SIGTERM)
        else:
            run.ctrl_c(times=2 if stop == 'ctrl-c twice' else 1)
        assert run.wait(timeout=60) == 0, run.output
    finally:
        run.kill()
    assert 'Traceback' not in run.output


def test_a_launch_argument_of_the_wrong_type_ends_with_the_nodes_reason(tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    launched = Launched(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py',
                         'camera_rate:=fast', 'port:=0'], env, tmp_path / 'launch.log')
    try:
        launched.wait(timeout=180)
    finally:
        launched.kill()
    output = launched.output
    assert re.search(r"\[sim-\d+\] \[FATAL\] .*\[ur_rg2_sim\]: invalid parameter: "
                     r".*'camera_rate'.*'fast'", output), output
    assert '[ERROR] [graph.launch.py]: sim exited with code 2; stopping the graph' in output
    assert 'Traceback' not in output


def test_use_sim_false_starts_the_graph_without_the_simulator(tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(next_domain_id()),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    launched = Launched(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py', 'use_sim:=false',
                         'port:=0'], env, tmp_path / 'launch.log')
    try:
        wait_for(lambda: len(re.findall(r'process started with pid', launched.output)) == 3
                 or launched.process.poll() is not None, 120.0, 'three nodes')
        wait_for(lambda: 'live view of' in launched.output, 120.0, 'the viewer')
        assert launched.process.poll() is None, launched.output
        launched.ctrl_c()
        assert launched.wait(timeout=60) == 0
    finally:
        launched.kill()
    output = launched.output
    assert '[sim-' not in output
    for name in ('vision', 'motion', 'viewer'):
        assert re.search(rf'\[{name}-\d+\]: process has finished cleanly', output), output
    assert 'Traceback' not in output
