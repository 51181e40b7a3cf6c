"""Benchmark of the browser viewer: stream frame rate and added CPU with 1 and with 10 viewers.

sim, vision and viewer run as separate processes with their defaults (640x480 camera at 30 Hz)
on a private DDS domain kept on this host. The viewers are HTTP clients in this process that
count the multipart frames of ``/stream``; the camera pipeline's rate is that of
``ball/position`` (vision finds the ball in every frame of the default scene), counted by a
node of this process. Run alone with ``python -m bench.viewer_bench``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from contextlib import contextmanager
import socket
import threading
import time

import aiohttp
from geometry_msgs.msg import PointStamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from bench.processes import cpu_seconds, node_process

DOMAIN_ID = 213
WINDOW_S = 8.0  # length of each measurement
WARMUP_S = 2.0  # after connecting viewers, before measuring
START_TIMEOUT_S = 90.0
BOUNDARY_LINE = b'--frame\r\n'  # ur_rg2_vision.viewer_web.BOUNDARY, as sent before each part
# Viewers must not cost the camera pipeline its rate, and see nearly all of its frames: a
# stream skips a frame when two arrive within one encode and send (the newest wins, for a live
# view), and on a loaded machine frames do arrive in bursts. The CPU budgets are this
# benchmark's own: one 2-core machine runs the whole graph and the browsers.
VIEWER_TARGET = 0.90  # of the pipeline's frames
PIPELINE_TARGET = 0.95  # of the pipeline's rate with no viewer
CPU_TARGET = {1: 15.0, 10: 30.0}  # % of one core, added by the viewers


class _BallCounter:
    """Counts ``ball/position`` messages in a node of its own context and thread."""

    def __init__(self, domain_id: int) -> None:
        self.count = 0
        self._context = Context()
        self._context.init(domain_id=domain_id)
        self._node = Node('viewer_bench_ball_counter', context=self._context)
        self._node.create_subscription(PointStamped, 'ball/position', self._on_ball, 100)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._thread = threading.Thread(target=self._executor.spin, daemon=True)
        self._thread.start()

    def _on_ball(self, _msg: PointStamped) -> None:
        self.count += 1  # only this thread writes; readers take a snapshot

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=5)
        self._thread.join(5)
        self._node.destroy_node()
        self._context.try_shutdown()


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return probe.getsockname()[1]


@contextmanager
def _graph() -> Iterator[tuple[int, str, _BallCounter]]:
    """Start sim, vision and viewer; yield the viewer's pid and URL and a ball counter."""
    port = _free_port()
    counter = _BallCounter(DOMAIN_ID)
    try:
        with (node_process('sim', {}, DOMAIN_ID, ready='simulating', timeout=START_TIMEOUT_S),
              node_process('vision', {}, DOMAIN_ID, timeout=START_TIMEOUT_S),
              node_process('viewer', {'port': str(port)}, DOMAIN_ID, ready='live view',
                           timeout=START_TIMEOUT_S) as viewer):
            deadline = time.monotonic() + START_TIMEOUT_S
            while counter.count < 10:
                if time.monotonic() > deadline:
                    raise RuntimeError('benchmark: vision found no ball within '
                                       f'{START_TIMEOUT_S:.0f} s')
                time.sleep(0.1)
            yield viewer.pid, f'http://127.0.0.1:{port}/', counter
    finally:
        counter.close()


async def _count_frames(session: aiohttp.ClientSession, url: str, counts: list[int],
                        index: int) -> None:
    """Read the MJPEG stream at ``url`` until cancelled, counting parts in ``counts[index]``."""
    async with session.get(url) as response:
        tail = b''
        async for chunk in response.content.iter_any():
            data = tail + chunk
            counts[index] += data.count(BOUNDARY_LINE)
            # Keep a boundary split across two chunks countable, but count none twice.
            tail = data[-(len(BOUNDARY_LINE) - 1):]


async def _measure(pid: int, url: str, counter: _BallCounter, viewers: int) -> dict[str, float]:
    """Return the pipeline's fps, the slowest viewer's fps and the viewer's CPU %."""
    async with aiohttp.ClientSession() as session:
        counts = [0] * viewers
        clients = [asyncio.create_task(_count_frames(session, url + 'stream', counts, i))
                   for i in range(viewers)]
        try:
            await asyncio.sleep(WARMUP_S)
            start = (time.monotonic(), cpu_seconds(pid), counter.count, list(counts),
                     time.process_time())
            await asyncio.sleep(WINDOW_S)
            end = (time.monotonic(), cpu_seconds(pid), counter.count, list(counts),
                   time.process_time())
        finally:
            for client in clients:
                client.cancel()
            await asyncio.gather(*clients, return_exceptions=True)
    elapsed = end[0] - start[0]
    return {
        'cpu': 100.0 * (end[1] - start[1]) / elapsed,
        'client_cpu': 100.0 * (end[4] - start[4]) / elapsed,
        'pipeline_fps': (end[2] - start[2]) / elapsed,
        'viewer_fps': min((b - a for a, b in zip(start[3], end[3], strict=True)),
                          default=0) / elapsed,
    }


def run() -> list[tuple[str, str, str]]:
    """Measure the viewer; return benchmark rows (metric, measured, target)."""
    with _graph() as (pid, url, counter):
        before = asyncio.run(_measure(pid, url, counter, 0))
        loaded = {n: asyncio.run(_measure(pid, url, counter, n)) for n in (1, 10)}
        after = asyncio.run(_measure(pid, url, counter, 0))
    # The no-viewer baseline brackets the loaded runs: the machine's other load drifts.
    idle = {key: (before[key] + after[key]) / 2 for key in before}
    rows = []
    for n, result in loaded.items():
        viewers = f'{n} viewer{"s" if n > 1 else ""}'
        rows.append((
            f'viewer stream fps, {viewers} (slowest viewer)',
            f'{result["viewer_fps"]:.1f} fps of the camera pipeline\'s '
            f'{result["pipeline_fps"]:.1f} ({idle["pipeline_fps"]:.1f} with no viewer)',
            f'viewer ≥ {VIEWER_TARGET:.0%} of pipeline; pipeline ≥ {PIPELINE_TARGET:.0%} of '
            'its no-viewer rate'))
        rows.append((
            f'viewer added CPU, {viewers}',
            f'{result["cpu"] - idle["cpu"]:+.1f} % of a core '
            f'(viewer process {result["cpu"]:.1f} %, {idle["cpu"]:.1f} % with no viewer; '
            f'the HTTP readers {result["client_cpu"]:.1f} %)',
            f'≤ {CPU_TARGET[n]:.0f} % of a core'))
    return rows


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
