"""The ``dataset`` command's run, without ROS: options, the sampler, the loop, the messages.

:class:`Sampler` places the ball for each sample through a driver of the sim (the ROS side,
:class:`ur_rg2_vision.dataset_node.SimDriver`: parameters set, frames, true poses and
/tf_static collected, waits), waits for a frame that shows it at rest and labels it; the
placements are in :mod:`ur_rg2_vision.placement`, the labels and the files in
:mod:`ur_rg2_vision.dataset`.
"""

from __future__ import annotations

import argparse
from collections import deque
from collections.abc import Sequence
import signal
import sys
import time

import numpy as np
from ur_rg2_common.tf_buffer import pose_matrix

from ur_rg2_vision.dataset import (
    DatasetWriter,
    Progress,
    check_writable,
    depth_png,
    hidden_fraction,
    yolo_label,
)
from ur_rg2_vision.placement import REACH, Camera, Placement, PlacementError, plan_placement
from ur_rg2_vision.ros_image import camera_matrix, image_to_depth, image_to_rgb
from ur_rg2_vision.sphere import sphere_box

SIM_NODE = 'ur_rg2_sim'
SIM_PARAMETERS = ('robot_model', 'ball_radius', 'ball_position', 'ball_color',
                  'camera_position', 'camera_look_at', 'scene_objects', 'floor_color',
                  'light_direction')
AT_REST_M = 1e-6  # consecutive true poses this close: the ball is at rest
ARRIVED_M = 0.005  # the ball is this near where it was put (it may settle, never roll off)
HIDDEN_MAX = 0.02  # more of the ball hidden than this: the placement is drawn again
EMPTY_MAX = 0.2  # more of the ball missing from the frame than this: wait for another frame
REDRAWS = 20  # placements drawn per sample before giving up
STALE_FRAMES = 5  # frames that miss the ball before giving up


