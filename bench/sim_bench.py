"""Benchmark of the simulator: rates across processes, real-time factor, render cost, speed.

The sim runs as its own process with its defaults (real-time factor 1, 640x480 camera at
30 Hz); this process subscribes like any other node would. Then, headless at real-time factor
0 with the camera off, it measures physics steps per second, and in this process the cost of
the protective stop's contact check on them. Run alone: python -m bench.sim_bench
"""

import re
import threading
import time

from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState

from bench.processes import (
    cpu_seconds,
    load,
    node_process,
    percentile,
    raw_steps_per_second,
    rss_mb,
)

WINDOW_S = 20.0
WARMUP_S = 3.0
HEADLESS_WINDOW_S = 5.0
HEADLESS_RUNS = 3
RAW_S = 1.5
DOMAIN_ID = 211
READY = 'simulating'


class _Listener:
    """Counts joint_states and colour images, and tracks /clock, in a node of its own."""

    def __init__(self, domain_id: int) -> None:
        self.context = Context()
        self.context.init(domain_id=domain_id)
        self.node = Node('sim_bench_listener', context=self.context)
        self.lock = threading.Lock()
        self.joint_states = 0
        self.image_stamps: list[int] = []
        self.sim_ns = 0
        image_qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(JointState, 'joint_states', self._on_joint_states, 100)
        self.node.create_subscription(Image, 'camera/color/image_raw', self._on_image,
                                      image_qos)
        self.node.create_subscription(Clock, '/clock', self._on_clock, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_joint_states(self, msg: JointState) -> None:
        with self.lock:
            self.joint_states += 1

    def _on_image(self, msg: Image) -> None:
        with self.lock:
            self.image_stamps.append(msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec)

    def _on_clock(self, msg: Clock) -> None:
        with self.lock:
            self.sim_ns = max(self.sim_ns, msg.clock.sec * 10 ** 9 + msg.clock.nanosec)

    def snapshot(self) -> tuple[float, int, int, int]:
        with self.lock:
            return time.monotonic(), self.joint_states, len(self.image_stamps), self.sim_ns

    def wait(self, predicate, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise RuntimeError(f'benchmark: no {what} within {timeout:.0f} s')
            time.sleep(0.05)

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=5)
        self.thread.join(timeout=5)
        self.node.destroy_node()
        self.context.try_shutdown()


def _real_time_run() -> list[tuple[str, str, str]]:
    listener = _Listener(DOMAIN_ID)
    try:
        with node_process('sim', {}, DOMAIN_ID, ready=READY) as sim:
            listener.wait(lambda: listener.snapshot()[2] > 0, 60, 'camera image')
            time.sleep(WARMUP_S)
            wall0, joints0, images0, sim0 = listener.snapshot()
            cpu0 = cpu_seconds(sim.pid)
            time.sleep(WINDOW_S)
            wall1, joints1, images1, sim1 = listener.snapshot()
            cpu1 = cpu_seconds(sim.pid)
            rss = rss_mb(sim.pid)
            with listener.lock:
                stamps = listener.image_stamps[images0:images1]
    finally:
        listener.close()
    wall = wall1 - wall0
    period_ns = 10 ** 9 / 30.0
    expected = round((stamps[-1] - stamps[0]) / period_ns) + 1 if stamps else 0
    lost = max(expected - len(stamps), 0)
    return [
        ('sim: joint_states rate (other process)', f'{(joints1 - joints0) / wall:.1f} Hz',
         '>= 99 Hz'),
        ('sim: camera rate (other process)', f'{(images1 - images0) / wall:.1f} Hz', '>= 29 Hz'),
        ('sim: camera frames lost', f'{lost} of {expected} ({100 * lost / max(expected, 1):.2f}%)',
         '< 1%'),
        ('sim: real-time factor', f'{(sim1 - sim0) / 1e9 / wall:.3f}', '>= 0.98'),
        ('sim: CPU (640x480 @ 30 Hz, RTF 1)', f'{100 * (cpu1 - cpu0) / wall:.0f}% of a core', ''),
        ('sim: RSS', f'{rss:.0f} MB', ''),
    ]


def _render_times() -> list[tuple[str, str, str]]:
    """Both renderers on the same scene in the same run, interleaved frame by frame."""
    from ur_rg2_common.contract import ARM_JOINTS
    from ur_rg2_sim.camera import Camera, CameraConfig
    from ur_rg2_sim.world import SimWorld, WorldConfig

    world = SimWorld(WorldConfig())
    cameras = {}
    try:
        # The arm bent into view over the ball: the pick's scene, every body in the frame.
        world.set_arm_positions(dict(zip(ARM_JOINTS, [-0.6, -1.2, 1.6, -1.9, -1.57, 0.0])))
        cameras = {name: Camera(world, CameraConfig(), name) for name in ('auto', 'tiny')}
        times = {name: [] for name in cameras}
        for camera in cameras.values():
            camera.render()
        for _ in range(100):
            for name, camera in cameras.items():
                start = time.perf_counter()
                camera.render()
                times[name].append(1000 * (time.perf_counter() - start))
        drawn_by = cameras['auto'].renderer.name
    finally:
        for camera in cameras.values():
            camera.close()
        world.close()
    ours, tiny = (percentile(times[name], 95) for name in ('auto', 'tiny'))
    return [
        (f'sim: render 640x480 RGB-D ({drawn_by}), ms p50 / p95',
         f"{percentile(times['auto'], 50):.1f} / {ours:.1f}", 'p95 <= 30 ms'),
        ('sim: render, TinyRenderer on the same scene, ms p50 / p95',
         f"{percentile(times['tiny'], 50):.1f} / {tiny:.1f}", ''),
        (f'sim: render speed-up over TinyRenderer ({drawn_by}), p95 ratio', f'{tiny / ours:.1f}x',
         '>= 5x'),
    ]


def _default_world_raw_rate(seconds: float) -> float:
    from ur_rg2_sim.world import SimWorld, WorldConfig

    world = SimWorld(WorldConfig())  # the sim's at its default parameters
    try:
        raw_steps_per_second(world, 0.2)  # settled, as the sim's world is after its start
        return raw_steps_per_second(world, seconds)
    finally:
        world.close()


def _headless_speed() -> list[tuple[str, str, str]]:
    """Return the sim's physics steps/s beside stepSimulation's alone on the same world.

    In turns (raw, sim, raw, sim, ...), so that the machine's drift hits both alike; each sim
    run is compared with the raw runs before and after it, and the median run's ratio is the
    row's. No subscriber: a reader of 100 Hz-of-sim-time topics at this speed would compete
    for the two cores. The sim reports its own speed when it stops.
    """
    parameters = {'real_time_factor': '0.0', 'camera_rate': '0.0'}
    loads, node, raw = [load()], [], [_default_world_raw_rate(RAW_S)]
    for _ in range(HEADLESS_RUNS):
        with node_process('sim', parameters, DOMAIN_ID + 1, ready=READY) as sim:
            time.sleep(HEADLESS_WINDOW_S)
        found = re.search(r'([\d,]+) physics steps/s', sim.log)
        if not found:
            raise RuntimeError(f'benchmark: the sim did not report its speed: {sim.log[-2000:]}')
        node.append(float(found.group(1).replace(',', '')))
        raw.append(_default_world_raw_rate(RAW_S))
        loads.append(load())
    runs = sorted((stepped / ((before + after) / 2), stepped, (before + after) / 2)
                  for stepped, before, after in zip(node, raw, raw[1:]))
    ratio = runs[len(runs) // 2][0]
    return [('sim: physics steps/s headless (RTF 0, camera off, no subscriber) / stepSimulation '
             'alone on the same world, this run',
             f"{ratio:.3f}, the median of {len(runs)} runs: "
             f"{', '.join(f'{stepped:,.0f} / {alone:,.0f}' for _, stepped, alone in runs)} "
             f"(load {'-'.join(loads)})", '>= 0.9')]


def _steps_per_second(world, stop, seconds: float) -> float:
    steps, now_ns = 0, 0
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(240):
            if stop is not None:
                stop.step(world, now_ns)
            world.step()
            now_ns += world.dt * 1e9
        steps += 240
    return steps / (time.perf_counter() - start)


def _contact_check_cost() -> list[tuple[str, str, str]]:
    """Physics steps/s in this process with and without the protective stop's check.

    Side by side in one world, alternating, so that the machine's drift hits both alike; the
    arm free (no contact: one query per step), then resting on the floor (a contact each
    step: its Jacobian too).
    """
    from ur_rg2_sim.safety import ProtectiveStop
    from ur_rg2_sim.world import SimWorld, WorldConfig

    world = SimWorld(WorldConfig())
    stop = ProtectiveStop(lambda *_: None)
    rates: dict[tuple[str, bool], list[float]] = {}
    try:
        for pose in ('free', 'on the floor'):
            if pose == 'on the floor':
                world.move_arm({'shoulder_lift_joint': 1.6})
                _steps_per_second(world, stop, 2.0)  # down onto the floor, stopped there
            for _ in range(3):
                for checked in (False, True):
                    rates.setdefault((pose, checked), []).append(
                        _steps_per_second(world, stop if checked else None, 1.0))
    finally:
        world.close()
    best = {key: max(values) for key, values in rates.items()}
    return [(f'sim: physics steps/s in-process without / with the contact check ({pose})',
             f'{best[(pose, False)]:,.0f} / {best[(pose, True)]:,.0f} '
             f'({100 * (1 - best[(pose, True)] / best[(pose, False)]):.0f}% fewer)',
             '<= 10% fewer' if pose == 'free' else '')
            for pose in ('free', 'on the floor')]


def run() -> list[tuple[str, str, str]]:
    """Measure the simulator; return (metric, measured, target) rows."""
    return _real_time_run() + _render_times() + _headless_speed() + _contact_check_cost()


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
