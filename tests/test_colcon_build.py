"""The ROS-native path: ``colcon build`` of ros2_ws, then the installed ``sim`` runs from it.

colcon runs from the venv with the pip rclpy, as a ROS user's workspace would on top of
/opt/ros: the build is a copy of ros2_ws in a temporary directory, so nothing lands in the tree.
The one ament_cmake package, ur_rg2_interfaces, is generated with the venv's PyPI ROS wheels as
scripts/build-interfaces builds it (the same CMake options).
Every package but the sim is built first on its own and its nodes start with neither the sim
nor pybullet importable, as on a real robot's computer.
"""

import json
import os
from pathlib import Path
import select
import shutil
import signal
import subprocess
import sys
import time

from conftest import wait_for
import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / 'ros2_ws' / 'src'
PACKAGES = sorted(manifest.parent.name for manifest in SRC.glob('*/package.xml'))
SIM = 'ur_rg2_sim'
# The contract's executables; every other console script a package declares is checked too.
EXECUTABLES = {'ur_rg2_sim': 'sim', 'ur_rg2_teleop': 'keys', 'ur_rg2_vision': 'vision',
               'ur_rg2_motion': 'motion', 'ur_rg2_learning': 'policy',
               'ur_rg2_bringup': 'graph', 'ur_rg2_tools': 'record',
               'ur_rg2_hardware': 'rg2_adapter'}
ARM_JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint']
# The nodes a real robot's graph runs (all but the sim): package, executable, node name, one
# parameter it declares, and its arguments.
OFF_SIM_NODES = [
    ('ur_rg2_motion', 'motion', 'ur_rg2_motion', 'lift_height', ()),
    ('ur_rg2_vision', 'vision', 'ur_rg2_vision', 'frames_dir', ()),
    ('ur_rg2_vision', 'viewer', 'ur_rg2_viewer', 'port', ('-p', 'port:=0')),
    ('ur_rg2_learning', 'policy', 'ur_rg2_policy', 'policy_dir', ()),
    ('ur_rg2_teleop', 'keys', 'ur_rg2_teleop', 'step_deg', ()),
    ('ur_rg2_tools', 'view3d', 'ur_rg2_view3d', 'cloud_step', ('-p', 'port:=0')),
    ('ur_rg2_hardware', 'rg2_adapter', 'ur_rg2_rg2_adapter', 'goal_timeout', ()),
]
# A sitecustomize that makes the sim and pybullet unimportable (the venv has both).
HIDE_SIM = """import sys


class HideSim:
    def find_spec(self, name, path=None, target=None):
        if name.partition('.')[0] in ('pybullet', 'pybullet_data', 'ur_rg2_sim'):
            raise ModuleNotFoundError(f'No module named {name!r} (hidden by the test)',
                                      name=name)
        return None


sys.meta_path.insert(0, HideSim())
"""
STARTUP_TIMEOUT = 60.0  # s: five nodes importing rclpy at once on a loaded 2-core machine
# What scripts/build-interfaces gives CMake for the PyPI ROS wheels (a ROS install needs none).
PIP_CMAKE_ARGS = (
    f'-DCMAKE_PROJECT_INCLUDE={ROOT}/interfaces/cmake/pypi_wheels.cmake',
    f'-DPython3_EXECUTABLE={sys.executable}', '-DBUILD_TESTING=OFF')


def in_workspace(ws: Path, *command: str) -> list[str]:
    """Return argv that runs ``command`` with ``install/setup.sh`` sourced, like a ROS user."""
    return ['bash', '-c', f'source "{ws}/install/setup.sh" && exec "$@"', 'bash', *command]


def colcon_build(ws: Path, *options: str) -> None:
    """Run ``colcon build`` in ``ws`` with ``options``; fail the test with its output."""
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        pytest.fail(f'{colcon} is missing: run scripts/bootstrap requirements-dev.txt')
    started = time.monotonic()
    build = subprocess.run(
        [str(colcon), '--log-base', 'log', 'build', *options,
         '--event-handlers', 'console_direct-', '--cmake-args', *PIP_CMAKE_ARGS],
        cwd=ws, capture_output=True, text=True, timeout=240,
        env=dict(os.environ, COLCON_HOME=str(ws / '.colcon')))  # ignore the user's defaults
    assert build.returncode == 0, f'colcon build failed:\n{build.stdout}\n{build.stderr}'
    print(f'colcon build {" ".join(options)}: {time.monotonic() - started:.1f} s')


def copy_package(package: str, ws: Path) -> None:
    """Copy the source of ``package`` into ``ws/src``, without build products."""
    shutil.copytree(SRC / package, ws / 'src' / package, ignore=shutil.ignore_patterns(
        '__pycache__', '*.egg-info', '.pytest_cache', 'build', 'install', 'log'))


