"""Soak benchmark: the headless graph for 10 minutes under a scripted user.

sim (defaults: real-time factor 1, 640x480 camera at 30 Hz), vision, motion and viewer run as
their own processes, started by their executables on a private DDS domain. A user in this
process repeats, until the time is up: a few joint jogs (some into the floor: protective
stops) and a reset, a frame saved (``vision/save_frame``), three browser viewers reading the
MJPEG stream for two seconds, and a pick of the ball put somewhere new. Every 10 s it samples
each node's resident memory; it also measures each ``ball/position``'s age when it arrives
here (simulation time from ``/clock``, so the camera stamp to here).

Rows: each node's RSS growth from the first to the last minute after the warm-up (a leak
shows as growth that goes on; the target is 2 MB), and of its private part (RssAnon: RSS less
mapped files and shared memory, whose pages of the DDS segments read from count as they are
first touched, up to 16 MiB a segment), the frame latency in those two minutes
(flat when nothing piles up), and what the user did. ``SOAK_SECONDS`` (default 600) sets the
length, for a quick try. Run alone: ``python -m bench soak``.
"""

from __future__ import annotations

from contextlib import ExitStack
import math
import os
import sys
import tempfile
import threading
import time
import urllib.request

from geometry_msgs.msg import PointStamped
import numpy as np
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from bench.motion_bench import placement
from bench.processes import (
    call_service,
    node_process,
    percentile,
    private_rss_mb,
    rss_mb,
    spun_node,
)
from bench.viewer_bench import _free_port

DOMAIN_ID = 217
SOAK_S = float(os.environ.get('SOAK_SECONDS', '600'))
WARMUP_S = min(120.0, SOAK_S / 5)  # first allocations, caches, DDS discovery
WINDOW_S = min(60.0, SOAK_S / 5)  # the first and the last window after the warm-up
SAMPLE_S = min(10.0, SOAK_S / 30)
START_TIMEOUT_S = 90.0
CALL_TIMEOUT_S = 60.0
RSS_TARGET_MB = 2.0
SEED = 20261125
NODES = ('sim', 'vision', 'motion', 'viewer')


class _User:
    """The scripted user: topics and services of the graph, from a node of this process."""

    def __init__(self, node, viewer_url: str) -> None:
        self.node = node
        self.viewer_url = viewer_url
        self.lock = threading.Lock()
        self.sim_clock: tuple[int, float] | None = None  # (/clock ns, monotonic when received)
        self.ages: list[tuple[float, float]] = []  # (monotonic, ms)
        self.seen = 0
        self.jog = node.create_publisher(JointState, 'joint_jog', 10)
        node.create_subscription(Clock, '/clock', self._on_clock, 10)
        node.create_subscription(PointStamped, 'ball/position', self._on_ball, 10)
        self._clients: dict[str, object] = {}
        self.tally = dict.fromkeys(('picks', 'held', 'jogs', 'resets', 'saves', 'viewer reads',
                                    'failed calls'), 0)

    def _on_clock(self, msg: Clock) -> None:
        with self.lock:
            self.sim_clock = (msg.clock.sec * 10 ** 9 + msg.clock.nanosec, time.monotonic())

    def _on_ball(self, msg: PointStamped) -> None:
        now = time.monotonic()
        with self.lock:
            self.seen += 1
            if self.sim_clock is None:
                return
            clock_ns, received = self.sim_clock
            # Simulation time now, at real-time factor 1, less the frame's stamp.
            sim_now = clock_ns + (now - received) * 1e9
            stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            self.ages.append((now, (sim_now - stamp) / 1e6))

    def call(self, service: str, kind=Trigger, request=None):
        return call_service(self.node, self._clients, service, kind, request, CALL_TIMEOUT_S)

    def trigger(self, service: str) -> bool:
        try:
            answer = self.call(service)
        except RuntimeError as error:
            print(f'soak: {error}', file=sys.stderr, flush=True)
            answer = None
        if answer is None or not answer.success:
            self.tally['failed calls'] += 1
            if answer is not None:
                print(f'soak: {service}: {answer.message}', file=sys.stderr, flush=True)
            return False
        return True

    def jogs(self, rng: np.random.Generator) -> None:
        """Jog a few joints by a key's step, now and then far enough to meet the floor."""
        for _ in range(8):
            joint = str(rng.choice(['shoulder_pan_joint', 'shoulder_lift_joint',
                                    'elbow_joint', 'wrist_1_joint']))
            step = math.radians(float(rng.choice([-5.0, 5.0, 30.0])))
            self.jog.publish(JointState(name=[joint], position=[step]))
            self.tally['jogs'] += 1
            time.sleep(0.15)
        time.sleep(1.0)
        self.tally['resets'] += self.trigger('reset')
        time.sleep(3.0)  # home again

    def save(self) -> None:
        self.tally['saves'] += self.trigger('vision/save_frame')

    def view(self) -> None:
        """Three browser viewers read the live stream for two seconds each, side by side."""
        def read() -> None:
            try:
                with urllib.request.urlopen(self.viewer_url + 'stream', timeout=10) as stream:
                    deadline = time.monotonic() + 2.0
                    while time.monotonic() < deadline and stream.read(65536):
                        pass
                with self.lock:
                    self.tally['viewer reads'] += 1
            except OSError as error:
                print(f'soak: viewer: {error}', file=sys.stderr, flush=True)
        readers = [threading.Thread(target=read) for _ in range(3)]
        for reader in readers:
            reader.start()
        for reader in readers:
            reader.join()

    def pick(self, rng: np.random.Generator) -> None:
        self.trigger('gripper/open')
        position = [float(v) for v in placement('pick_ball')(rng)]
        request = SetParameters.Request(parameters=[Parameter(
            'ball_position', value=position).to_parameter_msg()])
        self.call('ur_rg2_sim/set_parameters', SetParameters, request)
        with self.lock:
            wanted = self.seen + 6
        deadline = time.monotonic() + 10.0
        while self.seen < wanted and time.monotonic() < deadline:
            time.sleep(0.05)
        self.tally['picks'] += 1
        self.tally['held'] += self.trigger('pick_ball')
        self.trigger('gripper/open')