class InterruptError(Exception):
    """SIGINT or SIGTERM arrived; ``signum`` says which."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class SimError(RuntimeError):
    """The sim is missing or does not do what is asked, with the reason."""


def ns(stamp) -> int:
    """Return a header stamp in nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class SimRecord:
    """What the sim published (frames, the ball's true poses, /tf_static), and the looks at it.

    The driver (:class:`ur_rg2_vision.dataset_node.SimDriver`) fills the queues from its
    subscriptions and adds ``get_parameters``, ``set_parameters`` and ``spin_until``.
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.stop_signal: int | None = None
        self.colors: deque = deque(maxlen=4)  # sensor_msgs Image
        self.infos: deque = deque(maxlen=8)  # sensor_msgs CameraInfo
        self.depths: deque = deque(maxlen=4)  # sensor_msgs Image
        self.poses: deque = deque(maxlen=50)  # geometry_msgs PoseStamped
        self.static: dict[str, tuple[str, np.ndarray, int]] = {}

    def add_static(self, t) -> None:
        """Keep a geometry_msgs TransformStamped of /tf_static."""
        p, q = t.transform.translation, t.transform.rotation
        self.static[t.child_frame_id] = (
            t.header.frame_id, pose_matrix((p.x, p.y, p.z), (q.x, q.y, q.z, q.w)),
            ns(t.header.stamp))

    def lookup(self, target: str, source: str) -> np.ndarray | None:
        """Return the pose of frame ``source`` in ``target`` from /tf_static, None if unknown."""
        poses = []
        for frame in (target, source):
            pose = np.eye(4)
            seen = set()
            while frame in self.static and frame not in seen:
                seen.add(frame)
                parent, edge, _ = self.static[frame]
                pose = edge @ pose
                frame = parent
            poses.append((frame, pose))
        (root_t, t), (root_s, s) = poses
        if root_t != root_s:
            return None
        return np.linalg.inv(t) @ s

    def frame_after(self, stamp_ns: int) -> tuple | None:
        """Return the first colour frame stamped after ``stamp_ns`` with its info and depth."""
        for color in self.colors:
            stamp = ns(color.header.stamp)
            if stamp <= stamp_ns:
                continue
            info = next((i for i in self.infos if ns(i.header.stamp) == stamp), None)
            depth = next((d for d in self.depths if ns(d.header.stamp) == stamp), None)
            if info is not None and depth is not None:
                return color, info, depth
        return None

    def resting_pose(self, target: Sequence[float]) -> tuple[np.ndarray, int] | None:
        """Return (position, stamp) once two consecutive true poses agree near ``target``."""
        if len(self.poses) < 2:
            return None
        a, b = self.poses[-2], self.poses[-1]
        pa, pb = (np.array([p.pose.position.x, p.pose.position.y, p.pose.position.z])
                  for p in (a, b))
        if (ns(b.header.stamp) > ns(a.header.stamp)
                and np.linalg.norm(pb - pa) <= AT_REST_M
                and np.linalg.norm(pb - np.asarray(target)) <= ARRIVED_M):
            return pb, ns(b.header.stamp)
        return None

    def pose_at_or_after(self, stamp_ns: int) -> tuple[np.ndarray] | None:
        """Return (the first true position stamped at or after ``stamp_ns``,) or None."""
        for p in self.poses:
            if ns(p.header.stamp) >= stamp_ns:
                return (np.array([p.pose.position.x, p.pose.position.y, p.pose.position.z]),)
        return None


class Sampler:
    """Places the ball for each sample, waits for a frame that shows it at rest, labels it."""

    def __init__(self, driver, args: argparse.Namespace) -> None:
        self.driver = driver
        self.args = args
        self.redrawn = 0
        self.empty = 0
        values = driver.get_parameters(SIM_PARAMETERS)
        self.original = {name: values[name] for name in
                         SIM_PARAMETERS[2:]}
        self.radius = float(values['ball_radius'])
        self.reach = REACH.get(str(values['robot_model']), REACH['ur3'])
        driver.spin_until(lambda: driver.frame_after(-1), 'a camera frame (camera/color/'
                          'image_raw with its camera_info and depth): is the camera on '
                          '(camera_rate > 0)?')
        color, info, _ = driver.frame_after(-1)
        driver.spin_until(lambda: driver.poses, "the ball's true pose (ball/true_pose)")
        self.world_frame = driver.poses[-1].header.frame_id
        self.optical_frame = color.header.frame_id
        self.camera = Camera(tuple(values['camera_position']), tuple(values['camera_look_at']),
                             camera_matrix(info), info.width, info.height)
        self.changed: set[str] = set()

    def placement(self, index: int, attempt: int) -> Placement:
        """Return sample ``index``'s placement (attempt > 0: drawn again)."""
        a = self.args
        return plan_placement(a.seed, index, attempt, self.camera, self.radius, self.reach,
                              a.out_of_view, a.jitter_camera, a.jitter_color,
                              distractors=a.distractors, jitter_scene=a.jitter_scene,
                              ball_color=self.original['ball_color'],
                              any_camera=a.any_camera)

    def sample(self, index: int) -> tuple[np.ndarray, np.ndarray, tuple | None]:
        """Return (rgb, depth, label) of sample ``index``: the ball placed, at rest, a new frame.

        The depth in metres (inf: no return), registered to the colour image.
        """
        for attempt in range(REDRAWS):
            placement = self.placement(index, attempt)
            result = self._shoot(placement)
            if result is not None:
                if result[2] is None:
                    self.empty += 1
                return result
            self.redrawn += 1
        raise SimError(f'sample {index}: the ball was hidden (by the robot?) in {REDRAWS} '
                       f'placements in a row')

    def _shoot(self, placement: Placement
               ) -> tuple[np.ndarray, np.ndarray, tuple | None] | None:
        d = self.driver
        # The scenery first: the frame taken once the ball rests then shows it too.
        values: dict[str, object] = {}
        if placement.objects is not None:
            values['scene_objects'] = placement.objects
        if placement.floor is not None:
            values['floor_color'], values['light_direction'] = (list(placement.floor),
                                                                list(placement.light))
        values['ball_position'] = list(placement.ball)
        if placement.camera is not None:
            values['camera_position'], values['camera_look_at'] = (list(v) for v in
                                                                   placement.camera)
        if placement.color is not None:
            values['ball_color'] = list(placement.color)
        self.changed.update(values)
        d.set_parameters(values)
        # What came before the change is of no use; what is still in flight is told apart by
        # the ball's position and the stamps.
        d.poses.clear()
        d.colors.clear()
        after = -1
        if placement.camera is not None:
            after = d.spin_until(lambda: self._camera_moved(*placement.camera),
                                 'the new camera pose on /tf_static')[0]
        for _ in range(STALE_FRAMES):
            position, rest_stamp = d.spin_until(lambda: d.resting_pose(placement.ball),
                                                'the ball to rest where it was put '
                                                '(ball/true_pose)')
            since = max(rest_stamp, after)
            color, info, depth = d.spin_until(lambda t=since: d.frame_after(t),
                                              'a camera frame after the ball came to rest')
            stamp = ns(color.header.stamp)
            then = d.spin_until(lambda t=stamp: d.pose_at_or_after(t),
                                'a true pose of the ball after the frame')[0]
            if np.linalg.norm(then - position) > AT_REST_M:
                continue  # it moved while the frame was taken
            # /tf_static is latched: at the sim's full speed a first frame can come before it.
            frame = color.header.frame_id
            world_to_optical = d.spin_until(
                lambda f=frame: self._static_pose(f),
                f'/tf_static to connect {self.world_frame} and {frame}')[0]
            center = (world_to_optical @ np.append(position, 1.0))[:3]
            k = camera_matrix(info)
            label = yolo_label(sphere_box(center, self.radius, k), info.width, info.height)
            metres = image_to_depth(depth)
            if label is not None:
                hidden, missing = hidden_fraction(center, self.radius, k, metres)
                if hidden > HIDDEN_MAX:
                    return None
                if missing > EMPTY_MAX:
                    after = stamp
                    continue
            return image_to_rgb(color), metres, label
        raise SimError(f'{STALE_FRAMES} frames in a row did not show the ball where '
                       f'ball/true_pose has it')

    def _static_pose(self, frame: str) -> tuple[np.ndarray] | None:
        """Return (the world's pose in ``frame``,) once /tf_static connects them."""
        pose = self.driver.lookup(frame, self.world_frame)
        return None if pose is None else (pose,)

    def _camera_moved(self, position: Sequence[float], look_at: Sequence[float]
                      ) -> tuple[int] | None:
        """Return (the stamp of /tf_static,) once it has the camera at this pose."""
        d = self.driver
        pose = d.lookup(self.world_frame, self.optical_frame)
        forward = np.subtract(look_at, position)
        forward /= np.linalg.norm(forward)
        # The sim sets parameters one by one: a pose with the new position alone is not it.
        if (pose is not None and np.allclose(pose[:3, 3], position, atol=1e-6)
                and np.allclose(pose[:3, 2], forward, atol=1e-6)):
            return (d.static[self.optical_frame][2],)
        return None

    def restore(self) -> None:
        """Put back the sim's parameters this run changed."""
        if self.changed:
            self.driver.set_parameters({name: self.original[name] for name in self.changed})


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    """Return the command line options (ROS arguments removed)."""
    parser = argparse.ArgumentParser(
        prog='dataset', formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description='Make a labelled YOLO data set of the ball with a running sim (ros2 run '
        'ur_rg2_sim sim; real_time_factor:=0 makes it fastest). For each sample the ball is '
        "put somewhere on the floor within the arm's reach (now and then out of view), and "
        'the first camera frame with it at rest is saved with the exact box of the projected '
        'sphere. Writes DIR/images/{train,val}/NNNNNN.png, DIR/labels/{train,val}/NNNNNN.txt '
        '("0 cx cy w h" normalised, empty when the ball is out of view) and DIR/data.yaml. '
        'Appends to an existing data set; Ctrl-C leaves every image with its label.',
        epilog='ROS arguments go after --ros-args, e.g. --ros-args -r __ns:=/robot1. '
        'Exit codes: 0 done, 1 error, 2 bad option, 130 / 143 interrupted by SIGINT / SIGTERM.')
    parser.add_argument('--count', '-n', type=_positive_int, default=100, metavar='N',
                        help='samples to write in this run')
    parser.add_argument('--out', '-o', default='dataset', metavar='DIR',
                        help='data set directory (created; appended to if it exists)')
    parser.add_argument('--val-fraction', type=_fraction, default=0.2, metavar='FRACTION',
                        help='share of the samples in the validation split')
    parser.add_argument('--seed', type=int, default=0,
                        help='random seed: one seed gives the same placements')
    parser.add_argument('--out-of-view', type=_fraction, default=0.1, metavar='FRACTION',
                        help='share of the samples with the ball out of view (empty labels)')
    parser.add_argument('--jitter-camera', action='store_true',
                        help='move the camera up to 15 cm around its pose for each sample')
    parser.add_argument('--any-camera', action='store_true',
                        help='look from a random camera pose for each sample: from any side of '
                        'the arm, 0.6-2.2 m from a point of the floor in its reach, 25-65 '
                        'degrees down')
    parser.add_argument('--jitter-color', action='store_true',
                        help='give the ball a random colour for each sample')
    parser.add_argument('--distractors', type=_count, default=0, metavar='N',
                        help='put up to N objects that are not balls (cubes, boxes, flat '
                        "discs; random sizes and colours, a third in the ball's colour) on the "
                        'floor in view for each sample; removed afterwards')
    parser.add_argument('--jitter-scene', action='store_true',
                        help='give the floor a random colour and the light a random '
                        'direction for each sample')
    parser.add_argument('--timeout', type=float, default=20.0, metavar='SECONDS',
                        help='longest wait for the sim (its services, a frame, the ball)')
    parser.add_argument('--sim-node', default=SIM_NODE, metavar='NAME',
                        help='name of the sim node whose parameters are set')
    parser.add_argument('--progress-every', type=_positive_int, default=10, metavar='N',
                        help='without a terminal: one progress line every N samples')
    return parser.parse_args(argv)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be at least 1, got {value}')
    return value


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be 0 or more, got {value}')
    return value


