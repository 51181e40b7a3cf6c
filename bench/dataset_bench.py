"""Benchmark of the ``dataset`` executable: samples written per second against the sim.

The sim runs as its own process at real-time factor 0 (as fast as the machine allows) on a
private DDS domain kept on this host; ``dataset`` writes a seeded set of samples into a
temporary directory, and the rate is the samples over the wall time of the whole run
(start-up included, as a user sees it).

Run alone with ``python -m bench.dataset_bench``.
"""

from pathlib import Path
import re
import subprocess
import sys
import tempfile
import time

from bench.processes import bench_env, node_process

DOMAIN_ID = 215
SAMPLES = 60
TARGET_RATE = 2.0  # samples/s


def run() -> list[tuple[str, str, str]]:
    """Measure the data set's throughput; return (metric, measured, target) rows."""
    dataset = str(Path(sys.executable).parent / 'dataset')
    with node_process('sim', {'real_time_factor': '0.0'}, DOMAIN_ID, ready='simulating'), \
            tempfile.TemporaryDirectory() as out:
        started = time.monotonic()
        done = subprocess.run([dataset, '--count', str(SAMPLES), '--out', out, '--seed', '1'],
                              env=bench_env(DOMAIN_ID), capture_output=True, text=True,
                              timeout=600)
        elapsed = time.monotonic() - started
        if done.returncode != 0:
            raise RuntimeError(f'dataset failed: {done.stderr[-2000:]}')
        written = len(list(Path(out).glob('images/*/*.png')))
    # Its own summary: the rate once connected to the sim, without the process's start-up.
    steady = re.search(r'\(([0-9.]+) samples/s', done.stderr)
    return [
        (f'dataset: samples/s, {SAMPLES} samples (sim at real-time factor 0), once started',
         steady.group(1) if steady else 'n/a', f'>= {TARGET_RATE:g}'),
        ('dataset: samples/s, the whole run with start-up', f'{written / elapsed:.2f}',
         f'>= {TARGET_RATE:g}'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
