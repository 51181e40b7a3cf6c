"""Node ``ur_rg2_viewer``: the camera, joint angles, gripper and ball, live in a web browser.

For headless users (SSH, containers): open the logged URL. The HTTP side lives in
:mod:`ur_rg2_vision.viewer_web`; this module only wires ROS topics into its hub.

The ball's position comes in the camera's optical frame. It is shown in ``world`` and
``base_link`` too, through the transform tree (``/tf_static``). Without a tree (a sim that
publishes none) the world coordinates are computed from the sim's camera pose, asked from the
sim node's ``camera_position`` and ``camera_look_at`` parameters every few seconds (they may
change). The last ``pick_ball`` result of the motion node is shown as it comes, whether the
learned policy (ur_rg2_learning's ``policy`` node, ``policy/driving``) drives the arm, and its
last episode's outcome (``policy/result``).

The images, joint states and the ball wait in an :class:`~ur_rg2_common.inbox.Inbox` until a
page asks for them; images are taken serialized, and decoded only when a page shows them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import sys
import time

from geometry_msgs.msg import PointStamped
import numpy as np
from rcl_interfaces.srv import GetParameters
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.task import Future
from sensor_msgs.msg import Image, JointState
from std_msgs.msg import Bool, String
from tf2_msgs.msg import TFMessage
from ur_rg2_common.camera_pose import optical_rotation
from ur_rg2_common.contract import LATCHED_QOS, WORLD_FRAME
from ur_rg2_common.inbox import Arrival, Inbox
from ur_rg2_common.parameters import declare_parameters
from ur_rg2_common.spin import run_node
from ur_rg2_common.tf_buffer import FrameLookupError, TransformBuffer, transform_point

from ur_rg2_vision.ros_image import image_to_rgb
from ur_rg2_vision.settings import VIEWER_PARAMETERS, ViewerSettings
from ur_rg2_vision.viewer_web import (
    FrameHub,
    ViewerServer,
    ball_summary,
    is_loopback,
    joint_summary,
)

NODE_NAME = 'ur_rg2_viewer'
SIM_NODE = 'ur_rg2_sim'
# The frame of the sim's colour images, the one its camera pose parameters describe.
CAMERA_FRAME = 'camera_color_optical_frame'
_POSE_PARAMETERS = ('camera_position', 'camera_look_at')
BASE_FRAME = 'base_link'
_POSE_PERIOD_S = 2.0  # how often the sim is asked for its camera pose
_POSE_ANSWER_S = 10.0  # a question unanswered after this long is given up


def camera_to_world(position: Sequence[float], look_at: Sequence[float]
                    ) -> Callable[[Sequence[float]], np.ndarray]:
    """Return the conversion of optical-frame points to the world frame for a camera pose.

    The pose is the sim's (``camera_position``, ``camera_look_at``); ValueError if invalid.
    """
    rotation = optical_rotation(position, look_at)
    origin = np.asarray(position, dtype=float)
    return lambda point: rotation @ np.asarray(point, dtype=float) + origin


class ViewerNode(Node):
    """Serves the annotated camera stream and the robot's state over HTTP."""

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings = s = ViewerSettings.from_values(
            declare_parameters(self, VIEWER_PARAMETERS))
        address, port, image_topic, quality = s.address, s.port, s.image_topic, s.jpeg_quality

        self._hub = FrameHub(quality, self._decode)
        # Only the newest frame is shown: DDS keeps one (reliable, as the camera topics are);
        # the hub counts the frames skipped by their publisher's sequence numbers.
        frames = Inbox(self, Image, image_topic,
                       QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE),
                       lambda data, arrival: self._hub.put_frame(data, *arrival), raw=True)
        self._hub.pull_frames = frames.pull
        self._inboxes = (Inbox(self, JointState, 'joint_states', 100, self._on_joint_state),
                         Inbox(self, PointStamped, 'ball/position', 1, self._on_ball))
        self._hub.refresh = self._refresh
        # The camera and base_link are fixed in the world: /tf_static has all the ball needs.
        self._tree = TransformBuffer()
        self.create_subscription(TFMessage, '/tf_static', self._tree.add_message, LATCHED_QOS)
        self.create_subscription(String, 'pick_ball/result', self._on_pick_result, LATCHED_QOS)
        self.create_subscription(Bool, 'policy/driving', self._on_policy_driving, LATCHED_QOS)
        self.create_subscription(String, 'policy/result', self._on_policy_result, LATCHED_QOS)
        self._to_world: Callable[[Sequence[float]], np.ndarray] | None = None
        self._pose_client = self.create_client(GetParameters, f'{SIM_NODE}/get_parameters')
        self._pose_question: tuple[Future, float] | None = None
        self.create_timer(_POSE_PERIOD_S, self._ask_camera_pose)

        # Last, so that nothing before it can fail (e.g. a signal mid-construction) and leave
        # the server thread running with no node to stop it.
        self._server = ViewerServer(self._hub, address, port)
        try:
            self._server.start()
        except OSError as error:
            self.destroy_node()
            raise OSError(f'cannot serve on {address} port {port}: {error}') from error

        if not is_loopback(address):
            self.get_logger().warning(
                f'serving on non-loopback address {address}: anyone who can reach it sees '
                'the camera')
        self.get_logger().info(
            f'live view of {self.resolve_topic_name(image_topic)} at {self.url}')

    @property
    def url(self) -> str:
        """Address of the page."""
        return self._server.url

    def _decode(self, data: bytes) -> np.ndarray | None:
        """Return a serialized image as RGB (web thread), None when it cannot be shown."""
        try:
            return image_to_rgb(deserialize_message(data, Image))
        except ValueError as error:
            self.get_logger().warning(f'image dropped: {error}', throttle_duration_sec=10.0)
            return None

    def _refresh(self) -> None:
        """Take what came on the busy topics before a page reads the state (web thread)."""
        for inbox in self._inboxes:
            inbox.pull()

    def _on_joint_state(self, msg: JointState, arrival: Arrival) -> None:
        if len(msg.position) != len(msg.name):
            return  # positions omitted or malformed: no angles to show from this message
        for key, value in joint_summary(msg.name, msg.position).items():
            self._hub.set_state(key, value, arrival.received)

    def _on_ball(self, msg: PointStamped, arrival: Arrival) -> None:
        point = msg.point
        frame = msg.header.frame_id
        try:
            to_world, to_base = (self._tree.lookup(target, frame)
                                 for target in (WORLD_FRAME, BASE_FRAME))
            summary = ball_summary(frame, (point.x, point.y, point.z),
                                   lambda p: transform_point(to_world, p),
                                   lambda p: transform_point(to_base, p),
                                   'through the transform tree')
        except FrameLookupError:
            summary = ball_summary(frame, (point.x, point.y, point.z),
                                   self._to_world if frame == CAMERA_FRAME else None)
        self._hub.set_state('ball', summary, arrival.received)

    def _on_pick_result(self, msg: String) -> None:
        self._hub.set_state('pick', msg.data)

    def _on_policy_driving(self, msg: Bool) -> None:
        self._hub.set_state('policy_driving', msg.data)

    def _on_policy_result(self, msg: String) -> None:
        self._hub.set_state('policy_result', msg.data)

    def _ask_camera_pose(self) -> None:
        if self._pose_question is not None:
            future, asked = self._pose_question
            if time.monotonic() - asked < _POSE_ANSWER_S:
                return
            self._pose_client.remove_pending_request(future)  # the sim went away meanwhile
            self._pose_question = None
        if not self._pose_client.service_is_ready():
            return
        future = self._pose_client.call_async(GetParameters.Request(names=_POSE_PARAMETERS))
        future.add_done_callback(self._on_camera_pose)
        self._pose_question = future, time.monotonic()

    def _on_camera_pose(self, future: Future) -> None:
        self._pose_question = None
        try:
            position, look_at = (parameter_value_to_python(value)
                                 for value in future.result().values)
            self._to_world = camera_to_world(position, look_at)
        except (ValueError, TypeError) as error:  # not (yet) a sim with a valid camera pose
            self._to_world = None
            self.get_logger().debug(f'no world coordinates: {error}')

    def destroy_node(self) -> None:
        """Stop the web server (ending every stream), then the node."""
        self._server.stop()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the viewer until Ctrl-C / SIGTERM; exit code 1 on a bad parameter or a busy port."""
    return run_node(ViewerNode, args, NODE_NAME,
                    startup_errors=(OSError, ValueError, ParameterException))


if __name__ == '__main__':
    sys.exit(main())
