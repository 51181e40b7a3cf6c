"""Benchmark of the sim's transform tree: rates with /tf on, and what /tf costs the sim thread.

The sim runs as its own process with its defaults (real-time factor 1, 640x480 camera at
30 Hz, /tf at joint_state_rate) while this process subscribes to joint_states, /tf, the colour
images and /clock. Then a microbenchmark times, in this process, exactly what the simulation
thread does per joint_states sample for the frames (ball pose from pybullet, the eight moving
transforms, filling and publishing /tf and ball/true_pose) with a /tf subscriber matched.
Run alone: python -m bench.frames_bench
"""

import time

from geometry_msgs.msg import PoseStamped
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from tf2_msgs.msg import TFMessage

from bench.processes import cpu_seconds, node_process, percentile
from bench.sim_bench import READY, WARMUP_S, WINDOW_S
from bench.sim_bench import _Listener as SimListener

DOMAIN_ID = 215
PUBLISHES = 3000
JOINT_STATE_RATE = 100.0  # Hz, the sim's default


class _Listener(SimListener):
    """The sim benchmark's listener, also counting /tf messages."""

    def __init__(self, domain_id: int) -> None:
        from ur_rg2_common.contract import TF_QOS

        self.tf = 0
        super().__init__(domain_id)
        self.node.create_subscription(TFMessage, '/tf', self._on_tf, TF_QOS)

    def _on_tf(self, msg: TFMessage) -> None:
        with self.lock:
            self.tf += 1

    def tf_count(self) -> int:
        with self.lock:
            return self.tf


def _real_time_run() -> list[tuple[str, str, str]]:
    listener = _Listener(DOMAIN_ID)
    try:
        with node_process('sim', {}, DOMAIN_ID, ready=READY) as sim:
            listener.wait(lambda: listener.snapshot()[2] > 0 and listener.tf_count() > 0, 60,
                          'camera image and /tf')
            time.sleep(WARMUP_S)
            wall0, joints0, images0, sim0 = listener.snapshot()
            tf0, cpu0 = listener.tf_count(), cpu_seconds(sim.pid)
            time.sleep(WINDOW_S)
            wall1, joints1, images1, sim1 = listener.snapshot()
            tf1, cpu1 = listener.tf_count(), cpu_seconds(sim.pid)
    finally:
        listener.close()
    wall = wall1 - wall0
    return [
        ('frames: joint_states rate with /tf on', f'{(joints1 - joints0) / wall:.1f} Hz',
         '>= 99 Hz'),
        ('frames: /tf rate (other process)', f'{(tf1 - tf0) / wall:.1f} Hz', '= joint_states'),
        ('frames: camera rate with /tf on', f'{(images1 - images0) / wall:.1f} Hz', '>= 29 Hz'),
        ('frames: real-time factor with /tf on', f'{(sim1 - sim0) / 1e9 / wall:.3f}',
         '>= 0.98'),
        ('frames: sim CPU with /tf on (640x480 @ 30 Hz)',
         f'{100 * (cpu1 - cpu0) / wall:.0f}% of a core', ''),
    ]


def _publish_cost() -> list[tuple[str, str, str]]:
    from ur_rg2_common.contract import TF_QOS
    from ur_rg2_sim.frame_publisher import FramePublisher
    from ur_rg2_sim.frames import load_frame_tree, robot_description
    from ur_rg2_sim.world import SimWorld, WorldConfig

    context = Context()
    context.init(domain_id=DOMAIN_ID + 1)
    node = Node('frames_bench', context=context)
    # Not spun: its DDS reader still receives, which is all the publisher's cost depends on.
    reader = Node('frames_bench_reader', context=context)
    reader.create_subscription(TFMessage, '/tf', lambda _: None, TF_QOS)
    reader.create_subscription(PoseStamped, 'ball/true_pose', lambda _: None, 10)
    world = SimWorld(WorldConfig())
    executor = SingleThreadedExecutor(context=context)
    try:
        frames = FramePublisher(node, load_frame_tree(world, world.urdf),
                                robot_description(world.urdf), '', world.joint_names)
        # A matched reader, as its matched event tells: publish then really serialises and
        # sends (without one, /tf is not published at all).
        executor.add_node(node)
        deadline = time.monotonic() + 20
        while not frames.subscribed and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        settle = time.monotonic() + 1.0  # the other topic's match
        while time.monotonic() < settle:
            executor.spin_once(timeout_sec=0.05)
        times = []
        for i in range(PUBLISHES):
            world.step()
            sample = world.joint_states()
            start = time.perf_counter()
            frames.publish(i * 10_000_000, sample.positions, world.body_pose(world.ball))
            times.append(1e6 * (time.perf_counter() - start))
    finally:
        executor.shutdown()
        world.close()
        reader.destroy_node()
        node.destroy_node()
        context.try_shutdown()
    mean = sum(times) / len(times)
    return [
        ('frames: /tf + ball/true_pose publish, us p50 / p95 / mean',
         f'{percentile(times, 50):.0f} / {percentile(times, 95):.0f} / {mean:.0f}', ''),
        (f'frames: added sim CPU for /tf at {JOINT_STATE_RATE:g} Hz',
         f'{mean * JOINT_STATE_RATE / 1e4:.1f}% of a core', '<= 10%'),
    ]


def run() -> list[tuple[str, str, str]]:
    """Measure the frames' cost; return (metric, measured, target) rows."""
    return _real_time_run() + _publish_cost()


if __name__ == '__main__':
    from bench.__main__ import print_table

    print_table(run())