@pytest.fixture(scope='module')
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build a copy of ros2_ws with colcon; return the workspace directory.

    Every package but the sim first, alone: none of them may need the sim to build. Then the
    sim joins the workspace and only it is built.
    """
    ws = tmp_path_factory.mktemp('ws')
    for package in PACKAGES:
        if package != SIM:
            copy_package(package, ws)
    colcon_build(ws)
    assert not (ws / 'install' / SIM).exists()
    copy_package(SIM, ws)
    colcon_build(ws, '--base-paths', f'src/{SIM}')
    return ws


def test_every_package_is_built():
    assert {'ur_rg2_common', SIM, *EXECUTABLES} <= set(PACKAGES)


@pytest.mark.parametrize('package', PACKAGES)
def test_colcon_installs_executables_and_the_ament_index(workspace, package):
    prefix = workspace / 'install' / package
    marker = prefix / 'share/ament_index/resource_index/packages' / package
    assert marker.is_file(), f'{package} is not in the ament index'
    manifest = prefix / 'share' / package / 'package.xml'
    assert manifest.read_text() == (ROOT / 'ros2_ws/src' / package / 'package.xml').read_text()

    egg_info, = (prefix / 'lib').glob('python3.*/site-packages/*.egg-info')
    entry_points = egg_info / 'entry_points.txt'
    lines = entry_points.read_text().splitlines() if entry_points.exists() else []
    declared = [line.split('=')[0].strip() for line in lines if '=' in line]
    if package in EXECUTABLES:
        assert EXECUTABLES[package] in declared
    for executable in declared:
        path = prefix / 'lib' / package / executable
        assert os.access(path, os.X_OK), f'{path} is not installed'
        # colcon built with the venv's python, so the scripts run with the pip rclpy.
        assert path.read_text().splitlines()[0] == f'#!{sys.executable}'


def test_sourced_install_resolves_packages_from_it_and_rclpy_from_the_venv(workspace):
    probe = ('import json, rclpy, ur_rg2_sim\n'
             'from ament_index_python.packages import get_package_prefix\n'
             'print(json.dumps([get_package_prefix("ur_rg2_sim"), ur_rg2_sim.__file__,'
             ' rclpy.__file__]))')
    out = subprocess.run(in_workspace(workspace, sys.executable, '-c', probe),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    prefix, module, rclpy_module = json.loads(out.stdout)
    assert prefix == str(workspace / 'install/ur_rg2_sim')
    # The installed copy, not the venv's editable install of the source tree.
    assert Path(module).is_relative_to(workspace / 'install/ur_rg2_sim/lib')
    assert Path(rclpy_module).is_relative_to(sys.prefix)


def test_ros2_launch_finds_the_installed_launch_file(workspace):
    prefix = subprocess.run(in_workspace(workspace, 'ros2', 'pkg', 'prefix', 'ur_rg2_bringup'),
                            capture_output=True, text=True, timeout=60)
    assert prefix.stdout.strip() == str(workspace / 'install/ur_rg2_bringup'), prefix.stderr
    shown = subprocess.run(in_workspace(workspace, 'ros2', 'launch', 'ur_rg2_bringup',
                                        'graph.launch.py', '--show-args'),
                           capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    assert "'camera_rate':" in shown.stdout and "'namespace':" in shown.stdout


def test_install_carries_the_shipped_policy(workspace):
    probe = ('from ur_rg2_learning.actor import Actor\n'
             'from ur_rg2_learning.policy_node import shipped_policy\n'
             'print(shipped_policy()); print(Actor.load(shipped_policy()).env_id)')
    out = subprocess.run(in_workspace(workspace, sys.executable, '-c', probe),
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    directory, env_id = out.stdout.split()
    assert Path(directory).is_relative_to(workspace / 'install/ur_rg2_learning/lib')
    assert env_id == 'UrRg2Reach-v0'


def test_install_carries_the_arm_meshes(workspace):
    """robot_description's package://ur_rg2_sim/meshes/... resolve in the install."""
    meshes = workspace / 'install' / SIM / 'share' / SIM / 'meshes'
    assert (meshes / 'PROVENANCE.md').is_file()
    for model in ('ur3', 'ur5'):
        assert sorted(file.name for file in (meshes / model).glob('*.obj')) == sorted(
            file.name for file in (SRC / SIM / 'meshes' / model).glob('*.obj')), model
    assert len(list(meshes.glob('*/*.obj'))) == 14


