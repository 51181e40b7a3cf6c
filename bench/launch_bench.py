"""Benchmark of starting and stopping the graph: ``ros2 launch`` beside ``scripts/run``.

Each way starts the four nodes headless on a private domain; *ready* is when every node's
parameter services are discovered and a ``joint_states`` message has arrived; *stopped* is how
long the command takes to exit after the stop signal (Ctrl-C to ``ros2 launch``'s process
group, SIGTERM to ``scripts/run``, as a service manager sends it). The supervisor that
``scripts/run`` ran before the launch file (``bringup/`` at ``SUPERVISOR_REVISION``) is timed
the same way when git has it, for the comparison. Run alone with ``python -m bench.launch_bench``.
"""

from __future__ import annotations

import os
from pathlib import Path
import signal
import statistics
import subprocess
import sys
import tempfile
import time

from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from bench.processes import bench_env, spun_node

ROOT = Path(__file__).resolve().parents[1]
NODE_NAMES = ('ur_rg2_sim', 'ur_rg2_vision', 'ur_rg2_motion', 'ur_rg2_viewer')
# The last commit whose scripts/run was the project's own supervisor (bringup/).
SUPERVISOR_REVISION = 'ebc407c'
RUNS = 3
TIMEOUT_S = 180.0
DOMAIN_ID = 151


def _time_one(command: list[str], stop: signal.Signals, env: dict[str, str],
              domain_id: int) -> tuple[float, float]:
    """Start ``command``; return (seconds until the graph is ready, seconds to stop it)."""
    with spun_node('launch_bench', domain_id) as probe:
        received: list[JointState] = []
        probe.create_subscription(JointState, 'joint_states', received.append,
                                  qos_profile_sensor_data)
        with tempfile.TemporaryFile() as log:
            started = time.monotonic()
            process = subprocess.Popen(command, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                       stderr=subprocess.STDOUT, start_new_session=True)
            try:
                while True:
                    services = {name for name, _ in probe.get_service_names_and_types()}
                    if received and all(f'/{node}/list_parameters' in services
                                        for node in NODE_NAMES):
                        break
                    if process.poll() is not None or time.monotonic() - started > TIMEOUT_S:
                        log.seek(0)
                        raise RuntimeError(f'{command} did not come up:\n{log.read().decode()}')
                    time.sleep(0.05)
                ready = time.monotonic() - started
                stop_sent = time.monotonic()
                if stop is signal.SIGINT:
                    os.killpg(process.pid, signal.SIGINT)
                else:
                    process.send_signal(stop)
                if process.wait(timeout=60) != 0:
                    log.seek(0)
                    raise RuntimeError(f'{command} exited {process.returncode}:\n'
                                       f'{log.read().decode()}')
                return ready, time.monotonic() - stop_sent
            finally:
                if process.poll() is None:
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()


def _median_row(label: str, timings: list[tuple[float, float]]) -> tuple[str, str, str]:
    ready = statistics.median(t[0] for t in timings)
    stopped = statistics.median(t[1] for t in timings)
    return (f'{label}: start to all nodes ready / stop (median of {len(timings)})',
            f'{ready:.1f} s / {stopped:.1f} s (load {os.getloadavg()[0]:.1f})',
            'stop ≤ 5 s')


def run() -> list[tuple[str, str, str]]:
    """Time both ways of starting the graph; return benchmark rows."""
    env = bench_env(DOMAIN_ID)
    common = ['port:=0']
    rows = [
        _median_row('ros2 launch ur_rg2_bringup graph.launch.py', [
            _time_one(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py', *common],
                      signal.SIGINT, env, DOMAIN_ID) for _ in range(RUNS)]),
        _median_row('scripts/run --headless (graph.launch.py)', [
            _time_one([sys.executable, '-m', 'ur_rg2_bringup.run', '--headless', *common],
                      signal.SIGTERM, env, DOMAIN_ID) for _ in range(RUNS)]),
    ]
    with tempfile.TemporaryDirectory(prefix='launch-bench-') as old:
        archive = subprocess.run(['git', '-C', str(ROOT), 'archive', SUPERVISOR_REVISION,
                                  'bringup'], capture_output=True)
        if archive.returncode == 0:
            subprocess.run(['tar', '-x', '-C', old], input=archive.stdout, check=True)
            old_env = dict(env, PYTHONPATH=old)
            rows.append(_median_row(f'the former supervisor (bringup/ at {SUPERVISOR_REVISION})', [
                _time_one([sys.executable, '-m', 'bringup', '--headless', *common],
                          signal.SIGTERM, old_env, DOMAIN_ID) for _ in range(RUNS)]))
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
