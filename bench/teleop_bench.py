"""Benchmark of the keyboard teleop: key press to ``joint_jog`` and to the arm moving.

``keys`` runs on a pseudo-terminal and the sim as a separate process at its default rates
(camera off), on a private DDS domain kept on this host. This process types the keys, and
receives ``joint_jog`` and ``joint_states`` itself, so both latencies cross a process boundary
and include this process's rclpy dispatch. Run alone with ``python -m bench.teleop_bench``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import itertools
import math
import os
from pathlib import Path
import random
import select
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from rclpy.node import Node
from sensor_msgs.msg import JointState

from bench.processes import bench_env, node_process, spun_node

TRIALS = 200  # p99 then rests on the two slowest, not on one outlier
WARMUP_TRIALS = 5
START_TIMEOUT_S = 90.0
TRIAL_TIMEOUT_S = 5.0
JOINT = 'shoulder_pan_joint'
KEYS = (b'q', b'w')  # + and - on JOINT: the arm swings back and forth in place
MOVED_RAD = 1e-4  # a change in position larger than any jitter of a joint at rest
STILL_STATES = 5  # joint states in a row without a position change: the arm is at rest
# Key presses come at any phase of the 100 Hz joint_states; spread them over one period.
PHASE_SPREAD_S = 0.01
JOG_TARGET_MS = 10.0
MOVE_TARGET_MS = 30.0


class _Probe:
    """Arrival times of joint_jog and of the JOINT moving, seen from this process."""

    def __init__(self, node: Node) -> None:
        self._changed = threading.Condition()
        self.jogs: list[float] = []
        self.position: float | None = None
        self.still = 0  # joint states in a row in which JOINT did not move
        self.baseline = math.nan
        self.moved_at: float | None = None
        node.create_subscription(JointState, 'joint_jog', self._on_jog, 100)
        node.create_subscription(JointState, 'joint_states', self._on_state, 100)

    def _on_jog(self, _msg: JointState) -> None:
        now = time.monotonic()
        with self._changed:
            self.jogs.append(now)
            self._changed.notify_all()

    def _on_state(self, msg: JointState) -> None:
        now = time.monotonic()
        index = list(msg.name).index(JOINT)
        with self._changed:
            previous, self.position = self.position, msg.position[index]
            moving = previous is None or abs(self.position - previous) > MOVED_RAD / 10
            self.still = 0 if moving else self.still + 1
            if self.moved_at is None and abs(self.position - self.baseline) > MOVED_RAD:
                self.moved_at = now
            self._changed.notify_all()

    def wait(self, predicate, timeout: float, what: str) -> None:
        """Wait until ``predicate()`` holds (checked at each message); raise on timeout."""
        with self._changed:
            if not self._changed.wait_for(predicate, timeout):
                raise RuntimeError(f'timed out after {timeout:.0f} s waiting for {what}')

    def arm(self) -> int:
        """Start watching for the next move from the current position; return the jog count."""
        with self._changed:
            self.baseline = self.position
            self.moved_at = None
            return len(self.jogs)


@contextmanager
def _keys_terminal(env: dict[str, str], log: Path) -> Iterator[int]:
    """Run ``keys`` on a pseudo-terminal, its output drained to ``log``; yield the master fd."""
    master, slave = os.openpty()
    process = subprocess.Popen([str(Path(sys.executable).with_name('keys'))], stdin=slave,
                               stdout=slave, stderr=slave, env=env, start_new_session=True)
    stop = threading.Event()

    def drain() -> None:
        # keys blocks on a full terminal if nobody reads its output.
        with log.open('wb') as out:
            while not stop.is_set():
                if select.select([master], [], [], 0.1)[0]:
                    out.write(os.read(master, 65536))
                    out.flush()

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    try:
        yield master
    finally:
        os.write(master, b'p')
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        stop.set()
        reader.join()
        os.close(master)
        os.close(slave)


def _trial(probe: _Probe, master: int, key: bytes) -> tuple[float, float]:
    """Press ``key`` with the arm at rest; return (key→joint_jog, key→moving) in seconds."""
    probe.wait(lambda: probe.still >= STILL_STATES, TRIAL_TIMEOUT_S, 'the arm at rest')
    time.sleep(random.uniform(0.0, PHASE_SPREAD_S))
    jogs = probe.arm()
    pressed = time.monotonic()
    os.write(master, key)
    probe.wait(lambda: len(probe.jogs) > jogs and probe.moved_at is not None, TRIAL_TIMEOUT_S,
               f'joint_jog and {JOINT} moving after {key.decode()!r}')
    return probe.jogs[jogs] - pressed, probe.moved_at - pressed


def _connect(probe: _Probe, master: int) -> None:
    """Press keys until both this process and the sim get them (discovery is done)."""
    deadline = time.monotonic() + START_TIMEOUT_S
    probe.wait(lambda: probe.position is not None, START_TIMEOUT_S, 'joint_states from the sim')
    for trial in itertools.count():
        try:
            _trial(probe, master, KEYS[trial % 2])
            return
        except RuntimeError:
            if time.monotonic() > deadline:
                raise


def _percentile(samples: list[float], p: int) -> float:
    return statistics.quantiles(samples, n=100, method='inclusive')[p - 1] * 1000.0


def run() -> list[tuple[str, str, str]]:
    """Measure the teleop; return benchmark rows (metric, measured, target)."""
    domain_id = 150 + os.getpid() % 80
    env = bench_env(domain_id)
    with tempfile.TemporaryDirectory(prefix='teleop-bench-') as tmp, \
            node_process('sim', {'camera_rate': '0.0'}, domain_id, ready='simulating'), \
            spun_node('teleop_bench', domain_id) as node:
        probe = _Probe(node)
        with _keys_terminal(env, Path(tmp, 'keys.log')) as master:
            _connect(probe, master)
            results = [_trial(probe, master, KEYS[i % 2])
                       for i in range(WARMUP_TRIALS + TRIALS)]
    jog, move = (list(column) for column in zip(*results[WARMUP_TRIALS:], strict=True))
    # The tail is the scheduler's on a shared 2-core machine; say how busy it was.
    load = f'load {os.getloadavg()[0]:.1f}'
    return [
        ('teleop key → joint_jog in another process, p50 / p99',
         f'{_percentile(jog, 50):.2f} / {_percentile(jog, 99):.2f} ms ({TRIALS} keys, {load})',
         f'p99 ≤ {JOG_TARGET_MS:g} ms'),
        ('teleop key → joint_states shows the joint moving, p99',
         f'{_percentile(move, 99):.1f} ms (p50 {_percentile(move, 50):.1f} ms; sim at default '
         f'rates, camera off; {load})',
         f'≤ {MOVE_TARGET_MS:g} ms'),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
