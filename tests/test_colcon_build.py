"""The ROS-native path: ``colcon build`` of ros2_ws, then the installed ``sim`` runs from it.

colcon runs from the venv with the pip rclpy, as a ROS user's workspace would on top of
/opt/ros: the build is a copy of ros2_ws in a temporary directory, so nothing lands in the tree.
"""

import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

from conftest import wait_for
import pytest
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

ROOT = Path(__file__).resolve().parents[1]
# The contract's executables; every other console script a package declares is checked too.
EXECUTABLES = {'ur_rg2_sim': 'sim', 'ur_rg2_teleop': 'keys', 'ur_rg2_vision': 'vision',
               'ur_rg2_motion': 'motion', 'ur_rg2_learning': 'policy',
               'ur_rg2_bringup': 'graph'}
ARM_JOINTS = ['shoulder_pan_joint', 'shoulder_lift_joint', 'elbow_joint', 'wrist_1_joint',
              'wrist_2_joint', 'wrist_3_joint']


def in_workspace(ws: Path, *command: str) -> list[str]:
    """Return argv that runs ``command`` with ``install/setup.sh`` sourced, like a ROS user."""
    return ['bash', '-c', f'source "{ws}/install/setup.sh" && exec "$@"', 'bash', *command]


@pytest.fixture(scope='module')
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build a copy of ros2_ws with colcon; return the workspace directory."""
    colcon = Path(sys.executable).with_name('colcon')
    if not colcon.exists():
        pytest.fail(f'{colcon} is missing: run scripts/bootstrap requirements-dev.txt')
    ws = tmp_path_factory.mktemp('ws')
    shutil.copytree(ROOT / 'ros2_ws' / 'src', ws / 'src', ignore=shutil.ignore_patterns(
        '__pycache__', '*.egg-info', '.pytest_cache', 'build', 'install', 'log'))
    started = time.monotonic()
    build = subprocess.run(
        [str(colcon), '--log-base', 'log', 'build', '--event-handlers', 'console_direct-'],
        cwd=ws, capture_output=True, text=True, timeout=240,
        env=dict(os.environ, COLCON_HOME=str(ws / '.colcon')))  # ignore the user's defaults
    assert build.returncode == 0, f'colcon build failed:\n{build.stdout}\n{build.stderr}'
    print(f'colcon build of {len(EXECUTABLES)} packages: {time.monotonic() - started:.1f} s')
    return ws


@pytest.mark.parametrize('package', sorted(EXECUTABLES))
def test_colcon_installs_executables_and_the_ament_index(workspace, package):
    prefix = workspace / 'install' / package
    marker = prefix / 'share/ament_index/resource_index/packages' / package
    assert marker.is_file(), f'{package} is not in the ament index'
    manifest = prefix / 'share' / package / 'package.xml'
    assert manifest.read_text() == (ROOT / 'ros2_ws/src' / package / 'package.xml').read_text()

    egg_info, = (prefix / 'lib').glob('python3.*/site-packages/*.egg-info')
    declared = [line.split('=')[0].strip()
                for line in (egg_info / 'entry_points.txt').read_text().splitlines()
                if '=' in line]
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