def _growth(samples: list[tuple[float, float]], start: float, end: float) -> float:
    """Return mean RSS in the last window less that in the first, after the warm-up."""
    first = [mb for t, mb in samples if start <= t < start + WINDOW_S]
    last = [mb for t, mb in samples if end - WINDOW_S <= t <= end]
    return float(np.mean(last) - np.mean(first)) if first and last else math.nan


def run() -> list[tuple[str, str, str]]:
    """Soak the graph; return (metric, measured, target) rows."""
    port = _free_port()
    rng = np.random.default_rng(SEED)
    rss: dict[str, list[tuple[float, float]]] = {name: [] for name in NODES}
    private: dict[str, list[tuple[float, float]]] = {name: [] for name in NODES}
    with tempfile.TemporaryDirectory(prefix='soak-bench-') as frames, ExitStack() as stack:
        processes = {
            'sim': stack.enter_context(node_process('sim', {}, DOMAIN_ID, ready='simulating',
                                                    timeout=START_TIMEOUT_S)),
            'vision': stack.enter_context(node_process(
                'vision', {'frames_dir': frames}, DOMAIN_ID, ready='looking for the ball',
                timeout=START_TIMEOUT_S)),
            'motion': stack.enter_context(node_process('motion', {}, DOMAIN_ID, ready='ready:',
                                                       timeout=START_TIMEOUT_S)),
            'viewer': stack.enter_context(node_process(
                'viewer', {'port': str(port)}, DOMAIN_ID, ready='live view',
                timeout=START_TIMEOUT_S)),
        }
        node = stack.enter_context(spun_node('soak_user', DOMAIN_ID))
        user = _User(node, f'http://127.0.0.1:{port}/')
        started = time.monotonic()
        finished = threading.Event()

        def sample() -> None:
            while not finished.wait(SAMPLE_S):
                for name, process in processes.items():
                    if process.poll() is None:
                        now = time.monotonic() - started
                        rss[name].append((now, rss_mb(process.pid)))
                        private[name].append((now, private_rss_mb(process.pid)))
                print(f'soak: {time.monotonic() - started:.0f} of {SOAK_S:.0f} s: ' + ', '.join(
                    f'{name} {samples[-1][1]:.1f} MB' for name, samples in rss.items()
                    if samples) + f'; {user.tally}', file=sys.stderr, flush=True)
        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        actions = (lambda: user.jogs(rng), user.save, user.view, lambda: user.pick(rng))
        step = 0
        while time.monotonic() < started + SOAK_S:
            actions[step % len(actions)]()
            step += 1
        finished.set()
        sampler.join()
        run_s = time.monotonic() - started
        alive = [name for name, process in processes.items() if process.poll() is None]
        with user.lock:
            ages = list(user.ages)
    growth = {name: _growth(samples, WARMUP_S, run_s) for name, samples in rss.items()}
    private_growth = {name: _growth(samples, WARMUP_S, run_s)
                      for name, samples in private.items()}
    first = [ms for t, ms in ages if WARMUP_S <= t - started < WARMUP_S + WINDOW_S]
    last = [ms for t, ms in ages if run_s - WINDOW_S <= t - started]
    tally = user.tally
    return [
        (f'soak: RSS growth after warm-up, MB ({" / ".join(NODES)})',
         ' / '.join(f'{growth[name]:+.1f}' for name in NODES)
         + f' ({run_s / 60:.0f} min, first vs last {WINDOW_S:.0f} s after {WARMUP_S:.0f} s)',
         f'<= {RSS_TARGET_MB:g} MB each'),
        (f'soak: of that, private (RssAnon), MB ({" / ".join(NODES)})',
         ' / '.join(f'{private_growth[name]:+.1f}' for name in NODES),
         f'<= {RSS_TARGET_MB:g} MB each'),
        ('soak: camera stamp -> ball/position here, ms p50 / p95, first vs last window',
         f'{percentile(first, 50):.0f} / {percentile(first, 95):.0f} vs '
         f'{percentile(last, 50):.0f} / {percentile(last, 95):.0f}', 'flat'),
        ('soak: scripted user',
         f"{tally['picks']} picks ({tally['held']} held), {tally['jogs']} jogs, "
         f"{tally['resets']} resets, {tally['saves']} saves, {tally['viewer reads']} viewer "
         f"reads, {tally['failed calls']} failed calls; nodes alive: {len(alive)} of "
         f'{len(NODES)}', 'all alive'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
