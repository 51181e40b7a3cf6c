"""Node ``ur_rg2_vision``: the ball's 3D position from the RGB-D camera, and frame saving.

ROS wiring only; the work is done by :mod:`ur_rg2_vision.detector` (colour + shape) or, with
``detector:=learned``, :mod:`ur_rg2_vision.learned` (a trained network, ONNX),
:mod:`ur_rg2_vision.localize` (depth) and :mod:`ur_rg2_vision.frame_store` (PNG files).

Each colour image is searched for the ball; its depth image (same stamp, before or after it)
completes it, and then ``ball/position`` is published. A learned model that sees the depth too
searches the frame when its depth has come. A few frames wait for their partner; a colour frame
whose depth never comes gets no position (and, with such a model, a ``ball/image`` without
detections once it is given up). The annotated copy on ``ball/image`` follows as soon as the
messages already waiting have been handled: a depth image that came right behind its colour
image gives the position first (publishing the image costs 1-2 ms).

All callbacks run one at a time on one thread (rclpy's multi-threaded executor cost more CPU
and fell behind at 30 Hz): no locks, and a save simply delays the next frame. OpenCV runs on
that thread too, without worker threads (``main``), and on the newest frame
(``NEWEST_IMAGE_QOS``): frames that came while one was worked on are dropped, not queued.
"""

from dataclasses import dataclass
import sys
import time

import cv2
from geometry_msgs.msg import Point, PointStamped
import numpy as np
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from ur_rg2_common.contract import IMAGE_QOS, NEWEST_IMAGE_QOS
from ur_rg2_common.parameters import declare_parameters, follow_settings
from ur_rg2_common.spin import keep_freed_memory, run_node

from ur_rg2_vision.detector import Detection, draw_detections
from ur_rg2_vision.frame_store import save_frame
from ur_rg2_vision.learned import BallModel, detection_config
from ur_rg2_vision.localize import BallPosition, locate_first
from ur_rg2_vision.pairing import FramePairs
from ur_rg2_vision.ros_image import camera_matrix, image_to_depth, image_to_rgb, rgb_to_image
from ur_rg2_vision.settings import PARAMETERS, VisionSettings

NODE_NAME = 'ur_rg2_vision'

_PENDING_FRAMES = 4  # colour frames waiting for their depth (~130 ms at 30 Hz)
_EARLY_DEPTHS = 4  # depth images that came before their colour image
_WARN_PERIOD_S = 10.0  # a persisting input problem is logged again after this long
# camera_info may match a little after the images: a warning only after this many and long.
_INFO_GRACE_FRAMES = 10
_INFO_GRACE_S = 2.0


@dataclass
class _Frame:
    """A colour frame, what was found in it, and its depth once that has come."""

    header: Header
    index: int  # counts colour frames
    rgb: np.ndarray
    detections: list[Detection]
    depth: np.ndarray | None = None
    autosave: bool = False


def _stamp_key(header: Header) -> tuple[int, int]:
    return header.stamp.sec, header.stamp.nanosec


