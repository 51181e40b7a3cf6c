"""Balls of any size, without configuration: frames rendered by the sim, and the node in a graph.

Seeded frames (:mod:`ur_rg2_detector.scenes`): one red ball of 1.5-8 cm radius, 0.5-2 m from the
camera, anywhere in the image, on the floor or in the air; and red cubes, boxes, flat patches
and balls of other colours of the same sizes. The vision at its defaults (``ball_radius`` 0:
measured). The radius errors are in the assertion messages and printed (``pytest -s``).
"""

import functools
import threading

from conftest import start_sim, wait_for
from geometry_msgs.msg import PointStamped
import numpy as np
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import IMAGE_QOS
from ur_rg2_detector.scenes import MIN_VISIBLE, no_balls, sized_balls
from ur_rg2_vision.detector import BallDetector
from ur_rg2_vision.localize import locate_first
from ur_rg2_vision.vision_node import VisionNode

BALLS = 40
NOT_BALLS = 24
TIMEOUT = 30.0  # the sim and the vision in one process on a loaded 2-core machine


@functools.cache
def ball_results() -> tuple:
    """Return (shot, position or None) for the seeded balls."""
    detector = BallDetector()
    return tuple((s, locate_first(detector.detect(s.rgb, s.k), s.depth, s.k))
                 for s in sized_balls(BALLS, seed=11))


def test_the_set_spans_the_sizes_and_distances():
    shots = [s for s, _ in ball_results()]
    assert all(s.visible >= MIN_VISIBLE for s in shots)
    radii = [s.radius for s in shots]
    distances = [np.linalg.norm(s.centre) for s in shots]
    assert min(radii) < 0.02 and max(radii) > 0.065
    assert min(distances) < 0.75 and max(distances) > 1.75
    assert min(s.radius_px for s in shots) < 8 and max(s.radius_px for s in shots) > 50


def test_balls_of_1_5_to_8_cm_are_found():
    missed = [f'{s.name} at {np.linalg.norm(s.centre):.2f} m ({s.radius_px:.1f} px)'
              for s, p in ball_results() if p is None]
    assert len(missed) <= BALLS * 0.02, f'missed {missed}'


def test_balls_of_1_5_to_8_cm_are_located_and_measured():
    found = [(s, p) for s, p in ball_results() if p is not None]
    errors = np.array([np.linalg.norm(np.array([p.x, p.y, p.z]) - s.centre) for s, p in found])
    radius_errors = np.array([p.radius - s.radius for s, p in found])
    report = (f'3D error median {np.median(errors) * 1000:.2f} mm, p95 '
              f'{np.percentile(errors, 95) * 1000:.2f} mm; radius error median '
              f'{np.median(np.abs(radius_errors)) * 1000:.2f} mm (mean '
              f'{radius_errors.mean() * 1000:+.2f} mm), max '
              f'{np.abs(radius_errors).max() * 1000:.2f} mm')
    print(report)
    assert np.median(errors) <= 0.003 and np.percentile(errors, 95) <= 0.008, report
    assert np.median(np.abs(radius_errors)) <= 0.002, report
    # No ball is taken for one of a very different size.
    assert (np.abs(radius_errors) <= 0.15 * np.array([s.radius for s, _ in found])).all(), report


def test_cubes_boxes_patches_and_other_colours_are_not_balls():
    detector = BallDetector()
    wrong = [s.name for s in no_balls(NOT_BALLS, seed=12)
             if locate_first(detector.detect(s.rgb, s.k), s.depth, s.k) is not None]
    assert not wrong, f'a ball found in {wrong}'


class _Listener:
    """Records ball/position and the stamps of ball/image."""

    def __init__(self, graph) -> None:
        node = graph.node('ball_listener')
        self._lock = threading.Lock()
        self.positions: list[PointStamped] = []
        self.image_stamps: list[float] = []
        node.create_subscription(PointStamped, 'ball/position', self._on_position, 100)
        node.create_subscription(Image, 'ball/image', self._on_image, IMAGE_QOS)

    def _on_position(self, msg: PointStamped) -> None:
        with self._lock:
            self.positions.append(msg)

    def _on_image(self, msg: Image) -> None:
        with self._lock:
            self.image_stamps.append(_seconds(msg))

    def positions_after(self, stamp: float) -> list[PointStamped]:
        with self._lock:
            return [p for p in self.positions if _seconds(p) > stamp]

    def latest_image(self) -> float:
        with self._lock:
            return self.image_stamps[-1] if self.image_stamps else -1.0


def _seconds(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def test_node_finds_a_5_cm_ball_at_its_defaults(ros_graph, tmp_path):
    camera, look_at, ball = [1.3, -1.1, 0.95], [0.3, -0.1, 0.1], [0.6, -0.6, 0.05]
    start_sim(ros_graph, ball_radius=0.05, ball_position=ball, camera_position=camera,
              camera_look_at=look_at)
    vision = ros_graph.add(VisionNode(context=ros_graph.context, parameter_overrides=[
        Parameter('frames_dir', value=str(tmp_path))]))
    listener = _Listener(ros_graph)
    expected = optical_rotation(camera, look_at).T @ (np.array(ball) - camera)

    def located_after(stamp: float) -> list[PointStamped]:
        return [p for p in listener.positions_after(stamp)
                if np.linalg.norm([p.point.x, p.point.y, p.point.z] - expected) < 0.005]

    wait_for(lambda: len(located_after(0.0)) >= 3, TIMEOUT, 'the 5 cm ball at its place')
    # A radius given is assumed: the 5 cm ball is no 3 cm ball, and then it is again.
    assert vision.set_parameters([Parameter('ball_radius', value=0.03)])[0].successful
    changed = listener.latest_image()
    wait_for(lambda: listener.latest_image() > changed + 1.0, TIMEOUT, '1 s of ball/image')
    assert not listener.positions_after(changed + 0.5)
    assert vision.set_parameters([Parameter('ball_radius', value=0.05)])[0].successful
    changed = listener.latest_image()
    wait_for(lambda: located_after(changed + 0.5), TIMEOUT, 'the ball with its radius given')