def test_installed_sim_publishes_joint_states(workspace, ros_graph, tmp_path):
    received: list[JointState] = []
    ros_graph.node('listener').create_subscription(
        JointState, 'joint_states', received.append, qos_profile_sensor_data)
    sim = workspace / 'install/ur_rg2_sim/lib/ur_rg2_sim/sim'
    log = (tmp_path / 'sim.log').open('w+')
    proc = subprocess.Popen(
        in_workspace(workspace, str(sim), '--ros-args', '-p', 'real_time_factor:=0.0',
                     '-p', 'camera_rate:=0.0'),
        env=ros_graph.env, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_for(lambda: received or proc.poll() is not None, 45.0,
                 'joint_states from the installed sim')
        assert proc.poll() is None, f'sim exited:\n{Path(log.name).read_text()}'
        assert received[-1].name[:6] == ARM_JOINTS
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()
        log.close()
    assert 'Traceback' not in Path(log.name).read_text()


class NodeProcess:
    """An installed node executable running from the workspace, its output kept.

    ``keys`` needs a terminal: it gets a pseudo-terminal, read whenever the test looks.
    """

    def __init__(self, ws: Path, package: str, executable: str, args: tuple[str, ...],
                 env: dict[str, str], log: Path) -> None:
        self.terminal = os.openpty() if executable == 'keys' else None
        command = in_workspace(ws, str(ws / 'install' / package / 'lib' / package / executable),
                               '--ros-args', *args)
        self.log = log
        with log.open('w') as log_file:
            output = self.terminal[1] if self.terminal else log_file
            self.process = subprocess.Popen(command, env=env, stdin=output, stdout=output,
                                            stderr=output, start_new_session=True)

    def output(self) -> str:
        """Return what the node wrote so far."""
        if self.terminal:
            master, _ = self.terminal
            with self.log.open('a') as log:
                while select.select([master], [], [], 0)[0]:
                    log.write(os.read(master, 65536).decode(errors='replace'))
        return self.log.read_text()

    def exited(self) -> bool:
        """Return whether the process has ended (reading its terminal meanwhile)."""
        self.output()
        return self.process.poll() is not None

    def stop(self) -> None:
        """Ask the node to quit as a user would: ``p`` for keys, Ctrl-C (SIGINT) for the rest."""
        if self.terminal:
            os.write(self.terminal[0], b'p')
        else:
            self.process.send_signal(signal.SIGINT)

    def close(self) -> None:
        """Kill the process if it still runs, and close its terminal."""
        self.process.kill()
        self.process.wait(timeout=10)
        if self.terminal:
            for fd in self.terminal:
                os.close(fd)


def test_nodes_start_without_the_sim_or_pybullet(workspace, ros_graph, tmp_path):
    hidden = tmp_path / 'hide_sim'
    hidden.mkdir()
    (hidden / 'sitecustomize.py').write_text(HIDE_SIM)
    env = dict(ros_graph.env, PYTHONPATH=os.pathsep.join(
        filter(None, [str(hidden), os.environ.get('PYTHONPATH')])))
    for module in ('pybullet', 'ur_rg2_sim'):
        check = subprocess.run(in_workspace(workspace, sys.executable, '-c', f'import {module}'),
                               env=env, capture_output=True, text=True, timeout=60)
        assert 'hidden by the test' in check.stderr, check.stderr

    nodes = {}
    try:
        for package, executable, node, _, args in OFF_SIM_NODES:
            nodes[node] = NodeProcess(workspace, package, executable, args, env,
                                      tmp_path / f'{executable}.log')
        # Started: each node answers for a parameter it declares, through its service.
        probe = ros_graph.node('probe')
        for _, _, name, parameter, _ in OFF_SIM_NODES:
            node = nodes[name]
            client = probe.create_client(GetParameters, f'/{name}/get_parameters')
            # B023: the lambda is called before the loop moves on to the next node.
            wait_for(lambda: client.service_is_ready() or node.exited(),  # noqa: B023
                     STARTUP_TIMEOUT, f'{name} to start')
            assert not node.exited(), f'{name} exited:\n{node.output()}'
            future = client.call_async(GetParameters.Request(names=[parameter]))
            wait_for(future.done, STARTUP_TIMEOUT, f'{name} to answer get_parameters')
            value, = future.result().values
            assert value.type != ParameterType.PARAMETER_NOT_SET, f'{name} lacks {parameter}'
        for node in nodes.values():
            node.stop()
        for name, node in nodes.items():
            wait_for(node.exited, 15.0, f'{name} to stop')
            assert node.process.returncode == 0, (
                f'{name}: exit code {node.process.returncode}\n{node.output()}')
            assert 'Traceback' not in node.output(), node.output()
    finally:
        for node in nodes.values():
            node.close()
