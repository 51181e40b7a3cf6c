"""Benchmark of the vision node: detection time, and latency and throughput across processes.

1. Detection: the node's per-frame work (find the ball, confirm and locate it with depth) on
   640x480 frames rendered by the sim: the ball near and far, partly hidden by the gripper,
   next to a red cube, and no ball.
2. Sizes: on seeded frames rendered by the sim (:mod:`ur_rg2_detector.scenes`), one red ball of
   1.5-8 cm radius 0.5-2 m away, the node at its defaults (the radius measured): how many are
   found, how far off their centre and radius are, and the time per frame; and frames of red
   cubes, boxes, flat patches and balls of other colours, in which no ball may be found.
3. Pipeline: ``vision`` runs as its own process on a private DDS domain kept on this host;
   this process publishes a rendered frame (colour, camera_info, depth, stamped now) at 30 Hz
   and subscribes to ``ball/position`` and ``ball/image`` like the viewer does. Latency is the
   colour stamp to ``ball/position`` arriving here, so it includes both transports and this
   process's rclpy dispatch.

Run alone with ``python -m bench.vision_bench``.
"""

import math
import threading
import time

from geometry_msgs.msg import PointStamped
import numpy as np
import pybullet
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from ur_rg2_common.spin import keep_freed_memory

from bench.processes import cpu_seconds, node_process, percentile, rss_mb

DOMAIN_ID = 214
RATE_HZ = 30.0
WARMUP_S = 3.0
WINDOW_S = 15.0
START_TIMEOUT_S = 60.0
REPEATS = 40  # timings per rendered frame
SIZED_BALLS = 300
NOT_BALLS = 150
SIZED_REPEATS = 3
SEED = 2026
FRAME_ID = 'camera_color_optical_frame'
QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)


def _render_frames() -> list:
    """Return sim frames (rgb, depth, k) of the cases the detector meets, and the ball's."""
    from ur_rg2_common.contract import ARM_JOINTS
    from ur_rg2_sim.camera import Camera, CameraConfig
    from ur_rg2_sim.world import SimWorld, WorldConfig

    world = SimWorld(WorldConfig())
    try:
        camera = Camera(world, CameraConfig())
        near = Camera(world, CameraConfig(position=(0.95, -0.75, 0.45),
                                          look_at=(0.45, -0.35, 0.03)))
        frames = []

        def shoot(ball, cam=camera):
            world.set_ball_position(ball)
            frame = cam.render()
            frames.append((frame.rgb, frame.depth, cam.k))

        ball = np.array([0.45, -0.35, 0.03])
        for x, y in [(0.45, -0.35), (-0.2, 0.6), (0.9, 0.2), (0.1, -0.7)]:
            shoot((x, y, 0.03))
        shoot(ball, near)
        shoot((0.0, 0.0, -1.0))  # no ball: hidden under the floor
        down = pybullet.getQuaternionFromEuler([math.pi, 0.0, 0.0])
        tcp = ball + 0.1 * (np.array(camera.config.position) - ball)
        world.set_arm_positions(world.inverse_kinematics(tcp, down))
        shoot(ball)  # split by the gripper's fingers
        world.set_arm_positions(dict.fromkeys(ARM_JOINTS, 0.0))
        cube = world.add_box((0.52, -0.35, 0.03), [0.03] * 3, (1, 0, 0, 1))
        shoot(ball)  # touching a red cube in the image
        world.remove_bodies([cube])
        world.set_ball_position(ball)
        default = camera.render()
    finally:
        world.close()
    return frames, (default.rgb, default.depth, camera.k)


def _detection_times(frames: list) -> list[float]:
    from ur_rg2_vision.detector import BallDetector
    from ur_rg2_vision.localize import locate_first

    detector = BallDetector()
    times = []
    for _ in range(REPEATS):
        for rgb, depth, k in frames:
            start = time.perf_counter()
            locate_first(detector.detect(rgb, k), depth, k)
            times.append(1000 * (time.perf_counter() - start))
    return times


