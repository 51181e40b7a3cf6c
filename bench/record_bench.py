"""Benchmark of ``record --all`` on the whole graph: messages kept, CPU, MB per minute.

The sim runs with its defaults (RGB + depth 640x480 at 30 Hz, joint states and /tf at 100 Hz)
as a process on a private DDS domain kept on this host; the recorder runs as users run it. A
subscriber of this process beside the recorder keeps the header stamps of what was published;
the messages kept are those of its stamps, within the recording's span, that are in the file.
Run alone with ``python -m bench.record_bench``.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
import signal
import struct
import subprocess
import sys
import tempfile
import time

from mcap.reader import make_reader
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, JointState
from tf2_msgs.msg import TFMessage

from bench.processes import bench_env, cpu_seconds, load, node_process, spun_node

DOMAIN_ID = 214
WINDOW_S = 30.0  # recorded and measured
WARMUP_S = 3.0  # after the recorder has subscribed, before measuring its CPU
START_TIMEOUT_S = 90.0
TOPICS = {'/joint_states': JointState, '/camera/color/image_raw': Image,
          '/camera/depth/image_raw': Image, '/tf': TFMessage}
KEPT_TARGET = 0.99
CPU_TARGET = 100.0  # % of one core


def stamp(topic: str, cdr: bytes) -> tuple[int, int]:
    """Return a message's stamp: its header's, or for /tf its first transform's header's."""
    # After the 4-byte encapsulation header; a TFMessage starts with its sequence length.
    return struct.unpack_from('<iI', cdr, 8 if topic == '/tf' else 4)


def run() -> list[tuple[str, str, str]]:
    """Record the whole graph for WINDOW_S; return benchmark rows (metric, measured, target)."""
    seen: dict[str, set] = defaultdict(set)
    with (tempfile.TemporaryDirectory(prefix='record-bench-') as directory,
          node_process('sim', {}, DOMAIN_ID, ready='simulating', timeout=START_TIMEOUT_S),
          spun_node('record_bench_counter', DOMAIN_ID) as node):
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        for topic, kind in TOPICS.items():
            node.create_subscription(kind, topic, lambda data, topic=topic: seen[topic].add(
                stamp(topic, data)), qos, raw=True)
        path = Path(directory) / 'graph.mcap'
        log_path = Path(directory) / 'record.log'
        with log_path.open('w') as log:
            recorder = subprocess.Popen(
                [str(Path(sys.executable).parent / 'record'), '--all', '-o', str(path)],
                env=bench_env(DOMAIN_ID), stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + START_TIMEOUT_S
            while not all(f'recording {topic} ' in log_path.read_text() for topic in TOPICS):
                if recorder.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f'record did not start: {log_path.read_text()[-2000:]}')
                time.sleep(0.2)
            time.sleep(WARMUP_S)
            start = time.monotonic(), cpu_seconds(recorder.pid), load()
            time.sleep(WINDOW_S)
            end = time.monotonic(), cpu_seconds(recorder.pid), load()
            recorder.send_signal(signal.SIGINT)
            if recorder.wait(60) != 0:
                raise RuntimeError(f'record failed: {log_path.read_text()[-2000:]}')
        finally:
            if recorder.poll() is None:
                recorder.kill()
                recorder.wait()
        in_file: dict[str, set] = defaultdict(set)
        data_bytes, first, last = 0, None, None
        with path.open('rb') as stream:
            for _, channel, message in make_reader(stream).iter_messages():
                data_bytes += len(message.data)
                first = message.log_time if first is None else min(first, message.log_time)
                last = message.log_time if last is None else max(last, message.log_time)
                if channel.topic in TOPICS:
                    in_file[channel.topic].add(stamp(channel.topic, message.data))
        minutes = (last - first) / 60e9
        file_mb = path.stat().st_size / 1e6
    kept, rates = {}, {}
    for topic in TOPICS:
        low, high = min(in_file[topic]), max(in_file[topic])
        published = {s for s in seen[topic] if low <= s <= high}
        kept[topic] = len(published & in_file[topic]), len(published)
        rates[topic] = len(in_file[topic]) / (minutes * 60)
    worst = min(kept, key=lambda topic: kept[topic][0] / max(kept[topic][1], 1))
    cpu = 100.0 * (end[1] - start[1]) / (end[0] - start[0])
    loads = f'load {start[2]}-{end[2]}'
    summary = ', '.join(f'{topic.rsplit("/", 2)[-2 if "camera" in topic else -1]} '
                        f'{k} of {n} ({rates[topic]:.0f}/s)'
                        for topic, (k, n) in kept.items())
    return [
        ('record --all, messages kept (whole graph)',
         f'{kept[worst][0] / max(kept[worst][1], 1):.2%} worst ({summary}); {loads}',
         f'≥ {KEPT_TARGET:.0%} of each topic'),
        ('record --all, recorder CPU', f'{cpu:.0f} % of a core; {loads}',
         f'≤ {CPU_TARGET:.0f} % of a core'),
        ('record --all, file size', f'{file_mb / minutes:.0f} MB per minute written (zstd '
         f'chunks; {data_bytes / 1e6 / minutes:.0f} MB of messages per minute); {loads}',
         'printed'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