def _fraction(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f'must be between 0 and 1, got {value}')
    return value


def run(args: argparse.Namespace, driver) -> int:
    """Write ``args.count`` samples; return the exit code."""
    try:
        check_writable(args.out)
    except OSError as error:
        print(f'dataset: cannot write the data set to {args.out}: {error}', file=sys.stderr)
        return 1
    writer = None
    sampler = None
    written = before = 0
    progress = Progress(0)
    try:
        # The sim first: without one, nothing is created.
        sampler = Sampler(driver, args)
        renderer = driver.get_parameters(('renderer',))['renderer']
        writer = DatasetWriter(args.out, args.val_fraction,
                               f"the sim's renderer parameter: {renderer}" if renderer else '')
        if writer.removed_orphans:
            print(f'dataset: removed {writer.removed_orphans} label(s) without an image (left '
                  f'by a killed run)', file=sys.stderr)
        before = writer.count()
        started = time.monotonic()
        progress = Progress(args.count, every=args.progress_every)
        for _ in range(args.count):
            rgb, depth, label = sampler.sample(writer.next_index)
            writer.write(rgb, label, {'depth': ('.png', depth_png(depth))})
            written += 1
            progress.advance()
    except InterruptError as stop:
        progress.close()
        where = (f' to {writer.root} ({before + written} in the data set, every image with '
                 f'its label); run again to add more') if writer else ''
        print(f'dataset: interrupted by {stop}: wrote {written} of {args.count} samples{where}',
              file=sys.stderr)
        return 128 + stop.signum
    except (SimError, PlacementError, OSError, ValueError) as error:
        progress.close()
        print(f'dataset: {error}', file=sys.stderr)
        if written:
            print(f'dataset: wrote {written} samples to {writer.root} before that, every image '
                  f'with its label', file=sys.stderr)
        return 1
    finally:
        if sampler is not None:
            _restore(sampler, driver)
    elapsed = time.monotonic() - started
    print(f'dataset: wrote {written} samples to {writer.root} in {elapsed:.1f} s '
          f'({written / elapsed:.2f} samples/s; {sampler.empty} without the ball in view, '
          f'{sampler.redrawn} placements drawn again because the ball was hidden); '
          f'{before + written} in the data set', file=sys.stderr)
    return 0


def _restore(sampler: Sampler, driver) -> None:
    driver.stop_signal = None  # the restore must run even after a signal
    driver.timeout = min(driver.timeout, 5.0)
    try:
        sampler.restore()
    except (SimError, InterruptError) as error:
        print(f"dataset: could not restore the sim's parameters: {error}", file=sys.stderr)
