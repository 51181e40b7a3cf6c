"""Benchmark of the whole graph as a user runs it with its own features on.

``scripts/run --headless view3d:=true detector:=learned`` (sim, vision with the learned
detector, motion, viewer, 3D view) and ``record --all`` beside it, for ``GRAPH_SECONDS``
(default 60) after a warm-up. This process listens like any other node and measures: the
real-time factor (``/clock`` against the wall clock), the rates of joint states, colour,
depth and ``ball/position`` in wall and simulation time, the colour frame's arrival here to
its ``ball/position`` here (both transports and the vision node's work; split at the same
frame's depth image, which the learned detector waits for), the messages the
recording kept against those this listener received over each topic's span in it, and the CPU
of each process of the graph and of the recorder. Run alone: ``python -m bench graph``.
"""

import collections
import math
import os
from pathlib import Path
import re
import signal
import struct
import subprocess
import tempfile
import threading
import time

from geometry_msgs.msg import PointStamped
from mcap.reader import make_reader
import psutil
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState

from bench.processes import bench_env, load, percentile

DOMAIN_ID = 219
WINDOW_S = float(os.environ.get('GRAPH_SECONDS', '60'))
WARMUP_S = 5.0
START_TIMEOUT_S = 120.0
ROOT = Path(__file__).resolve().parents[1]
TOPICS = {'joint_states': JointState, 'camera/color/image_raw': Image,
          'camera/depth/image_raw': Image, 'ball/position': PointStamped}
# Which process is which: a word of its command line.
ROLES = ('sim', 'vision', 'motion', 'viewer', 'view3d', 'record', 'launch')


class _Listener:
    """Counts the graph's messages with their wall and simulation times, in a node of its own."""

    def __init__(self) -> None:
        self.context = Context()
        self.context.init(domain_id=DOMAIN_ID)
        self.node = Node('graph_bench_listener', context=self.context)
        self.lock = threading.Lock()
        self.arrivals: dict[str, list[float]] = collections.defaultdict(list)
        self.stamps: dict[str, list[int]] = collections.defaultdict(list)
        self.clock: list[tuple[float, int]] = []
        self.color_at: dict[int, float] = {}
        self.depth_at: dict[int, float] = {}
        self.latency: list[float] = []
        # The same frames' colour -> depth and depth -> ball/position, where both came here.
        self.depth_after_color: list[float] = []
        self.ball_after_depth: list[float] = []
        qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        # Serialized: this listener reads only the stamp, as cheaply as it can (it shares the
        # machine with the graph it measures).
        for topic, kind in TOPICS.items():
            self.node.create_subscription(
                kind, topic, lambda data, topic=topic: self._on(topic, data),
                qos if kind is Image else 100, raw=True)
        self.node.create_subscription(Clock, '/clock', self._on_clock, 100)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on(self, topic: str, data: bytes) -> None:
        now = time.monotonic()
        # CDR: 4 bytes of encapsulation, then the header's stamp (int32 sec, uint32 nanosec).
        sec, nanosec = struct.unpack_from('<iI', data, 4)
        stamp = sec * 10 ** 9 + nanosec
        with self.lock:
            self.arrivals[topic].append(time.time())
            self.stamps[topic].append(stamp)
            if topic == 'camera/color/image_raw':
                self.color_at[stamp] = now
            elif topic == 'camera/depth/image_raw':
                self.depth_at[stamp] = now
            elif topic == 'ball/position' and stamp in self.color_at:
                color = self.color_at[stamp]
                self.latency.append(1000 * (now - color))
                depth = self.depth_at.get(stamp)
                if depth is not None:
                    self.depth_after_color.append(1000 * (depth - color))
                    self.ball_after_depth.append(1000 * (now - depth))

    def _on_clock(self, msg: Clock) -> None:
        with self.lock:
            self.clock.append((time.monotonic(), msg.clock.sec * 10 ** 9 + msg.clock.nanosec))

    def counts(self) -> dict[str, int]:
        with self.lock:
            return {topic: len(self.arrivals[topic]) for topic in TOPICS}

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
        self.thread.join(5)


def _role(process: psutil.Process) -> str:
    try:
        words = ' '.join(process.cmdline())
    except psutil.Error:
        return 'other'
    for role in ROLES:
        if f'/{role}' in words or f' {role}' in words:
            return role
    return 'other'


def _cpu(processes: list[psutil.Process]) -> dict[int, float]:
    seconds = {}
    for process in processes:
        try:
            times = process.cpu_times()
            seconds[process.pid] = times.user + times.system
        except psutil.Error:
            pass
    return seconds


def _tree(*roots: subprocess.Popen) -> list[psutil.Process]:
    found = []
    for root in roots:
        parent = psutil.Process(root.pid)
        found += [parent, *parent.children(recursive=True)]
    return found


