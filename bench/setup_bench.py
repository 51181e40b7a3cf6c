"""Benchmark of the set-up: the message build of tf2_msgs and control_msgs on a warm pip cache.

The ROS wheels are already in the venv (bootstrap ran), so this is the part of a fresh set-up
that the pip cache does not save: ``scripts/build-interfaces --force`` builds both packages
from clean into a temporary prefix, leaving the venv's own install alone. Run alone with
``python -m bench.setup_bench``.
"""

from __future__ import annotations

import os
from pathlib import Path
import resource
import subprocess
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
# Our own budget: the two packages' generated C/C++ on one 2-core machine, idle.
TARGET_S = 60.0


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run() -> list[tuple[str, str, str]]:
    """Time a clean build of both packages; return benchmark rows (metric, measured, target)."""
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
        ('set-up: message build (tf2_msgs + control_msgs), warm pip cache',
         f'{elapsed:.0f} s ({cpu:.0f} s CPU, {os.cpu_count()} cores, '
         f'load {os.getloadavg()[0]:.1f})',
         f'≤ {TARGET_S:g} s'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
