"""Benchmark of discovery as ROS 2's own tools see it: ``ros2 node list`` beside a running graph.

The graph (``ros2 launch ur_rg2_bringup graph.launch.py``, headless, a private domain) is up
and every node has said it is ready; then ``ros2 node list --no-daemon --spin-time 1`` runs
``TRIES`` times; then ``ros2 node list`` as many times after ``ros2 daemon stop`` (that first
call starts a daemon and answers from its own 0.5 s look, ros2cli's DirectNode), and as many
times through a fresh daemon (``ros2 daemon stop`` and ``ros2 daemon start`` before each). A
try counts when it lists all four nodes. Then a new node joins the graph ``JOINS`` times, each in
a process of its own, and times how long after its creation it sees all four. Run alone with
``python -m bench.discovery_bench``.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import tempfile
import time

from bench.processes import bench_env

ROOT = Path(__file__).resolve().parents[1]
NODE_NAMES = ('/ur_rg2_sim', '/ur_rg2_vision', '/ur_rg2_motion', '/ur_rg2_viewer')
READY = (r'\[ur_rg2_sim\]: simulating', r'\[ur_rg2_motion\]: ready',
         r'\[ur_rg2_vision\]: looking for the ball', r'\[ur_rg2_viewer\]: live view')
TRIES = 20
JOINS = 30
TIMEOUT_S = 120.0
DOMAIN_ID = 152


def _lists_all(command: list[str], env: dict[str, str]) -> bool:
    """Run ``command``; return whether it listed every node of the graph."""
    listed = subprocess.run(command, env=env, capture_output=True, text=True, timeout=60,
                            check=False).stdout.split()
    return all(name in listed for name in NODE_NAMES)


# A node joins, then prints the seconds until it sees every node of the graph (or 'miss' at 3 s).
JOIN_PROBE = f"""
import sys, time
import rclpy
rclpy.init()
node = rclpy.create_node('discovery_probe', start_parameter_services=False)
created = time.monotonic()
want = {{name[1:] for name in {NODE_NAMES!r}}}
while not want <= set(node.get_node_names()):
    if time.monotonic() - created > 3.0:
        print('miss')
        sys.exit()
    time.sleep(0.005)
print(time.monotonic() - created)
"""


def _join_seconds(env: dict[str, str]) -> float:
    """Return how long a new node took to see the whole graph (infinity for a miss)."""
    printed = subprocess.run([sys.executable, '-c', JOIN_PROBE], env=env, capture_output=True,
                             text=True, timeout=60, check=False).stdout.strip()
    return float('inf') if printed in ('miss', '') else float(printed)


def _load() -> str:
    return Path('/proc/loadavg').read_text().split()[0]


def run() -> list[tuple[str, str, str]]:
    """Start the graph, count the ``ros2 node list`` calls that see all of it."""
    env = bench_env(DOMAIN_ID)
    daemon_stop = ['ros2', 'daemon', 'stop']
    with tempfile.TemporaryFile('w+') as log:
        graph = subprocess.Popen(['ros2', 'launch', 'ur_rg2_bringup', 'graph.launch.py',
                                  'port:=0'], env=env, stdin=subprocess.DEVNULL, stdout=log,
                                 stderr=subprocess.STDOUT, start_new_session=True)
        try:
            deadline = time.monotonic() + TIMEOUT_S
            while True:
                log.seek(0)
                text = log.read()
                if all(re.search(pattern, text) for pattern in READY):
                    break
                if graph.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f'the graph did not come up:\n{text[-3000:]}')
                time.sleep(0.2)
            loads = [_load()]
            direct = sum(_lists_all(['ros2', 'node', 'list', '--no-daemon', '--spin-time', '1'],
                                    env) for _ in range(TRIES))
            loads.append(_load())
            first, fresh = 0, 0
            for _ in range(TRIES):
                subprocess.run(daemon_stop, env=env, capture_output=True, timeout=60,
                               check=False)
                first += _lists_all(['ros2', 'node', 'list'], env)
            loads.append(_load())
            for _ in range(TRIES):
                for verb in ('stop', 'start'):
                    subprocess.run(['ros2', 'daemon', verb], env=env, capture_output=True,
                                   timeout=60, check=False)
                fresh += _lists_all(['ros2', 'node', 'list'], env)
            loads.append(_load())
            joins = sorted(_join_seconds(env) for _ in range(JOINS))
            loads.append(_load())
        finally:
            subprocess.run(daemon_stop, env=env, capture_output=True, timeout=60, check=False)
            if graph.poll() is None:
                os.killpg(graph.pid, signal.SIGINT)
            graph.wait(timeout=60)
    load = f'load {min(loads)}-{max(loads)}'
    return [
        ('`ros2 node list --no-daemon --spin-time 1` lists all 4 nodes of the running graph',
         f'{direct} of {TRIES} ({load})', f'>= 19 of {TRIES}'),
        ('`ros2 node list` after `ros2 daemon stop` (it starts one, answers by itself) lists '
         'all 4', f'{first} of {TRIES} ({load})', '-'),
        ('`ros2 node list` through a fresh daemon (`ros2 daemon stop`, `ros2 daemon start` '
         'first) lists all 4', f'{fresh} of {TRIES} ({load})', f'{TRIES} of {TRIES}'),
        (f'a new node sees all 4 nodes after, s (median / p90 / max of {JOINS} joins)',
         f'{joins[JOINS // 2]:.2f} / {joins[int(JOINS * 0.9)]:.2f} / {joins[-1]:.2f} '
         f'({sum(j > 0.5 for j in joins)} over 0.5 s; {load})', '< 0.5 s each'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