def _start(command: list[str], log) -> subprocess.Popen:
    return subprocess.Popen(command, cwd=ROOT, env=bench_env(DOMAIN_ID), stdin=subprocess.DEVNULL,
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGINT)
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def run() -> list[tuple[str, str, str]]:
    """Run the graph and the recorder, listen, and return the rows."""
    started_load = load()
    with tempfile.TemporaryDirectory(prefix='graph-bench-') as scratch:
        graph_log = open(Path(scratch) / 'graph.log', 'wb')  # noqa: SIM115 - closed below
        record_log = open(Path(scratch) / 'record.log', 'wb')  # noqa: SIM115
        recording = Path(scratch) / 'graph.mcap'
        graph = _start([str(ROOT / 'scripts' / 'run'), '--headless', 'view3d:=true',
                        'detector:=learned', 'port:=18480'], graph_log)
        listener = _Listener()
        recorder = None
        try:
            deadline = time.monotonic() + START_TIMEOUT_S
            while listener.counts()['ball/position'] < 10:
                if graph.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError('the graph did not start: '
                                       + (Path(scratch) / 'graph.log').read_text()[-2000:])
                time.sleep(0.2)
            recorder = _start(['ros2', 'run', 'ur_rg2_tools', 'record', '--all', '-o',
                               str(recording)], record_log)
            time.sleep(WARMUP_S)
            processes = _tree(graph, recorder)
            roles = {process.pid: _role(process) for process in processes}
            before, wall_before = _cpu(processes), time.monotonic()
            counts_before = listener.counts()
            with listener.lock:
                clock_before = listener.clock[-1]
            time.sleep(WINDOW_S)
            after, wall_after = _cpu(processes), time.monotonic()
            counts_after = listener.counts()
            with listener.lock:
                clock_after = listener.clock[-1]
            _stop(recorder)
        finally:
            _stop(graph)
            if recorder is not None:
                _stop(recorder)
            listener.close()
            graph_log.close()
            record_log.close()
        recorded = _recorded(recording, [f'/{topic}' for topic in TOPICS])
        camera = re.search(r'camera: (\d+) frames drawn, (\d+) dropped',
                           (Path(scratch) / 'graph.log').read_text(errors='replace'))
    wall = wall_after - wall_before
    sim = (clock_after[1] - clock_before[1]) / 1e9
    rows = [('graph: real-time factor (/clock against wall time)',
             f'{sim / (clock_after[0] - clock_before[0]):.2f}', '>= 0.98')]
    targets = {'joint_states': 99, 'camera/color/image_raw': 29, 'camera/depth/image_raw': 29,
               'ball/position': 28}
    for topic, target in targets.items():
        count = counts_after[topic] - counts_before[topic]
        rows.append((f'graph: {topic} Hz, wall / simulation time',
                     f'{count / wall:.1f} / {count / sim:.1f}', f'>= {target}'))
    rows.append(('graph: camera frames drawn / dropped by the sim, whole run',
                 f'{camera[1]} / {camera[2]}' if camera else 'no summary in the log', ''))
    rows.append(('graph: colour frame -> ball/position here (learned), ms p50 / p95',
                 f'{percentile(listener.latency, 50):.1f} / '
                 f'{percentile(listener.latency, 95):.1f}', 'p95 <= 30 ms'))
    rows.append(('graph: of that, colour -> its depth here, then -> ball/position, ms p50 / p95',
                 f'{percentile(listener.depth_after_color, 50):.1f} / '
                 f'{percentile(listener.depth_after_color, 95):.1f}, '
                 f'{percentile(listener.ball_after_depth, 50):.1f} / '
                 f'{percentile(listener.ball_after_depth, 95):.1f}', ''))
    for topic in targets:
        kept, first, last = recorded.get(f'/{topic}', (0, 0.0, 0.0))
        received = sum(first <= t <= last for t in listener.arrivals[topic])
        rows.append((f'graph: recording kept / received here, {topic}',
                     f'{kept} / {received} ({kept / max(received, 1):.1%})', '>= 99 %'))
    busy = collections.Counter()
    for process in processes:
        if process.pid in before and process.pid in after:
            busy[roles[process.pid]] += (after[process.pid] - before[process.pid]) / wall
    for role, cores in sorted(busy.items(), key=lambda item: -item[1]):
        rows.append((f'graph: CPU of {role}, cores', f'{cores:.2f}', ''))
    rows.append(('graph: CPU of graph + recorder, cores', f'{sum(busy.values()):.2f}',
                 '<= 1.6'))
    rows.append(('graph: load at start / end, 1-minute', f'{started_load} / {load()}', ''))
    return rows


def _recorded(path: Path, topics: list[str]) -> dict[str, tuple[int, float, float]]:
    """Return, per topic, the recording's message count and its first and last log times.

    Per topic: the recorder subscribes to each topic as it discovers it, so a topic's span
    starts with its own first message, not the recording's (wall seconds).
    """
    found: dict[str, tuple[int, float, float]] = {}
    with open(path, 'rb') as stream:
        for _, channel, message in make_reader(stream).iter_messages(topics=topics):
            count, first, last = found.get(channel.topic, (0, math.inf, -math.inf))
            at = message.log_time / 1e9
            found[channel.topic] = (count + 1, min(first, at), max(last, at))
    return found


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
