"""Benchmark of the set-up: the message build, and the install of ROS 2's own tools.

The ROS wheels are already in the venv (bootstrap ran), so the message build is the part of a
fresh set-up that the pip cache does not save: ``scripts/build-interfaces --force`` builds
tf2_msgs, control_msgs, composition_interfaces and ur_rg2_interfaces from clean into a
temporary prefix, leaving the venv's own install alone. The tools (ros2cli, launch,
launch_ros: requirements-ros-tools.txt) install from their local wheels into a temporary
directory, as bootstrap installs them into the venv. Run alone with
``python -m bench.setup_bench``.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import resource
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
# Our own budget: the packages' generated C and Python on one 2-core machine, idle.
TARGET_S = 60.0
TOOLS_TARGET_S = 30.0
TOOLS = ROOT / 'requirements-ros-tools.txt'
TOOL_WHEELS = Path(os.environ.get('ROS_TOOLS_WHEELS', ROOT.parent / 'shared' / 'ros-tools'))


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _tools_row() -> tuple[str, str, str]:
    """Time installing ROS 2's tools from their wheels, as bootstrap does; measure their size."""
    pins = [f'{name}=={tag}' for name, tag in re.findall(
        r'^(\w+) @ git\+[^@]*@([\d.]+)', TOOLS.read_text(), re.MULTILINE)]
    with tempfile.TemporaryDirectory(prefix='tools-bench-') as target:
        started = time.monotonic()
        subprocess.run([sys.executable, '-m', 'pip', 'install', '--disable-pip-version-check',
                        '-q', '--no-deps', '--no-index', '--find-links', str(TOOL_WHEELS),
                        '--target', target, *pins], check=True, capture_output=True)
        elapsed = time.monotonic() - started
        size = sum(f.stat().st_size for f in Path(target).rglob('*') if f.is_file())
    return (f"set-up: ROS 2's own tools ({len(pins)} wheels: ros2cli, launch, launch_ros)",
            f'{elapsed:.1f} s, {size / 2 ** 20:.1f} MiB (load {os.getloadavg()[0]:.1f})',
            f'≤ {TOOLS_TARGET_S:g} s')


def run() -> list[tuple[str, str, str]]:
    """Time a clean message build and the tools' install; return benchmark rows."""
    with tempfile.TemporaryDirectory(prefix='setup-bench-') as prefix:
        cpu_before = _children_cpu_s()
        started = time.monotonic()
        build = subprocess.run(
            [str(ROOT / 'scripts' / 'build-interfaces'), '--prefix', prefix, '--force'],
            capture_output=True, text=True, timeout=1800)
        elapsed = time.monotonic() - started
        cpu = _children_cpu_s() - cpu_before
        if build.returncode != 0:
            raise RuntimeError(f'build-interfaces failed:\n{build.stderr}')
        if not Path(prefix, 'share/control_msgs/action/FollowJointTrajectory.json').is_file():
            raise RuntimeError(f'build-interfaces installed nothing in {prefix}')
    # CPU time says what the build costs whatever else the machine runs; the load says that.
    return [
        _tools_row(),
        ('set-up: message build (tf2_msgs, control_msgs, composition_interfaces, '
         'ur_rg2_interfaces; C and Python), warm pip cache',
         f'{elapsed:.0f} s ({cpu:.0f} s CPU, {os.cpu_count()} cores, '
         f'load {os.getloadavg()[0]:.1f})',
         f'≤ {TARGET_S:g} s'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