def _sizes() -> dict[str, list]:
    """Run the node's per-frame work on the seeded frames of balls and of things not balls."""
    from ur_rg2_detector.scenes import no_balls, sized_balls
    from ur_rg2_vision.detector import BallDetector
    from ur_rg2_vision.localize import locate_first

    detector = BallDetector()
    result = {'missed': [], 'errors': [], 'radius_errors': [], 'times': [], 'false': []}
    for shot in sized_balls(SIZED_BALLS, SEED):  # one at a time: 2 MB each
        for _ in range(SIZED_REPEATS):
            start = time.perf_counter()
            position = locate_first(detector.detect(shot.rgb, shot.k), shot.depth, shot.k)
            result['times'].append(1000 * (time.perf_counter() - start))
        if position is None:
            result['missed'].append(shot.name)
            continue
        centre = np.array([position.x, position.y, position.z])
        result['errors'].append(1000 * np.linalg.norm(centre - shot.centre))
        result['radius_errors'].append(1000 * abs(position.radius - shot.radius))
    for shot in no_balls(NOT_BALLS, SEED + 1):
        if locate_first(detector.detect(shot.rgb, shot.k), shot.depth, shot.k) is not None:
            result['false'].append(shot.name)
    return result


class _Feeder:
    """Publishes one frame at 30 Hz, stamped now; records when each ball/position arrives.

    It stands in for the camera and the viewer, image handlers like the vision node, and so
    keeps freed memory as that does.
    """

    def __init__(self, rgb: np.ndarray, depth: np.ndarray, k: np.ndarray) -> None:
        keep_freed_memory()
        self.context = Context()
        self.context.init(domain_id=DOMAIN_ID)
        self.node = Node('vision_bench_feeder', context=self.context)
        height, width = depth.shape
        self.color = Image(height=height, width=width, encoding='rgb8', step=width * 3,
                           data=rgb.tobytes())
        self.depth = Image(height=height, width=width, encoding='32FC1', step=width * 4,
                           data=depth.astype(np.float32).tobytes())
        self.info = CameraInfo(width=width, height=height, distortion_model='plumb_bob',
                               d=[0.0] * 5, k=k.ravel().tolist())
        self.publishers = [self.node.create_publisher(Image, 'camera/color/image_raw', QOS),
                           self.node.create_publisher(CameraInfo, 'camera/color/camera_info',
                                                      QOS),
                           self.node.create_publisher(Image, 'camera/depth/image_raw', QOS)]
        self.lock = threading.Lock()
        self.sent: list[int] = []  # stamps, ns
        self.positions: list[tuple[int, int]] = []  # (stamp, arrival), ns
        self.images: list[int] = []  # stamps, ns
        self.node.create_subscription(PointStamped, 'ball/position', self._on_position, 100)
        self.node.create_subscription(Image, 'ball/image', self._on_image, QOS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spinner = threading.Thread(target=self.executor.spin, daemon=True)
        self.spinner.start()
        self.running = True
        self.feeder = threading.Thread(target=self._feed, daemon=True)

    def _on_position(self, msg: PointStamped) -> None:
        now = time.time_ns()
        with self.lock:
            self.positions.append((_nanoseconds(msg.header), now))

    def _on_image(self, msg: Image) -> None:
        with self.lock:
            self.images.append(_nanoseconds(msg.header))

    def _feed(self) -> None:
        period = 1.0 / RATE_HZ
        next_time = time.monotonic()
        while self.running:
            now = time.time_ns()
            header = Header(frame_id=FRAME_ID)
            header.stamp.sec, header.stamp.nanosec = divmod(now, 10 ** 9)
            for publisher, msg in zip(self.publishers, (self.color, self.info, self.depth)):
                msg.header = header
                publisher.publish(msg)
            with self.lock:
                self.sent.append(now)
            next_time += period
            time.sleep(max(0.0, next_time - time.monotonic()))

    def matched(self) -> bool:
        return all(p.get_subscription_count() for p in self.publishers)

    def window(self, start: int, end: int) -> tuple[int, list[float], int]:
        """Return frames sent, latencies (ms) of positions and images, stamped in [start, end)."""
        with self.lock:
            sent = sum(start <= t < end for t in self.sent)
            latencies = [(arrival - t) / 1e6 for t, arrival in self.positions if start <= t < end]
            images = sum(start <= t < end for t in self.images)
        return sent, latencies, images

    def close(self) -> None:
        self.running = False
        if self.feeder.is_alive():
            self.feeder.join(5)
        self.executor.shutdown(timeout_sec=5)
        self.spinner.join(5)  # a daemon thread still in rclpy at exit aborts the process
        self.node.destroy_node()
        self.context.try_shutdown()


def _nanoseconds(header: Header) -> int:
    return header.stamp.sec * 10 ** 9 + header.stamp.nanosec


def _wait(predicate, what: str) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f'benchmark: no {what} within {START_TIMEOUT_S:.0f} s')
        time.sleep(0.05)