class VisionNode(Node):
    """Publishes ``ball/position`` and ``ball/image``; serves ``vision/save_frame``."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = VisionSettings.from_values(declare_parameters(self, PARAMETERS))
        # Loaded once: read-only, and a missing or broken model stops the start (ModelError).
        self._model = BallModel(s.model_dir) if s.detector == 'learned' else None
        self._config = detection_config(s.color, s.min_radius_px, s.ball_radius, self._model)
        follow_settings(self, PARAMETERS, VisionSettings.from_values, self._apply_settings)

        self._camera: tuple[np.ndarray, tuple[int, int]] | None = None  # k, (width, height)
        self._awaiting_info: _Frame | None = None  # a complete frame without a fitting info
        # (since, frames): when ball frames began to lack a fitting camera_info, how many did.
        self._info_missing: tuple[float, int] | None = None
        self._pairs: FramePairs[_Frame] = FramePairs(_PENDING_FRAMES, _EARLY_DEPTHS)
        self._color_count = 0
        self._latest: _Frame | None = None  # the newest colour frame
        self._latest_complete: _Frame | None = None  # the newest one with its depth
        self._warned: dict[str, tuple[str, float]] = {}

        # All in the node's default, mutually exclusive callback group: one at a time, under
        # any executor. camera_info first: of messages ready together, it is taken first.
        self.create_subscription(CameraInfo, 'camera/color/camera_info', self._on_camera_info,
                                 IMAGE_QOS)
        self.create_subscription(Image, 'camera/color/image_raw', self._on_color,
                                 NEWEST_IMAGE_QOS)
        self.create_subscription(Image, 'camera/depth/image_raw', self._on_depth,
                                 NEWEST_IMAGE_QOS)
        self._position_pub = self.create_publisher(PointStamped, 'ball/position', 10)
        self._image_pub = self.create_publisher(Image, 'ball/image', IMAGE_QOS)
        # The executor takes a triggered guard condition after the subscriptions ready with it.
        self._unpublished: list[_Frame] = []  # colour frames whose ball/image is due
        self._images_due = self.create_guard_condition(self._publish_images)
        self.create_service(Trigger, 'vision/save_frame', self._on_save_frame)
        how = ('by its colour' if self._model is None
               else f'with the learned detector in {self._model.directory}')
        self.get_logger().info(
            f'looking for the ball {how} in {self.resolve_topic_name("camera/color/image_raw")}'
            f'; frames are saved to {s.frames_dir}')

    # -- parameters ---------------------------------------------------------------------------

    def _apply_settings(self, settings: VisionSettings) -> None:
        previous, self.settings = self.settings, settings
        # Balls are found with these from the next frame on.
        self._config = detection_config(settings.color, settings.min_radius_px,
                                         settings.ball_radius, self._model)
        if settings.frames_dir != previous.frames_dir:
            self.get_logger().info(f'frames are saved to {settings.frames_dir}')

    # -- inputs -------------------------------------------------------------------------------

    def _warn(self, source: str, text: str) -> None:
        """Log a problem once, and again only if it changes or persists for a while."""
        now = time.monotonic()
        last = self._warned.get(source)
        if last is None or last[0] != text or now - last[1] >= _WARN_PERIOD_S:
            self._warned[source] = (text, now)
            self.get_logger().warning(text)

    def _on_camera_info(self, msg: CameraInfo) -> None:
        try:
            self._camera = camera_matrix(msg), (msg.width, msg.height)
        except ValueError as error:
            self._warn('camera_info', f'camera_info ignored: {error}')
            return
        frame, self._awaiting_info = self._awaiting_info, None
        if frame is not None:
            self._publish_position(frame)

    def _on_color(self, msg: Image) -> None:
        try:
            rgb = image_to_rgb(msg)
        except ValueError as error:
            self._warn('color', f'colour image ignored: {error}')
            return
        self._color_count += 1
        frame = _Frame(msg.header, self._color_count, rgb, [])
        if not self._config.detector.needs_depth:
            self._detect(frame)
        every = self.settings.save_every_n
        frame.autosave = every > 0 and frame.index % every == 0
        self._latest = frame
        depth, stale = self._pairs.add_color(_stamp_key(msg.header), frame)
        for old in stale:  # its depth never came
            if self._config.detector.needs_depth:
                self._queue_image(old)  # as it is: the model had nothing to look at
            if old.autosave:  # save the colour alone
                self._autosave(old)
        if depth is not None:
            self._complete(frame, depth)  # the position before the (slower) image

    def _detect(self, frame: _Frame) -> None:
        """Find the balls in a frame (with its depth, for a detector that needs it).

        Queues the frame's ball/image, drawn with what was found.
        """
        try:
            frame.detections = self._config.detector.detect(
                frame.rgb, self._camera[0] if self._info_fits(frame) else None, frame.depth)
        except ValueError as error:  # a depth image of another size than the colour's
            self._warn('detect', f'no ball detection: {error}')
        self._queue_image(frame)

    def _queue_image(self, frame: _Frame) -> None:
        if self._image_pub.get_subscription_count() > 0:
            self._unpublished.append(frame)
            self._images_due.trigger()

    def _publish_images(self) -> None:
        frames, self._unpublished = self._unpublished, []
        for frame in frames:
            self._image_pub.publish(rgb_to_image(draw_detections(frame.rgb, frame.detections),
                                                 frame.header))

    def _on_depth(self, msg: Image) -> None:
        try:
            depth = image_to_depth(msg)
        except ValueError as error:
            self._warn('depth', f'depth image ignored: {error}')
            return
        frame = self._pairs.add_depth(_stamp_key(msg.header), depth)
        if frame is not None:
            self._complete(frame, depth)

    def _complete(self, frame: _Frame, depth: np.ndarray) -> None:
        """Pair a colour frame with its depth: publish the ball's position, autosave."""
        frame.depth = depth
        self._latest_complete = frame
        if self._config.detector.needs_depth:
            self._detect(frame)
        fits = self._info_fits(frame)
        if fits:
            self._info_missing = None
        if frame.detections and not fits:
            # Its camera_info may still be on the way: the next camera_info retries it.
            self._note_missing_info(frame)
            self._awaiting_info = frame
        else:
            self._publish_position(frame)
        if frame.autosave:
            self._autosave(frame)

    def _note_missing_info(self, frame: _Frame) -> None:
        """Count a ball frame without a fitting camera_info; warn once that persists."""
        now = time.monotonic()
        since, frames = self._info_missing or (now, 0)
        self._info_missing = since, frames + 1
        if frames + 1 >= _INFO_GRACE_FRAMES and now - since >= _INFO_GRACE_S:
            self._warn('locate', 'no camera/color/camera_info for the '
                       f'{frame.rgb.shape[1]}x{frame.rgb.shape[0]} colour images: '
                       'no ball/position')

    def _publish_position(self, frame: _Frame) -> None:
        position = self._locate(frame)
        if position is not None:
            self._position_pub.publish(PointStamped(
                header=frame.header, point=Point(x=position.x, y=position.y, z=position.z)))

    def _info_fits(self, frame: _Frame) -> bool:
        height, width = frame.rgb.shape[:2]
        return self._camera is not None and self._camera[1] == (width, height)

    def _locate(self, frame: _Frame) -> BallPosition | None:
        """Return the 3D position of the first detection the depth confirms as a ball."""
        if not frame.detections:
            return None
        height, width = frame.rgb.shape[:2]
        k, (info_width, info_height) = self._camera  # set: see _complete
        if (info_width, info_height) != (width, height):
            self._warn('locate', f'camera_info is for {info_width}x{info_height}, the colour '
                       f'image is {width}x{height}: no ball/position')
            return None
        if frame.depth.shape != (height, width):
            self._warn('locate', f'depth image {frame.depth.shape[1]}x{frame.depth.shape[0]} is '
                       f'not registered to the {width}x{height} colour image: no ball/position')
            return None
        return locate_first(frame.detections, frame.depth, k, self._config.ball_radius)

    # -- saving -------------------------------------------------------------------------------

    def _save(self, frame: _Frame) -> list[str]:
        stamp = frame.header.stamp
        return save_frame(self.settings.frames_dir, stamp.sec, stamp.nanosec, frame.rgb,
                          frame.depth)

    def _autosave(self, frame: _Frame) -> None:
        try:
            self._save(frame)
        except OSError as error:
            self._warn('autosave', 'save_every_n: cannot save to '
                       f'{self.settings.frames_dir!r}: {error}')

    def _on_save_frame(self, request: Trigger.Request, response: Trigger.Response
                       ) -> Trigger.Response:
        frame = self._latest
        complete = self._latest_complete
        if frame is None:
            response.success = False
            response.message = 'no camera frame received yet'
            return response
        if (frame.depth is None and complete is not None
                and frame.index - complete.index <= _PENDING_FRAMES):
            frame = complete  # the newest depth is still on its way: save the newest pair
        try:
            paths = self._save(frame)
        except OSError as error:
            response.success = False
            response.message = f'cannot save to {self.settings.frames_dir!r}: {error}'
            self.get_logger().warning(f'vision/save_frame: {response.message}')
            return response
        response.success = True
        response.message = ' '.join(paths)
        if frame.depth is None:
            response.message += ' (no depth image for this frame)'
        # Debug: the caller (keys) prints the answer; an info line would repeat it there.
        self.get_logger().debug(f'saved {response.message}')
        return response


def main(args: list[str] | None = None) -> int:
    """Run the node until Ctrl-C / SIGTERM; exit code 1 on invalid parameters."""
    keep_freed_memory()
    cv2.setNumThreads(1)  # see the module's docstring
    return run_node(VisionNode, args, NODE_NAME, startup_errors=(ValueError, ParameterException))


if __name__ == '__main__':
    sys.exit(main())
