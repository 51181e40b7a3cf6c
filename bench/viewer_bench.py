"""Benchmark of the browser viewer: stream frame rate and added CPU with 1 and with 10 viewers.

sim, vision and viewer run as separate processes with their defaults (640x480 camera at 30 Hz)
on a private DDS domain kept on this host; the viewers are HTTP clients in this process that
count the multipart frames of ``/stream``. Run alone with ``python -m bench.viewer_bench``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from contextlib import contextmanager
import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import tempfile
import time

import aiohttp

WINDOW_S = 8.0  # length of each measurement
WARMUP_S = 2.0  # after connecting viewers, before measuring
START_TIMEOUT_S = 90.0
CLK_TCK = os.sysconf('SC_CLK_TCK')
BOUNDARY_LINE = b'--frame\r\n'  # ur_rg2_vision.viewer_web.BOUNDARY, as sent before each part
# Targets: viewers must get every frame the pipeline delivers, and must not cost the pipeline
# its rate. The CPU budgets are this benchmark's own: one 2-core machine runs the whole graph.
CPU_TARGET = {1: 15.0, 10: 30.0}  # % of one core, added by the viewers


def _cpu_seconds(pid: int) -> float:
    """Return the user + system CPU time of process ``pid`` so far."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


@contextmanager
def _graph() -> Iterator[tuple[subprocess.Popen, str]]:
    """Start sim, vision and viewer; yield the viewer process and its URL; stop them all."""
    bindir = Path(sys.executable).parent
    env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    processes: list[subprocess.Popen] = []
    with tempfile.TemporaryDirectory(prefix='viewer-bench-') as tmp:
        logs = {name: Path(tmp, f'{name}.log') for name in ('sim', 'vision', 'viewer')}
        try:
            for name, args in (('sim', []), ('vision', []), ('viewer', ['-p', 'port:=0'])):
                with logs[name].open('wb') as log:
                    processes.append(subprocess.Popen(
                        [str(bindir / name), '--ros-args', *args], env=env,
                        stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT))
            deadline = time.monotonic() + START_TIMEOUT_S
            while not (found := re.search(r'at (http://\S+/)', logs['viewer'].read_text())):
                for name, process in zip(logs, processes, strict=True):
                    if process.poll() is not None:
                        raise RuntimeError(f'{name} exited: {logs[name].read_text()[-2000:]}')
                if time.monotonic() > deadline:
                    raise RuntimeError('the viewer did not report its URL')
                time.sleep(0.1)
            yield processes[-1], found.group(1)
        finally:
            for process in processes:
                process.send_signal(signal.SIGINT)
            for process in processes:
                try:
                    process.wait(10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()


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


async def _measure(pid: int, url: str, viewers: int) -> dict[str, float]:
    """Return pipeline fps, per-viewer fps (min) and viewer CPU % with ``viewers`` clients."""
    async with aiohttp.ClientSession() as session:

        async def pipeline_frames() -> int:
            async with session.get(url + 'state') as response:
                return json.loads(await response.text())['camera']['frames']

        counts = [0] * viewers
        clients = [asyncio.create_task(_count_frames(session, url + 'stream', counts, i))
                   for i in range(viewers)]
        try:
            await asyncio.sleep(WARMUP_S)
            start = (time.monotonic(), _cpu_seconds(pid), await pipeline_frames(), list(counts))
            await asyncio.sleep(WINDOW_S)
            end = (time.monotonic(), _cpu_seconds(pid), await pipeline_frames(), list(counts))
        finally:
            for client in clients:
                client.cancel()
            await asyncio.gather(*clients, return_exceptions=True)
    elapsed = end[0] - start[0]
    return {
        'cpu': 100.0 * (end[1] - start[1]) / elapsed,
        'pipeline_fps': (end[2] - start[2]) / elapsed,
        'viewer_fps': min((b - a for a, b in zip(start[3], end[3], strict=True)),
                          default=0) / elapsed,
    }


async def _wait_for_frames(url: str) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    async with aiohttp.ClientSession() as session:
        while time.monotonic() < deadline:
            async with session.get(url + 'state') as response:
                if json.loads(await response.text())['camera']['fps']:
                    return
            await asyncio.sleep(0.2)
    raise RuntimeError('no annotated frames reached the viewer')


def run() -> list[tuple[str, str, str]]:
    """Measure the viewer; return benchmark rows (metric, measured, target)."""
    with _graph() as (viewer, url):
        asyncio.run(_wait_for_frames(url))
        idle = asyncio.run(_measure(viewer.pid, url, 0))
        loaded = {n: asyncio.run(_measure(viewer.pid, url, n)) for n in (1, 10)}
    rows = []
    for n, result in loaded.items():
        rows.append((
            f'viewer stream fps, {n} viewer{"s" if n > 1 else ""} (slowest viewer)',
            f'{result["viewer_fps"]:.1f} fps; pipeline {result["pipeline_fps"]:.1f} fps '
            f'({idle["pipeline_fps"]:.1f} with no viewer)',
            'every pipeline frame; pipeline ≥ 95 % of its no-viewer rate'))
    for n, result in loaded.items():
        rows.append((
            f'viewer added CPU, {n} viewer{"s" if n > 1 else ""}',
            f'{result["cpu"] - idle["cpu"]:+.1f} % of a core '
            f'(viewer process {result["cpu"]:.1f} %, {idle["cpu"]:.1f} % with no viewer)',
            f'≤ {CPU_TARGET[n]:.0f} % of a core'))
    return rows


if __name__ == '__main__':
    for metric, measured, target in run():
        print(f'{metric}: {measured} (target: {target})')
