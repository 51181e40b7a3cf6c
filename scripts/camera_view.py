"""Make the README's picture: the vision node's camera view with the ball it detected.

Runs the real graph headless (what ``scripts/run`` runs, ``python -m ur_rg2_bringup.run``) on
a private ROS domain, waits until the scene has settled, and writes the ``ball/image`` frame
whose stamp vision also published a ``ball/position`` for, i.e. a frame with a detection drawn
on it.

usage: scripts/camera-view [OUTPUT.png] [NAME:=VALUE ...]   (default docs/camera_view.png;
       parameters go to the graph as with scripts/run, e.g. robot_model:=ur3)
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import cv2
from geometry_msgs.msg import PointStamped
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Image
from ur_rg2_vision.ros_image import image_to_rgb

ROOT = Path(__file__).resolve().parents[1]
# Detections to let pass first: the ball drops onto the floor and comes to rest.
SETTLE_DETECTIONS = 15
TIMEOUT_S = 120.0
# Recent frames kept to pair with a detection that arrives after its image.
KEEP_IMAGES = 60


def capture(params: list[str], domain_id: int) -> Image:
    """Run the graph with ``params``; return a ``ball/image`` frame with a detection."""
    rclpy.init(domain_id=domain_id)
    node = Node('camera_view')
    images: dict[tuple[int, int], Image] = {}
    detected: list[tuple[int, int]] = []

    def stamp(msg: Image | PointStamped) -> tuple[int, int]:
        return msg.header.stamp.sec, msg.header.stamp.nanosec

    def on_image(msg: Image) -> None:
        images[stamp(msg)] = msg
        if len(images) > KEEP_IMAGES:
            del images[next(iter(images))]  # the oldest

    # Reliable like the vision node's publisher: best effort loses large frames.
    node.create_subscription(Image, 'ball/image', on_image, QoSProfile(depth=30))
    node.create_subscription(PointStamped, 'ball/position',
                             lambda m: detected.append(stamp(m)), 10)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    graph = subprocess.Popen([sys.executable, '-m', 'ur_rg2_bringup.run', '--headless', 'port:=0',
                              *params],
                             env=env, stdin=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            rclpy.spin_once(node, timeout_sec=0.1)
            settled = detected[SETTLE_DETECTIONS:]
            frame = next((images[s] for s in settled if s in images), None)
            if frame is not None:
                return frame
            if graph.poll() is not None:
                raise RuntimeError(f'the graph ended (exit status {graph.returncode})')
            if time.monotonic() > deadline:
                raise RuntimeError(f'no frame with a detected ball within {TIMEOUT_S:.0f} s '
                                   f'({len(detected)} detections, {len(images)} images)')
    finally:
        graph.send_signal(signal.SIGTERM)
        try:
            graph.wait(timeout=20)
        except subprocess.TimeoutExpired:
            graph.kill()
        node.destroy_node()
        rclpy.shutdown()


def main(argv: list[str]) -> int:
    """Write the picture; return the exit status."""
    if argv[:1] in (['-h'], ['--help']):
        print(__doc__)
        return 0
    output = ROOT / 'docs/camera_view.png'
    if argv and ':=' not in argv[0]:
        output = Path(argv.pop(0))
    # A domain of its own, so that a graph the user is running is not disturbed.
    frame = capture(argv, domain_id=150 + os.getpid() % 80)
    output.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(output), cv2.cvtColor(image_to_rgb(frame), cv2.COLOR_RGB2BGR)):
        print(f'camera-view: cannot write {output}', file=sys.stderr)
        return 1
    print(f'camera-view: wrote {output} ({frame.width}x{frame.height})', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