def _pipeline(frame, parameters: dict | None = None) -> dict[str, float]:
    """Feed ``frame`` at 30 Hz to a vision process with ``parameters``; measure its answers."""
    feeder = _Feeder(*frame)
    try:
        with node_process('vision', parameters or {}, DOMAIN_ID, ready='looking for the ball',
                          timeout=START_TIMEOUT_S) as vision:
            _wait(feeder.matched, 'subscription by the vision node')
            feeder.feeder.start()
            _wait(lambda: feeder.positions, 'ball/position')
            time.sleep(WARMUP_S)
            start, cpu0 = time.time_ns(), cpu_seconds(vision.pid)
            time.sleep(WINDOW_S)
            end, cpu1 = time.time_ns(), cpu_seconds(vision.pid)
            rss = rss_mb(vision.pid)
            time.sleep(1.0)  # the last frames of the window come back
            sent, latencies, images = feeder.window(start, end)
    finally:
        feeder.close()
    wall = (end - start) / 1e9
    return {'sent': sent, 'positions': len(latencies), 'images': images, 'wall': wall,
            'p50': percentile(latencies, 50), 'p95': percentile(latencies, 95),
            'cpu': 100 * (cpu1 - cpu0) / wall, 'rss': rss}


def run() -> list[tuple[str, str, str]]:
    """Measure the vision node; return benchmark rows (metric, measured, target)."""
    frames, default = _render_frames()
    times = _detection_times(frames)
    sizes = _sizes()
    result = _pipeline(default)
    sent, positions, images = result['sent'], result['positions'], result['images']
    found = SIZED_BALLS - len(sizes['missed'])
    errors, radius_errors = sizes['errors'], sizes['radius_errors']
    return [
        ('vision: detection + 3D per 640x480 frame, ms p50 / p95',
         f'{percentile(times, 50):.1f} / {percentile(times, 95):.1f}', 'p95 <= 5 ms'),
        ('vision: balls of 1.5-8 cm at 0.5-2 m found, radius measured',
         f'{found} of {SIZED_BALLS} ({100 * found / SIZED_BALLS:.1f}%)', '>= 98%'),
        ('vision: false balls (red cubes, boxes, flat patches, other colours)',
         f'{len(sizes["false"])} of {NOT_BALLS}', '0'),
        ('vision: balls of 1.5-8 cm, 3D error, mm median / p95',
         f'{percentile(errors, 50):.2f} / {percentile(errors, 95):.2f}', '<= 3 / <= 8 mm'),
        ('vision: balls of 1.5-8 cm, radius error, mm median / p95',
         f'{percentile(radius_errors, 50):.2f} / {percentile(radius_errors, 95):.2f}',
         'median <= 2 mm'),
        ('vision: balls of 1.5-8 cm, detection + 3D per frame, ms p50 / p95',
         f'{percentile(sizes["times"], 50):.1f} / {percentile(sizes["times"], 95):.1f}',
         'p95 <= 5 ms'),
        ('vision: colour stamp -> ball/position in another process, ms p50 / p95',
         f'{result["p50"]:.1f} / {result["p95"]:.1f}', 'p95 <= 15 ms'),
        ('vision: frames processed, fed at 30 Hz (ball/position, ball/image)',
         f'{positions} and {images} of {sent} ({positions / result["wall"]:.1f}/s)', 'all'),
        ('vision: CPU at 30 Hz (with ball/image)', f'{result["cpu"]:.0f}% of a core', ''),
        ('vision: RSS', f'{result["rss"]:.0f} MB', ''),
    ]


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
