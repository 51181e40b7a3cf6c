"""Helpers shared by the benchmarks: node processes on a private domain, their CPU and memory.

Also the benchmark process's own node on that domain, spun in the background.
"""

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from rclpy.client import Client
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

CLK_TCK = os.sysconf('SC_CLK_TCK')
PAGE_SIZE = os.sysconf('SC_PAGE_SIZE')


def bench_env(domain_id: int) -> dict[str, str]:
    """Return the environment of a benchmark graph: its own DDS domain, localhost only."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


def cpu_seconds(pid: int) -> float:
    """Return the user + system CPU time of process ``pid`` so far."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def rss_mb(pid: int) -> float:
    """Return the resident memory of process ``pid`` in MiB."""
    pages = int(Path(f'/proc/{pid}/statm').read_text().split()[1])
    return pages * PAGE_SIZE / 2 ** 20


def private_rss_mb(pid: int) -> float:
    """Return the resident anonymous memory of process ``pid`` in MiB (heap, arenas, stacks).

    RSS less the pages of files and shared memory mapped in. Those include the Fast DDS
    shared-memory segments (16 MiB each, config/fastdds.xml) of the publishers a process
    reads from, whose pages count once touched: they fill in as each segment's buffers go
    round, up to the segment's size, which is no leak.
    """
    for line in Path(f'/proc/{pid}/status').read_text().splitlines():
        if line.startswith('RssAnon:'):
            return int(line.split()[1]) / 1024
    return math.nan


def load() -> str:
    """Return the 1-minute load average (``/proc/loadavg``), to print beside what it slows."""
    return Path('/proc/loadavg').read_text().split()[0]


def raw_steps_per_second(world, seconds: float) -> float:
    """Return how many times a second pybullet's stepSimulation alone steps ``world``.

    ``world`` is a ur_rg2_sim SimWorld: the physics the sim node or an environment runs, timed
    without anything around it, to compare them with.
    """
    import pybullet

    client = world.client
    steps = 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(100):
            pybullet.stepSimulation(physicsClientId=client)
        steps += 100
    return steps / (time.perf_counter() - start)


def percentile(values: Sequence[float], q: float) -> float:
    """Return the ``q``-th percentile of ``values`` (nan when there are none)."""
    return float(np.percentile(values, q)) if len(values) else float('nan')


@contextmanager
def node_process(executable: str, parameters: dict[str, str], domain_id: int,
                 ready: str = '', timeout: float = 90.0) -> Iterator[subprocess.Popen]:
    """Run a node executable of this venv; wait for ``ready`` in its log; stop it with SIGINT.

    After the block, the process's ``log`` attribute holds everything it printed.
    """
    command = [str(Path(sys.executable).parent / executable), '--ros-args']
    for name, value in parameters.items():
        command += ['-p', f'{name}:={value}']
    with tempfile.TemporaryFile() as log:
        process = subprocess.Popen(command, env=bench_env(domain_id), stdin=subprocess.DEVNULL,
                                   stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + timeout
            while ready:
                log.seek(0)
                output = log.read().decode(errors='replace')
                if ready in output:
                    break
                if process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f'{executable} did not start: {output[-2000:]}')
                time.sleep(0.1)
            yield process
        finally:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            log.seek(0)
            process.log = log.read().decode(errors='replace')  # for what it says on exit


def call_service(node: Node, clients: dict[str, Client], service: str, kind: type,
                 request: object | None, timeout: float) -> object:
    """Call ``service`` from ``node`` (spun on another thread); return the answer.

    ``clients`` keeps one client per service between calls. Raises RuntimeError when the
    service is not there, or does not answer, within ``timeout`` s.
    """
    if service not in clients:
        clients[service] = node.create_client(kind, service)
    client = clients[service]
    if not client.wait_for_service(timeout_sec=timeout):
        raise RuntimeError(f'service {service} not available')
    future = client.call_async(request or kind.Request())
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout):
        raise RuntimeError(f'no answer from {service} within {timeout:.0f} s')
    return future.result()


@contextmanager
def spun_node(name: str, domain_id: int) -> Iterator[Node]:
    """Yield a node of this process on ``domain_id``, spun on a background thread meanwhile."""
    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = Node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin() -> None:
        try:
            executor.spin()
        except ExternalShutdownException:
            pass

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        yield node
    finally:
        context.try_shutdown()
        spinner.join()
        node.destroy_node()
        executor.shutdown()
